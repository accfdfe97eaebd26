"""docs/protocol.md section 11, the example session, played against a fresh instance under `eca up` with plain
pyzmq and msgpack, as a client in another language would: every message the document shows is what the
instance says (its keys, and every value but the times and counts that vary), the 84 payload bytes it prints are
the ones sent, and the answers come as it says. So the document cannot fall behind the services again."""

from __future__ import annotations

import json
import os
import re
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgpack
import pytest
import zmq

from eca.protocol.endpoints import BusConfig
from tests.support.bus import eca_command, private_bus_config, running

pytestmark = pytest.mark.slow

DOC = Path(__file__).resolve().parent.parent / "docs" / "protocol.md"
VARYING = {"seq", "t_ns", "started_ns"}  # "times and sequence numbers vary": counts and monotonic times
ELIDED = {"seq", "t_ns", "source"}  # what a "..." in a shown payload may stand for: envelope keys only
# The services of a fresh instance that publish what section 11 shows (the renderer publishes no state).
SERVICES = ["dialogue", "gaze", "audio"]


def example() -> str:
    text = DOC.read_text(encoding="utf-8")
    return text[text.index("## 11. Example session"):text.index("## 12.")]


def step(n: int) -> str:
    """The text of step n of the example."""
    section = example()
    start = re.search(rf"^{n}\. ", section, flags=re.MULTILINE)
    end = re.search(rf"^{n + 1}\. ", section, flags=re.MULTILINE)
    assert start is not None, f"no step {n}"
    return section[start.start():end.start() if end else len(section)]


def shown(text: str) -> list[tuple[str, dict[str, Any], bool]]:
    """The (topic, payload, elided) rows of the tables in `text`; elided: the payload shows "..." for keys."""
    rows = []
    for topic, payload in re.findall(r"^\s*\| `([^`]+)` \| `(\{.*\})` \|$", text, flags=re.MULTILINE):
        elided = "..." in payload
        rows.append((topic, json.loads(payload.replace(", ...,", ",")), elided))
    return rows


def check_shown(topic: str, doc: dict[str, Any], elided: bool, got_topic: bytes, got: dict[str, Any]) -> None:
    assert got_topic.decode() == topic
    extra = set(got) - set(doc)
    assert extra <= (ELIDED if elided else set()), f"{topic}: the document does not show {sorted(extra)}"
    assert set(doc) <= set(got), f"{topic}: the instance does not send {sorted(set(doc) - set(got))}"
    for key in set(doc) - VARYING:
        assert got[key] == doc[key], f"{topic}: {key} is {got[key]!r}, the document says {doc[key]!r}"


def hex_bytes(line: str) -> str:
    """The bytes of one line of the document's hex dump: the hex pairs before its comment."""
    out = []
    for token in line.split():
        if not re.fullmatch(r"[0-9a-f]{2}", token):
            break
        out.append(token)
    return " ".join(out)


@pytest.fixture
def instance() -> Iterator[BusConfig]:
    with private_bus_config(services=SERVICES) as config:
        argv = eca_command("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet",
                           "--silent-audio")
        with running(argv) as (proc, reader):
            reader.wait_for("[up] ready in", 90.0)
            for name in ("broker", *SERVICES):  # each has published its first states (eca up's ready may come first)
                reader.wait_for(f"[{name}] INFO ready (pid", 10.0)
            yield config
            assert proc.poll() is None, "eca up itself stopped"


def recv(sub: zmq.Socket[bytes], seen: dict[bytes, bytes], timeout_s: float = 5.0) -> tuple[bytes, dict[str, Any]]:
    """The next message, less the cache's repeats: as section 9 tells a client, a state whose payload is the one
    last seen on its topic is skipped (the broker sends the cache again to everyone when anyone subscribes)."""
    while True:
        assert sub.poll(int(timeout_s * 1000)), "nothing arrived"
        topic, payload = sub.recv_multipart()
        if topic.startswith(b"state.") and seen.get(topic) == payload:
            continue
        seen[topic] = payload
        return topic, msgpack.unpackb(payload)


def test_the_example_session_is_what_a_fresh_instance_says(instance: BusConfig) -> None:
    ctx = zmq.Context()
    pub, sub = ctx.socket(zmq.XPUB), ctx.socket(zmq.SUB)
    seen: dict[bytes, bytes] = {}
    try:
        # steps 1-2: the publisher's barrier
        pub.setsockopt(zmq.LINGER, 500)
        pub.connect(instance.frontend)
        sub.setsockopt(zmq.LINGER, 0)
        for prefix in (b"state.ada.", b"error.ada."):
            sub.setsockopt(zmq.SUBSCRIBE, prefix)
        sub.connect(instance.backend)
        assert pub.poll(5000) and pub.recv() == b"\x01"
        # step 3: the subscriber's barrier; the cached states come first
        nonce = os.urandom(8).hex()
        probe = f"sys.{nonce}.hello".encode()
        sub.setsockopt(zmq.SUBSCRIBE, probe)
        cached: list[tuple[bytes, dict[str, Any]]] = []
        while True:
            topic, msg = recv(sub, seen)
            if topic == probe:
                hello = msg
                break
            cached.append((topic, msg))
        sub.setsockopt(zmq.UNSUBSCRIBE, probe)
        rows = shown(step(3))
        states, hello_row = rows[:-1], rows[-1]
        assert len(states) == 7 and "seven" in step(3)
        assert sorted(t for t, _ in cached) == sorted(t.encode() for t, _, _ in states), "the cached states"
        by_topic = dict(cached)
        for topic, doc, elided in states:
            check_shown(topic, doc, elided, topic.encode(), by_topic[topic.encode()])
        # "in the order their topics were first published": the dialogue service's, in the order shown
        dialogue_order = [t for t, m in cached if m["source"] == "dialogue"]
        assert dialogue_order == [t.encode() for t, doc, _ in states if doc.get("source", "dialogue") == "dialogue"]
        doc_hello = {**hello_row[1], "agent": nonce}
        check_shown(f"sys.{nonce}.hello", doc_hello, hello_row[2], probe, hello)
        # step 4: the payload bytes the document prints, sent as they are
        text = step(4)
        dump = re.search(r"```\n(.*?)```", text, flags=re.DOTALL)
        assert dump is not None
        payload = bytes.fromhex(" ".join(hex_bytes(line) for line in dump.group(1).splitlines()))
        assert f"{len(payload)} bytes" in text
        said = json.loads(re.search(r"payload `(\{.*?\})`", text, flags=re.DOTALL).group(1))  # type: ignore[union-attr]
        assert msgpack.unpackb(payload) == said
        topic = re.search(r"the topic, (\d+) bytes: `([^`]+)`", text)
        assert topic is not None and len(topic.group(2)) == int(topic.group(1))
        pub.send_multipart([topic.group(2).encode(), payload])
        # step 5
        [(doc_topic, doc, elided)] = shown(step(5))
        got_topic, got = recv(sub, seen)
        check_shown(doc_topic, doc, elided, got_topic, got)
        # step 6
        text = step(6)
        command = json.loads(re.search(r"with `(\{.*?\})`", text, flags=re.DOTALL).group(1).replace("\n", " "))  # type: ignore[union-attr]
        pub.send_multipart([b"cmd.ada.set_emotion", msgpack.packb(command)])
        [(doc_topic, doc, elided)] = shown(text)
        got_topic, got = recv(sub, seen)
        check_shown(doc_topic, doc, elided, got_topic, got)
        # step 7: garbage, answered, and the service serves on
        pub.send_multipart([b"cmd.ada.set_emotion", bytes.fromhex("ffffff")])
        got_topic, got = recv(sub, seen)
        assert got_topic == b"error.ada.error" and (got["kind"], got["topic"]) == ("not_msgpack", "cmd.ada.set_emotion")
        assert '"kind": "not_msgpack"' in step(7)
        again = {**said, "seq": 3, "t_ns": time.monotonic_ns(), "name": "surprised"}
        pub.send_multipart([b"cmd.ada.set_emotion", msgpack.packb(again)])
        got_topic, got = recv(sub, seen)
        assert got_topic == b"state.ada.emotion" and got["name"] == "surprised"
    finally:
        pub.close()
        sub.close()
        ctx.term()
