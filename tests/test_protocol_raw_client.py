"""A client written from docs/protocol.md alone, with only pyzmq and msgpack, against a real `eca up`.

Nothing from eca's protocol package is used on the client side (no Publisher, Subscriber, codec or
message classes): if this client works, a program in another language that follows the document
works too. `tests/support/bus.py` only starts and stops the process group.
"""

from __future__ import annotations

import os
import re
import secrets
import shutil
import stat
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgpack
import pytest
import zmq

from tests.support.bus import eca_command, running, write_test_config

AGENT = "ada"
TIMEOUT_S = 10.0


@dataclass(frozen=True)
class Instance:
    name: str
    runtime_dir: Path
    pub: str  # the endpoints printed in the "ready in" line
    sub: str


@contextmanager
def up(services: list[str]) -> Iterator[Instance]:
    directory = Path(tempfile.mkdtemp(prefix="eca-"))
    config_path = write_test_config(directory, services=services, agents=[AGENT])
    # a say request with no audio service fails sooner (the default waits 3 s)
    config_path.write_text(re.sub(r"(?m)^say_start_timeout_s = [0-9.]+", "say_start_timeout_s = 0.3",
                                  config_path.read_text()))
    name = f"raw{secrets.token_hex(3)}"
    try:
        with running(eca_command("up", "--config", str(config_path), "--instance", name, "--quiet")) as (_, out):
            line = out.lines[out.wait_for("ready in", 30.0)]
            found = re.search(r"publish to (\S+), subscribe at (\S+)\)", line)
            assert found, line
            yield Instance(name, directory / "run", found.group(1), found.group(2))
    finally:
        shutil.rmtree(directory, ignore_errors=True)


@pytest.fixture(scope="module")
def instance() -> Iterator[Instance]:
    with up(["dialogue"]) as inst:
        yield inst


class RawClient:
    """An XPUB (or PUB) to `pub`, a SUB to `sub`, the two readiness barriers of §2, msgpack maps."""

    def __init__(self, inst: Instance, prefixes: list[str], xpub: bool = True, source: str = "raw-test") -> None:
        self.ctx = zmq.Context()
        self.source = source
        self.seq = 0
        self.pub = self.ctx.socket(zmq.XPUB if xpub else zmq.PUB)
        self.pub.setsockopt(zmq.LINGER, 500)
        self.pub.connect(inst.pub)
        self.sub = self.ctx.socket(zmq.SUB)
        self.sub.setsockopt(zmq.LINGER, 0)
        for p in prefixes:
            self.sub.setsockopt(zmq.SUBSCRIBE, p.encode())
        self.sub.connect(inst.sub)
        self._last_state: dict[bytes, bytes] = {}
        self.inbox: list[tuple[str, dict[str, Any]]] = []
        if xpub:
            assert self.pub.poll(int(TIMEOUT_S * 1000)), "no subscription from the broker on the XPUB"
            assert self.pub.recv() == b"\x01"  # the broker subscribes to everything
        self.early = self._wait_for_hello()

    def _wait_for_hello(self) -> list[tuple[str, dict[str, Any]]]:
        probe = f"sys.{secrets.token_hex(8)}.hello"
        self.sub.setsockopt(zmq.SUBSCRIBE, probe.encode())
        try:
            early = []
            while True:
                got = self.recv(TIMEOUT_S)
                assert got is not None, "the broker did not answer the probe subscription"
                topic, msg = got
                if topic == probe:
                    assert msg["type"] == "hello" and msg["source"] == "broker"
                    return early
                early.append(got)
        finally:
            self.sub.setsockopt(zmq.UNSUBSCRIBE, probe.encode())

    def send_raw(self, frames: list[bytes]) -> None:
        self.pub.send_multipart(frames)

    def send(self, type_name: str, agent: str = AGENT, category: str = "cmd", **body: Any) -> None:
        self.seq += 1
        msg = {"v": 1, "type": type_name, "agent": agent, "seq": self.seq, "t_ns": time.monotonic_ns(),
               "source": self.source, **body}
        self.send_raw([f"{category}.{agent}.{type_name}".encode(), msgpack.packb(msg, use_bin_type=True)])

    def recv(self, timeout_s: float) -> tuple[str, dict[str, Any]] | None:
        """One message (a repeat of a cached state skipped, §9), or None after the timeout."""
        deadline = time.monotonic() + timeout_s
        while self.sub.poll(max(0, int((deadline - time.monotonic()) * 1000))):
            frames = self.sub.recv_multipart()
            assert len(frames) == 2, frames
            if frames[0].startswith(b"state."):
                if self._last_state.get(frames[0]) == frames[1]:
                    continue  # the cache re-sent what we have (§9)
                self._last_state[frames[0]] = frames[1]
            return frames[0].decode(), msgpack.unpackb(frames[1], raw=False)
        return None

    def expect(self, match: Callable[[str, dict[str, Any]], bool], timeout_s: float = TIMEOUT_S,
               what: str = "") -> tuple[str, dict[str, Any]]:
        """The first message that matches; everything received on the way is kept in `inbox`."""
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            got = self.recv(left)
            if got is None:
                break
            self.inbox.append(got)
            if match(*got):
                return got
        tail = "\n".join(f"{t}: {m}" for t, m in self.inbox[-10:])
        raise AssertionError(f"nothing matching {what} within {timeout_s} s; last received:\n{tail}")

    def close(self) -> None:
        self.pub.close()
        self.sub.close()
        self.ctx.term()


@pytest.fixture
def client(instance: Instance) -> Iterator[RawClient]:
    c = RawClient(instance, [f"state.{AGENT}.", f"event.{AGENT}.", "error.", "sys."])
    yield c
    c.close()


def test_endpoints_are_the_documented_files_in_a_private_directory(instance: Instance) -> None:
    run_dir = instance.runtime_dir / instance.name
    assert (instance.pub, instance.sub) == (f"ipc://{run_dir}/pub", f"ipc://{run_dir}/sub")
    assert stat.S_IMODE(os.stat(run_dir).st_mode) == 0o700
    assert stat.S_ISSOCK(os.stat(run_dir / "pub").st_mode) and stat.S_ISSOCK(os.stat(run_dir / "sub").st_mode)


def test_a_new_subscriber_gets_the_current_state_from_the_cache(client: RawClient) -> None:
    topics = {topic for topic, _ in client.early}
    for kind in ("role", "emotion", "head", "eyes", "gaze_target", "speech"):  # this instance runs no audio
        assert f"state.{AGENT}.{kind}" in topics
    for topic, msg in client.early:
        if topic.startswith("state."):
            assert topic == f"state.{msg['agent']}.{msg['type']}"
            owner = "audio" if msg["type"] == "playback" else "dialogue"
            assert msg["v"] == 1 and msg["source"] == owner and msg["seq"] >= 1


def test_sets_an_emotion_and_receives_the_state_change(client: RawClient) -> None:
    sent_ns = time.monotonic_ns()
    client.send("set_emotion", name="Happy", intensity=0.37)  # transition_s left at its default
    topic, msg = client.expect(lambda t, m: t == f"state.{AGENT}.emotion" and m["intensity"] == 0.37,
                               what="the emotion state")
    assert msg["name"] == "happy"  # the canonical name
    assert msg["transition_s"] == 0.5
    assert msg["type"] == "emotion" and msg["agent"] == AGENT and msg["source"] == "dialogue"
    assert msg["t_ns"] >= sent_ns  # the same host: one monotonic clock
    assert set(msg) == {"v", "type", "agent", "seq", "t_ns", "source", "name", "intensity", "transition_s"}


def test_an_unknown_emotion_comes_back_on_the_error_topic(client: RawClient) -> None:
    client.send("set_emotion", name="gleeful", request_id="req-7")
    topic, err = client.expect(lambda t, m: t.startswith("error.") and m.get("request_id") == "req-7",
                               what="the error")
    assert topic == f"error.{AGENT}.error"
    assert err["kind"] == "rejected" and err["service"] == "dialogue"
    assert err["topic"] == f"cmd.{AGENT}.set_emotion"
    assert "gleeful" in err["reason"] and "happy" in err["reason"]  # lists the known emotions


def test_garbage_on_a_cmd_topic_yields_errors_and_the_service_keeps_working(client: RawClient) -> None:
    def error_for(kind: str) -> Callable[[str, dict[str, Any]], bool]:
        return lambda t, m: t.startswith("error.") and m["kind"] == kind

    client.send_raw([f"cmd.{AGENT}.set_emotion".encode(), b"\xff\xff\xff"])
    topic, err = client.expect(error_for("not_msgpack"), what="not_msgpack")
    assert topic == f"error.{AGENT}.error" and err["topic"] == f"cmd.{AGENT}.set_emotion"

    client.send("set_emotion", name="happy", intensity=2.0, request_id="r-range")
    topic, err = client.expect(error_for("out_of_range"), what="out_of_range")
    assert "intensity" in err["reason"]
    # an error about a command the codec refused still names its request and goes to its agent
    assert topic == f"error.{AGENT}.error" and err["request_id"] == "r-range"

    client.send("set_emotion", name="happy", mood="great")
    _, err = client.expect(error_for("extra_field"), what="extra_field")
    assert "mood" in err["reason"]

    client.send("set_emotion", name="happy", intensity=float("nan"))
    client.expect(error_for("not_finite"), what="not_finite")

    payload = msgpack.packb({"v": 1, "type": "set_emotion", "agent": "ada", "name": "happy"})
    client.send_raw([f"cmd.{AGENT}.set_role".encode(), payload])  # topic and content disagree
    client.expect(error_for("bad_topic"), what="bad_topic")

    client.send_raw([f"cmd.{AGENT}.set_emotion".encode(), payload, b"third frame"])
    topic, err = client.expect(error_for("bad_frames"), what="bad_frames")
    # the first frame reads as a topic: the error goes where a client of that agent listens
    assert topic == f"error.{AGENT}.error" and err["topic"] == f"cmd.{AGENT}.set_emotion"

    client.send("set_emotion", name="angry", intensity=0.61)
    _, state = client.expect(lambda t, m: t == f"state.{AGENT}.emotion" and m["intensity"] == 0.61,
                             what="the emotion state after the garbage")
    assert state["name"] == "angry"
    _, beat = client.expect(lambda t, m: m["type"] == "heartbeat" and m["service"] == "dialogue"
                            and m["bad_messages"] >= 6, what="a dialogue heartbeat counting the bad messages")
    assert beat["agent"] == "*"


def test_a_plain_pub_socket_is_ready_once_its_own_hello_comes_back(instance: Instance) -> None:
    c = RawClient(instance, [f"state.{AGENT}.", "error."], xpub=False, source="plain-pub")
    try:
        nonce = secrets.token_hex(8)
        probe = f"sys.{nonce}.hello"
        c.sub.setsockopt(zmq.SUBSCRIBE, probe.encode())
        deadline = time.monotonic() + TIMEOUT_S
        echoed = False
        while not echoed and time.monotonic() < deadline:
            c.send("hello", agent=nonce, category="sys")
            got = c.recv(0.05)
            while got is not None and not echoed:
                echoed = got[0] == probe and got[1]["source"] == "plain-pub"
                got = None if echoed else c.recv(0.0)
        assert echoed, "our own hello never came back"
        c.sub.setsockopt(zmq.UNSUBSCRIBE, probe.encode())
        c.send("set_role", role="silence", speaker="")
        _, msg = c.expect(lambda t, m: t == f"state.{AGENT}.role" and m["role"] == "silence", what="role")
        assert msg["set_by"] == "command"
    finally:
        c.close()


def test_say_without_an_audio_service_ends_in_one_failure_and_a_bad_say_in_an_error(client: RawClient) -> None:
    client.send("say", request_id="bad-1", audio_path="a.wav", pcm=b"\x00\x00", sample_rate=16000)
    client.send("say", request_id="ok-1", pcm=b"\x00\x00" * 800, sample_rate=16000, text="hello")
    topic, err = client.expect(lambda t, m: t.startswith("error.") and m.get("request_id") == "bad-1",
                               what="the rejection of the say with two audio sources")
    assert err["kind"] == "rejected" and topic == f"error.{AGENT}.error"
    topic, ack = client.expect(lambda t, m: t.startswith("event.") and m.get("request_id") == "ok-1",
                               what="the acknowledgement of the say request")
    assert topic == f"event.{AGENT}.ack" and ack["command"] == "say"  # accepted and handed on
    topic, ev = client.expect(lambda t, m: t.startswith("event.") and m.get("request_id") == "ok-1",
                              what="the lifecycle of the say request")
    assert topic == f"event.{AGENT}.speech_failed"
    assert ev["reason"] == "no audio service answered"
    # one round trip more: anything the dialogue service published about these requests has arrived
    client.send("set_eyes", mode="noise", request_id="after")
    client.expect(lambda t, m: t == f"state.{AGENT}.eyes" and m["mode"] == "noise", what="the eye state")
    client.expect(lambda t, m: t == f"event.{AGENT}.ack" and m["request_id"] == "after", what="the eyes' ack")
    events = [(t, m["request_id"]) for t, m in client.inbox
              if t.startswith("event.") and m.get("request_id") in ("ok-1", "bad-1", "after")]  # the module's others
    # exactly one acknowledgement and one terminal event for ok-1, the acknowledgement first; none for bad-1
    assert events == [(f"event.{AGENT}.ack", "ok-1"), (f"event.{AGENT}.speech_failed", "ok-1"),
                      (f"event.{AGENT}.ack", "after")]


def test_a_command_for_an_agent_the_instance_does_not_animate_gets_an_error(client: RawClient) -> None:
    client.sub.setsockopt(zmq.SUBSCRIBE, b"error.bob.")
    client.send("set_emotion", agent="bob", name="happy", request_id="for-bob")
    _, err = client.expect(lambda t, m: t == "error.bob.error" and m.get("request_id") == "for-bob", timeout_s=2.0,
                           what="an error about the unknown agent")
    assert err["kind"] == "rejected" and "unknown agent" in err["reason"]


def test_a_say_with_only_text_is_spoken_and_lives_its_whole_lifecycle() -> None:
    """A dialogue manager with text and no audio, in any language: the audio service speaks it."""
    with up(["dialogue", "audio"]) as inst:
        client = RawClient(inst, [f"event.{AGENT}.", f"stream.{AGENT}.voice", f"error.{AGENT}."])
        try:
            client.send("say", request_id="spoken-1", text="Hello from a client that has only text.")
            client.expect(lambda t, m: t == f"event.{AGENT}.ack" and m["request_id"] == "spoken-1", what="the ack")
            client.expect(lambda t, m: t == f"event.{AGENT}.speech_started" and m["request_id"] == "spoken-1",
                          what="speech_started")
            _, done = client.expect(lambda t, m: t.startswith(f"event.{AGENT}.speech_") and
                                    m["request_id"] == "spoken-1" and m["type"] != "speech_started",
                                    timeout_s=30.0, what="the terminal event")
            voice = [m for t, m in client.inbox if t == f"stream.{AGENT}.voice" and m["request_id"] == "spoken-1"]
        finally:
            client.close()
    assert done["type"] == "speech_finished" and 1.5 < done["played_s"] < 6.0, done
    import numpy as np

    samples = np.frombuffer(b"".join(m["pcm"] for m in voice), "<i2").astype(np.float64)
    assert len(samples) / 48_000 > 1.0 and np.sqrt(np.mean(samples ** 2)) > 300  # heard, not silence
