"""What the field sends, against real processes under `eca up`: hostile bytes on every topic, and kill -9
of every service, the broker first and again and again. Every process keeps its pid through the bytes;
after any kills the state read back is the state last commanded, a restarted renderer draws it, and
every say request ends exactly once.
"""

from __future__ import annotations

import os
import random
import re
import signal
import time
from collections.abc import Iterator
from pathlib import Path

import msgpack
import numpy as np
import pytest
import zmq

from eca.protocol.bus import Publisher, Subscriber
from eca.protocol.client import AgentClient
from eca.protocol.codec import encode
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import (
    ALL_AGENTS,
    TERMINAL_SPEECH_EVENTS,
    ClockAnchor,
    EmotionState,
    FaceFrame,
    Heartbeat,
    Message,
    MouthKeys,
    RoleState,
    Say,
    SetEmotion,
    SpeechState,
)
from eca.protocol.topics import CATEGORIES
from eca.services.processes.liveness import liveness_endpoint
from eca.services.tools.child_processes import LineReader
from tests.support.bus import eca_command, private_bus_config, running

pytestmark = pytest.mark.slow

SERVICES = ["dialogue", "gaze", "audio", "renderer"]
# small, slow frames: the renderer is a process to keep alive here, not a picture to look at
RENDERER = "[renderer]\nfps = 15.0\nwidth = 96\nheight = 72\nview = \"full\"\nidle_noise = false\n"


@pytest.fixture
def instance() -> Iterator[tuple[BusConfig, LineReader, dict[str, int]]]:
    with private_bus_config(services=SERVICES, extra=RENDERER) as config:
        argv = eca_command("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet",
                           "--headless")
        with running(argv) as (proc, reader):
            reader.wait_for("[up] ready in", 90.0)
            for name in ("broker", *SERVICES):  # each child's output reaches the reader on a thread of its own
                reader.wait_for(f"[{name}] INFO ready (pid", 10.0)
            yield config, reader, pids_of(reader)
            assert proc.poll() is None, "eca up itself stopped"


def pids_of(reader: LineReader, since: int = 0) -> dict[str, int]:
    """The pid each service last reported ready with."""
    pids = {}
    for line in reader.lines[since:]:
        m = re.match(r"\[(\w+)\] INFO ready \(pid (\d+)", line)
        if m:
            pids[m.group(1)] = int(m.group(2))
    return pids


def alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/status") as fh:
            return "zombie" not in fh.read()
    except FileNotFoundError:
        return False


COMMANDED = [
    lambda c: c.set_emotion("angry", 0.55, 0.0),
    lambda c: c.move_head(turn=0.25, nod=-0.1, tilt=0.05, duration_s=0.0),
    lambda c: c.set_role("silence"),
    lambda c: c.set_eyes("saccade"),
    lambda c: c.set_gaze_target(12.5, -4.0, "user"),
]


def command(config: BusConfig, sends: list, timeout_s: float = 20.0) -> dict[str, Message]:
    """Send commands and wait for each acknowledgement; the states they caused."""
    with AgentClient(config, timeout_s=timeout_s) as client:
        for send in sends:
            client.wait_applied(send(client), timeout_s)
        return dict(client.state)


def read_back(config: BusConfig) -> dict[str, tuple]:
    """The agent's state as a new client finds it in the cache, as comparable values."""
    with AgentClient(config, timeout_s=20.0) as client:
        return {t: state_values(m) for t, m in client.state.items() if t not in ("playback", "speech")}


def state_values(msg: Message) -> tuple:
    return tuple(v for k, v in vars(msg).items() if k not in ("seq", "t_ns", "source"))


# --- hostile bytes -----------------------------------------------------------------------------------


def hostile_corpus(seed: int) -> list[list[bytes]]:
    """Every class of malformed message on every topic category: not msgpack, deep nesting, huge
    containers, oversize, wrong types, NaN, extra and missing fields, unknown types and versions, wrong
    frame counts, non-UTF-8 and mismatched topics, stale states, and valid messages with bytes flipped."""
    rng = random.Random(seed)
    deep = [0]
    for _ in range(1000):
        deep = [deep]
    deep_map: dict = {}
    for _ in range(900):
        deep_map = {"k": deep_map}
    base = msgpack.unpackb(encode(SetEmotion(agent="ada", name="happy", request_id="fz")))
    payloads = [
        b"", b"\xff\xff\xff", b"\xc1", b"\x92\x01", b"\x91" * 2000 + b"\x00", msgpack.packb(deep),
        msgpack.packb({"v": 1, "type": deep, "agent": "ada"}), msgpack.packb({"v": deep, "type": "role"}),
        msgpack.packb({"v": 1, "type": "set_emotion", "agent": "ada", "name": deep_map}),
        msgpack.packb({"v": 1, "type": "set_emotion", "agent": "ada", "name": "x" * 3_000_000}),
        msgpack.packb({"v": 1, "type": "mouth", "agent": "ada", "request_id": "r", "sample_rate": 1,
                       "sample_index": list(range(200_000))}),
        msgpack.packb({"v": 1, "type": "face_frame", "agent": "ada", "frame_ns": 1,
                       "flexors": {f"k{i}": 0.1 for i in range(50_000)}}),
        b"\xdb" + (5 * 2**20).to_bytes(4, "big") + b"x" * (5 * 2**20),  # over the codec's 4 MiB cap
        msgpack.packb({**base, "intensity": float("nan")}), msgpack.packb({**base, "intensity": "high"}),
        msgpack.packb({**base, "mood": 1}), msgpack.packb({k: v for k, v in base.items() if k != "name"}),
        msgpack.packb({**base, "type": "set_mood"}), msgpack.packb({**base, "v": 2}),
        msgpack.packb({**base, "agent": "é"}), msgpack.packb({1: 2}), msgpack.packb([base]),
    ]
    valid = [encode(m) for m in (
        SetEmotion(agent="ada", name="happy"), RoleState(agent="ada", role="talking"),
        SpeechState(agent="ada", request_ids=["a"], streamed=[False], next_chunk=[0], chunks_done=[False],
                    started=[False], audio_started_ns=[0]),
        ClockAnchor(agent="ada", request_id="r", sample_index=5, sample_rate=16000, dac_time_ns=9),
        MouthKeys(agent="ada", request_id="r", sample_rate=100, sample_index=[1, 2], weights={"say_ah": [0.1, 0.2]}),
        Heartbeat(agent=ALL_AGENTS, service="gaze", pid=1, started_ns=1),
        Say(agent="ada", request_id="r", pcm=b"\0\0" * 100, sample_rate=16000),
    )]
    for _ in range(300):
        flipped = bytearray(rng.choice(valid))
        for _ in range(rng.randint(1, 4)):
            flipped[rng.randrange(len(flipped))] = rng.randrange(256)
        payloads.append(bytes(flipped[:rng.randint(1, len(flipped))]))
    stale = {"emotion": EmotionState(agent="ada", name="surprised", t_ns=1, source="dialogue"),
             "role": RoleState(agent="ada", role="talking", t_ns=1, source="dialogue")}
    out: list[list[bytes]] = []
    types = ["say", "set_emotion", "role", "emotion", "speech", "playback", "heartbeat", "error", "mouth",
             "clock_anchor", "eye_states", "face_frame", "speech_finished", "x"]
    for category in CATEGORIES:
        for agent in ("ada", "*", "bob"):
            for type_name in types:
                topic = f"{category}.{agent}.{type_name}".encode()
                out += [[topic, rng.choice(payloads)] for _ in range(2)]
    out += [[b"cmd.ada.set_emotion", p] for p in payloads]
    out += [[b"state.ada.emotion", p] for p in payloads]
    out += [[b"sys.*.heartbeat", p] for p in payloads]
    out += [[f"state.ada.{t}".encode(), encode(m)] for t, m in stale.items()]
    out += [[b"\xff\xfe.ada.say", payloads[1]], [b"cmd.ada.set_role", encode(SetEmotion(agent="ada", name="happy"))],
            [b"cmd.ada.set_emotion"], [b"cmd.ada.set_emotion", b"\x80", b"third"], [b"x" * 5000, b"\x80"],
            [b"sys.x.hello", msgpack.packb({"v": 1, "type": "hello", "agent": "x"})]]
    rng.shuffle(out)
    return out


def test_hostile_bytes_on_every_topic_cost_no_process_and_no_state(instance) -> None:
    config, reader, pids = instance
    assert set(pids) == {"broker", *SERVICES}
    command(config, COMMANDED)
    before = read_back(config)
    ctx = zmq.Context()
    pub = Publisher(ctx, config, "fuzzer")
    to_supervisor = ctx.socket(zmq.PUSH)
    to_supervisor.setsockopt(zmq.LINGER, 0)
    to_supervisor.connect(liveness_endpoint(config))
    try:
        pub.wait_ready()
        corpus = hostile_corpus(seed=15)
        for k, frames in enumerate(corpus):
            pub.socket.send_multipart(frames)
            if k % 50 == 0:
                # the supervisor's own channel gets garbage too: it must not share a fate with what it reads
                to_supervisor.send(frames[-1], zmq.NOBLOCK)
        # the services read it all: an acknowledged command after it has waited behind every message
        command(config, [lambda c: c.set_eyes("saccade")], timeout_s=60.0)
    finally:
        pub.close()
        to_supervisor.close()
        ctx.term()
    assert read_back(config) == before
    for name, pid in pids.items():
        assert alive(pid), f"{name} (pid {pid}) died"
    assert pids_of(reader) == pids, "a service was restarted"
    assert not [line for line in reader.lines if "Traceback" in line or "restarting" in line]
    # and each is still at work: the renderer draws, the gaze service moves the eyes
    ctx = zmq.Context()
    sub = Subscriber(ctx, config, ["stream.ada.face_frame", "stream.*.eye_states"])
    try:
        sub.wait_ready()
        seen: set[str] = set()
        deadline = time.monotonic() + 20.0
        while seen != {"face_frame", "eye_states"} and time.monotonic() < deadline:
            got = sub.recv(1.0)
            if got is not None and got.message is not None:
                seen.add(got.message.TYPE)
        assert seen == {"face_frame", "eye_states"}
    finally:
        sub.close()
        ctx.term()


# --- kill -9 ------------------------------------------------------------------------------------------


def kill_and_wait_back(reader: LineReader, name: str, pid: int) -> int:
    """SIGKILL one service and wait until a new instance of it reports ready; its pid."""
    start = len(reader.lines)
    os.kill(pid, signal.SIGKILL)
    reader.wait_for(f"[up] {name} exited", 30.0, start)
    reader.wait_for(f"[{name}] INFO ready (pid", 60.0, start)
    new = pids_of(reader, start)[name]
    assert new != pid
    return new


def say_pcm(seconds: float, rate: int = 16_000) -> bytes:
    t = np.arange(int(seconds * rate)) / rate
    return (0.2 * np.sin(2 * np.pi * 220 * t) * 32767).astype("<i2").tobytes()


def test_any_kills_in_any_order_keep_the_commanded_state_and_end_every_say_once(instance) -> None:
    config, reader, pids = instance
    rng = random.Random(1515)
    others = [rng.choice(SERVICES) for _ in range(4)]
    order = ["broker"]
    for name in others:  # the broker first, and again between the others
        order += [name, "broker"]
    # one emotion commanded after every second kill; the last one (happy) is what must come back
    emotions = [("disappointed", 0.45), ("surprised", 0.7), ("angry", 0.3), ("frightened", 0.6), ("happy", 0.9)]
    command(config, COMMANDED)
    terminals: dict[str, set[str]] = {}
    says: list[str] = []
    commanded = None
    with AgentClient(config, timeout_s=20.0) as client:
        for k, name in enumerate(order):
            rid = client.new_request_id()
            client.wait_applied(client.send(Say(agent="ada", request_id=rid, pcm=say_pcm(1.5), sample_rate=16_000)),
                                timeout_s=30.0)
            says.append(rid)
            pids[name] = kill_and_wait_back(reader, name, pids[name])
            if k % 2 == 0:
                commanded = emotions[k // 2]
                command(config, [lambda c, e=commanded: c.set_emotion(*e, transition_s=0.0)], timeout_s=30.0)
        for rid in says:
            ended = client.wait_for_speech(rid, timeout_s=60.0)
            terminals.setdefault(rid, set()).add(ended.TYPE)
        # every other ending of those requests that reached this client: never a second, different one
        for msg in list(client._inbox):
            if isinstance(msg, TERMINAL_SPEECH_EVENTS) and msg.request_id in terminals:
                terminals[msg.request_id].add(msg.TYPE)
        if client.state["speech"].request_ids:  # none stays pending: the last speech state lists none
            client.wait_for(lambda m: isinstance(m, SpeechState) and not m.request_ids, 30.0)
    assert set(terminals) == set(says)
    assert all(len(kinds) == 1 for kinds in terminals.values()), terminals
    # the state read back is the last commanded, whatever was killed in between
    assert commanded == ("happy", 0.9)
    state = read_back(config)
    assert state["emotion"][1:3] == commanded
    assert state["head"][1:4] == (0.25, -0.1, 0.05) and state["eyes"][1] == "saccade"
    assert state["gaze_target"][1:4] == (12.5, -4.0, "user")
    assert not [line for line in reader.lines if "not restarted again" in line or "Traceback" in line]
    # only what was killed was restarted: a broker that is down costs the healthy services nothing
    assert pids_of(reader) == pids
    # a renderer started after all that draws the commanded face, not a neutral one
    kill_and_wait_back(reader, "renderer", pids["renderer"])
    smile = face_flexor(config, "smile_l")
    assert smile > 0.4, f"the restarted renderer draws a smile of {smile:.2f} for {commanded}"


def face_flexor(config: BusConfig, name: str, settle_s: float = 1.0) -> float:
    """A flexor of the face the renderer draws, once any transition has settled."""
    ctx = zmq.Context()
    sub = Subscriber(ctx, config, ["stream.ada.face_frame"])
    try:
        sub.wait_ready(20.0)
        first = None
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:
            got = sub.recv(1.0)
            if got is None or not isinstance(got.message, FaceFrame):
                continue
            first = first or got.message.frame_ns
            if got.message.frame_ns - first >= settle_s * 1e9:
                return got.message.flexors[name]
        raise AssertionError("the renderer drew no frames")
    finally:
        sub.close()
        ctx.term()


def test_a_stopped_instance_leaves_no_runtime_files_and_no_process(tmp_path: Path) -> None:
    with private_bus_config(services=["dialogue", "gaze"]) as config:
        argv = eca_command("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet")
        with running(argv) as (proc, reader):
            reader.wait_for("[up] ready in", 60.0)
            pids = pids_of(reader)
            command(config, COMMANDED[:1])
            assert (config.runtime_dir / "state.msgpack").exists()
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=20)
        assert proc.returncode == 0
        assert not [p for p in pids.values() if alive(p)]
        assert not config.runtime_dir.exists(), sorted(config.runtime_dir.iterdir())



def test_a_service_alone_with_no_broker_says_so_in_one_line(tmp_path: Path) -> None:
    """Started without `eca up` and with no broker, a service waits its connect timeout, then stops with
    one line naming the endpoint: no traceback."""
    import subprocess
    import sys

    from eca.services.tools.child_processes import subprocess_env
    from tests.support.bus import REPO_ROOT

    with private_bus_config() as config:
        text = config.config_path.read_text()
        config.config_path.write_text(text.replace("connect_timeout_s = 10.0", "connect_timeout_s = 0.6", 1))
        done = subprocess.run([sys.executable, "-m", "eca.services.processes.run", "dialogue",
                               "--config", str(config.config_path), "--instance", config.instance],
                              capture_output=True, text=True, timeout=60, env=subprocess_env(), cwd=REPO_ROOT)
    assert done.returncode == 1
    errors = [line for line in done.stderr.splitlines() if "ERROR" in line]
    assert len(errors) == 1 and "no broker answered at ipc://" in errors[0] and "within 0.6 s" in errors[0]
    assert "Traceback" not in done.stderr
