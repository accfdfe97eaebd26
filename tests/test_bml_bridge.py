"""`eca bml-bridge` end to end: a private ActiveMQ broker (tests/support/activemq.py), `eca up` with the bml realizer
on a private bus, the bridge as a real process, and a STOMP client that is not eca's (stomp.py in the test) speaking
as AsapRealizer's, Greta's and the Virtual Human Toolkit's clients do: a block in, the standard's feedback (or the
VHMsg reply lines, Greta's callbacks) out; bad frames answered with warnings while the bridge lives on; and a broker
restart survived.

The commands it runs:
    java ... -jar /usr/share/activemq/bin/activemq.jar start xbean:file:<tmp>/activemq.xml   (STOMP on 127.0.0.1:P)
    eca up --config <tmp>/eca.toml --instance tXXXX --quiet --silent-audio     (services dialogue, gaze, audio, bml)
    eca bml-bridge --stomp 127.0.0.1:P --config <tmp>/eca.toml --instance tXXXX
"""

from __future__ import annotations

import logging
import threading
import time
import urllib.parse
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import pytest

from eca.services.processes.run import SERVICES as KNOWN_SERVICES
from eca.services.tools.child_processes import LineReader
from tests.support.activemq import ActiveMQ, activemq_missing, private_activemq
from tests.support.bus import eca_command, private_bus_config, running

NS = "http://www.bml-initiative.org/bml/bml-1.0"
SERVICES = ["dialogue", "gaze", "audio", "bml"]  # "bml": the realizer that answers the bridge's commands
SCOPE = "/topic/DEFAULT_SCOPE"

pytestmark = [pytest.mark.slow, pytest.mark.skipif(activemq_missing() is not None, reason=str(activemq_missing()))]


@dataclass(frozen=True)
class Got:
    destination: str
    headers: dict[str, str]
    body: str


class StompClient:
    """A plain stomp.py client, as the other systems' own clients are: subscribes with a receipt (so nothing sent
    after it is missed) and keeps every frame it receives."""

    def __init__(self, port: int, destinations: list[str]) -> None:
        import stomp  # type: ignore[import-untyped]

        self.frames: list[Got] = []
        self._cond = threading.Condition()
        self._receipts: set[str] = set()
        # content-length off: what it sends is a JMS TextMessage, as the Java clients' are
        self.conn = stomp.Connection([("127.0.0.1", port)], auto_content_length=False, heartbeats=(0, 0))
        self.conn.set_listener("test", self)
        self.conn.connect(wait=True)
        for i, destination in enumerate(destinations):
            self.conn.subscribe(destination, id=f"t{i}", ack="auto", headers={"receipt": f"r{i}"})
            self.wait_receipt(f"r{i}")

    def on_message(self, frame: Any) -> None:
        body = frame.body if isinstance(frame.body, str) else frame.body.decode("utf-8", "replace")
        with self._cond:
            self.frames.append(Got(frame.headers.get("destination", ""), dict(frame.headers), body))
            self._cond.notify_all()

    def on_receipt(self, frame: Any) -> None:
        with self._cond:
            self._receipts.add(frame.headers.get("receipt-id", ""))
            self._cond.notify_all()

    def wait_receipt(self, receipt: str, timeout_s: float = 10.0) -> None:
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while receipt not in self._receipts:
                left = deadline - time.monotonic()
                assert left > 0, f"no receipt {receipt} from the broker"
                self._cond.wait(left)

    def send(self, destination: str, body: str | bytes, headers: dict[str, str] | None = None,
             content_length: bool = False) -> None:
        extra = dict(headers or {})
        if content_length:  # a BytesMessage: the body's bytes reach the bridge as they are
            raw = body if isinstance(body, bytes) else body.encode()
            extra["content-length"] = str(len(raw))
        self.conn.send(destination, body, headers=extra)

    def wait(self, predicate: Callable[[Got], bool], timeout_s: float, what: str, logs: LineReader) -> Got:
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                for got in self.frames:
                    if predicate(got):
                        return got
                left = deadline - time.monotonic()
                if left <= 0:
                    seen = "\n".join(f"{g.destination}: {g.body[:200]}" for g in self.frames[-15:])
                    tail = "\n".join(logs.lines[-25:])
                    raise AssertionError(f"no {what} within {timeout_s} s; frames seen:\n{seen}\nlogs:\n{tail}")
                self._cond.wait(left)

    def clear(self) -> None:
        with self._cond:
            self.frames.clear()

    def close(self) -> None:
        try:
            self.conn.disconnect()
        except Exception:  # the broker may be gone (the restart test)
            pass


@pytest.fixture(scope="module")
def broker() -> Iterator[ActiveMQ]:
    with private_activemq() as amq:
        print(f"ActiveMQ STOMP on 127.0.0.1:{amq.port}, up in {amq.startup_s:.1f} s")
        yield amq


@pytest.fixture(scope="module")
def logs(broker: ActiveMQ) -> Iterator[LineReader]:
    """`eca up` (with the bml realizer) and the bridge; their merged output lines."""
    if "bml" not in KNOWN_SERVICES:
        pytest.skip("the bml realizer service (`eca up`'s 'bml') is not in this tree: the bridge's commands would "
                    "have no one to realize them")
    with private_bus_config(services=SERVICES) as config:
        up = eca_command("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet",
                         "--silent-audio")
        with running(up) as (_up, up_reader):
            up_reader.wait_for("[up] ready in", 90.0)
            bridge = eca_command("bml-bridge", "--stomp", f"127.0.0.1:{broker.port}", "--config",
                                 str(config.config_path), "--instance", config.instance)
            with running(bridge) as (proc, reader):
                reader.wait_for("subscribed to", 30.0)
                yield reader
                assert proc.poll() is None, "the bridge died:\n" + "\n".join(reader.lines[-30:])


@pytest.fixture
def client(broker: ActiveMQ, logs: LineReader) -> Iterator[StompClient]:
    c = StompClient(broker.port, ["/topic/asap.bml.feedback", "/topic/greta.output.feedback.BML", SCOPE])
    yield c
    c.close()


def nod(block: str, character: str = "ada") -> str:
    who = f' characterId="{character}"' if character else ""
    return f'<bml xmlns="{NS}" id="{block}"{who}><head id="h1" lexeme="NOD" amount="0.5"/></bml>'


def vh_send(client: StompClient, args: str) -> None:
    """A VHMsg line as the toolkit's clients send it: the prefix, then the rest URL-encoded."""
    client.send(SCOPE, "vrAgentBML " + urllib.parse.quote_plus(args, safe=""),
                {"ELVISH_SCOPE": "DEFAULT_SCOPE", "MESSAGE_PREFIX": "vrAgentBML"})


def vh_line(got: Got) -> str:
    prefix, _, rest = got.body.partition(" ")
    return f"{prefix} {urllib.parse.unquote_plus(rest)}"


def asap(block: str, what: str) -> Callable[[Got], bool]:
    return lambda g: g.destination.endswith("asap.bml.feedback") and what in g.body and block in g.body


def test_an_asap_block_gets_its_progress_back(client: StompClient, logs: LineReader) -> None:
    client.send("/topic/asap.bml.request", nod("asap1"))
    start = client.wait(asap("asap1", 'id="asap1:start"'), 20.0, "blockProgress start", logs)
    sync = client.wait(asap("asap1", "<syncPointProgress"), 20.0, "a syncPointProgress", logs)
    end = client.wait(asap("asap1", 'id="asap1:end"'), 20.0, "blockProgress end", logs)
    order = client.frames.index
    assert order(start) < order(sync) < order(end)
    assert start.body.lstrip().startswith("<blockProgress")
    assert "content-length" not in end.headers  # a JMS TextMessage, which AsapRealizer's adapter reads


def test_a_vhmsg_request_line_gets_start_and_end_complete(client: StompClient, logs: LineReader) -> None:
    vh_send(client, f"ada vh1 request {nod('vhblock', character='')}")
    start = client.wait(lambda g: vh_line(g) == "vrAgentBML ada vh1 start", 20.0, "vrAgentBML ... start", logs)
    end = client.wait(lambda g: vh_line(g).startswith("vrAgentBML ada vh1 end"), 20.0, "vrAgentBML ... end", logs)
    assert vh_line(end) == "vrAgentBML ada vh1 end complete"
    assert client.frames.index(start) < client.frames.index(end)
    assert end.headers.get("MESSAGE_PREFIX") == "vrAgentBML" and end.headers.get("ELVISH_SCOPE") == "DEFAULT_SCOPE"
    assert " " not in end.body.partition(" ")[2]  # the rest URL-encoded, as VHMsg clients decode it


def test_a_greta_block_gets_start_and_end_callbacks(client: StompClient, logs: LineReader) -> None:
    client.send("/topic/greta.BML", nod("greta1", character=""))

    def callback(kind: str) -> Callable[[Got], bool]:
        return lambda g: (g.destination.endswith("greta.output.feedback.BML")
                          and g.headers.get("feedback-type") == kind and g.headers.get("feedback-id") == "greta1")

    start = client.wait(callback("start"), 20.0, "Greta's start callback", logs)
    end = client.wait(callback("end"), 20.0, "Greta's end callback", logs)
    assert client.frames.index(start) < client.frames.index(end)
    assert int(end.headers["feedback-time"]) >= int(start.headers["feedback-time"])


def test_bad_frames_get_warnings_and_the_bridge_goes_on(client: StompClient, logs: LineReader) -> None:
    def warning(kind: str, block: str = "") -> Callable[[Got], bool]:
        return lambda g: (g.destination.endswith("asap.bml.feedback") and "<warningFeedback" in g.body
                          and f'type="{kind}"' in g.body and (not block or f'id="{block}"' in g.body))

    client.send("/topic/asap.bml.request", "hello, this is not BML")
    client.wait(warning("PARSING_FAILURE", "unknown"), 10.0, "a warning about text that is not XML", logs)
    client.clear()
    client.send("/topic/asap.bml.request", b'<bml id="latin1">caf\xe9</bml>', content_length=True)
    client.wait(warning("PARSING_FAILURE"), 10.0, "a warning about a body that is not UTF-8", logs)
    client.clear()
    client.send("/topic/asap.bml.request", nod("huge")[:-6] + "<!--" + "x" * 70_000 + "--></bml>")
    client.wait(warning("PARSING_FAILURE"), 10.0, "a warning about a body over 65,536 characters", logs)
    client.wait(lambda g: "65536" in g.body, 1.0, "the limit named", logs)
    client.clear()
    client.send("/topic/asap.bml.request", nod("stranger", character="nobody"))
    client.wait(warning("UNKNOWN_CHARACTER", "stranger"), 10.0, "a warning about an agent there is not", logs)
    client.clear()
    vh_send(client, "ada vh2 request")
    got = client.wait(lambda g: vh_line(g).startswith("vrAgentBML ada vh2 end"), 10.0, "a VHMsg error line", logs)
    assert vh_line(got).startswith("vrAgentBML ada vh2 end error PARSING_FAILURE")
    assert sum("frame refused" in line for line in logs.lines) >= 5
    client.clear()  # XML-looking but broken: the realizer refuses it, and the refusal comes back
    broken = f'<bml xmlns="{NS}" id="broken"><head id="h1" lexeme="NOD"></bml>'
    client.send("/topic/asap.bml.request", broken)
    client.wait(warning("PARSING_FAILURE"), 20.0, "the realizer's warning about a broken block", logs)
    vh_send(client, f"ada vh3 request {broken}")
    got = client.wait(lambda g: vh_line(g).startswith("vrAgentBML ada vh3 end"), 20.0, "a VHMsg error line", logs)
    assert vh_line(got).startswith("vrAgentBML ada vh3 end error PARSING_FAILURE")
    client.clear()
    client.send("/topic/asap.bml.request", nod("after"))  # still bridging
    client.wait(asap("after", 'id="after:end"'), 20.0, "the end of a good block after the bad ones", logs)


def test_a_flood_is_bounded_and_the_bridge_goes_on(broker: ActiveMQ, logs: LineReader) -> None:
    """20,000 bad frames as fast as one client sends them: the bridge drops what its queue cannot hold (counted), logs
    a bounded number of lines, and bridges a good block once the flood has passed. (A good block sent into the
    flood may be dropped with it: the test sends one every few seconds until one ends.)"""
    import stomp  # type: ignore[import-untyped]

    first = len(logs.lines)
    flooder = stomp.Connection([("127.0.0.1", broker.port)], auto_content_length=False)
    flooder.connect(wait=True)
    t0 = time.monotonic()
    for _ in range(20_000):  # Greta's topic: its warnings go where no test client listens
        flooder.send("/topic/greta.BML", "junk")
    flooder.disconnect()
    watcher = StompClient(broker.port, ["/topic/asap.bml.feedback"])
    try:
        deadline = time.monotonic() + 90.0
        for n in range(1000):
            watcher.send("/topic/asap.bml.request", nod(f"calm{n}"))
            try:
                watcher.wait(lambda g: 'id="calm' in g.body and ':end"' in g.body, 3.0, "", logs)
                break
            except AssertionError:
                assert time.monotonic() < deadline, "no block bridged after the flood:\n" + "\n".join(logs.lines[-20:])
    finally:
        watcher.close()
    lines = logs.lines[first:]
    refused_lines = sum("frame refused" in line for line in lines)
    assert refused_lines <= 10 * (time.monotonic() - t0 + 2)  # at most 10 a second, the rest counted
    assert any("more frames refused" in line or "flood: dropped" in line for line in lines)


def test_the_bridge_reconnects_after_the_broker_restarts(broker: ActiveMQ, logs: LineReader) -> None:
    lost_before = sum("connection lost" in line for line in logs.lines)
    start = len(logs.lines)
    broker.restart()
    logs.wait_for("reconnected after", 60.0, start)
    assert sum("connection lost" in line for line in logs.lines) == lost_before + 1  # once per outage
    fresh = StompClient(broker.port, ["/topic/asap.bml.feedback"])
    try:
        fresh.send("/topic/asap.bml.request", nod("again"))
        fresh.wait(asap("again", 'id="again:end"'), 20.0, "a block's end after the restart", logs)
    finally:
        fresh.close()


def test_heart_beats_find_a_frozen_broker_and_the_link_comes_back(caplog: pytest.LogCaptureFixture) -> None:
    """A broker that stops answering but keeps its socket open (SIGSTOP) is found by the STOMP heart-beats; the link
    says so once, and connects again when the broker is back. (The bridge's link alone, on a broker of its own.)"""
    import os
    import signal

    from eca.services.processes.bml_bridge import StompLink

    caplog.set_level(logging.INFO, logger="bml-bridge")
    with private_activemq() as amq:
        assert amq.proc is not None
        link = StompLink("127.0.0.1", amq.port, {"/topic/asap.bml.request": "asap"}, lambda frame: None,
                         heartbeat_ms=1000)
        link.start()
        try:
            until(lambda: link.connected, 20.0, "the link connecting")
            os.killpg(amq.proc.pid, signal.SIGSTOP)
            try:
                until(lambda: not link.connected, 15.0, "the heart-beats finding the frozen broker")
            finally:
                os.killpg(amq.proc.pid, signal.SIGCONT)
            until(lambda: link.connected and link.connections == 2, 30.0, "the link connecting again")
        finally:
            link.stop()
    said = [r.getMessage() for r in caplog.records if r.name == "bml-bridge"]
    assert sum("connection lost (no heart-beat from the broker)" in m for m in said) == 1, said
    assert sum("reconnected after" in m for m in said) == 1, said


def until(condition: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"no {what} within {timeout_s} s"
        time.sleep(0.05)
