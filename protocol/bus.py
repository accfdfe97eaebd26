"""Sockets onto the eca bus: a publisher and a subscriber that speak the codec, with readiness barriers.

Publishers connect an XPUB to the broker's XSUB. The broker subscribes to everything, and an XPUB
sees that subscription arrive: that is the publisher's readiness barrier (no message sent before it is
lost to the slow-joiner problem). Subscribers connect a SUB to the broker's XPUB; their barrier is a
probe subscription `sys.<nonce>.hello` that the broker answers once the subscription is live.
Every option (HWM, linger) is set before connect: options set later do not take.
"""

from __future__ import annotations

import secrets
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import zmq

from protocol.codec import DEFAULT_MAX_BYTES, ProtocolError, decode, encode
from protocol.endpoints import BusConfig
from protocol.messages import Hello, Message
from protocol.topics import split_topic, topic_for


class BusTimeout(TimeoutError):
    """A readiness barrier or a wait did not complete in time."""


def _now_ns() -> int:
    return time.monotonic_ns()


class Publisher:
    """Stamps each message with sequence number, time and source, validates it, and sends it."""

    def __init__(self, ctx: zmq.Context, config: BusConfig, source: str,
                 now_ns: Callable[[], int] = _now_ns) -> None:
        self.source = source
        self._now_ns = now_ns
        self._max_bytes = config.max_message_bytes
        self._seq = 0
        self.socket = ctx.socket(zmq.XPUB)
        self.socket.setsockopt(zmq.SNDHWM, config.hwm)
        self.socket.setsockopt(zmq.LINGER, 500)  # let the last events out on a clean stop
        self.socket.connect(config.frontend)

    def wait_ready(self, timeout_s: float = 5.0) -> None:
        """Block until the broker's subscription arrives, so nothing sent afterwards is lost."""
        if not self.socket.poll(int(timeout_s * 1000), zmq.POLLIN):
            raise BusTimeout(f"no broker subscription within {timeout_s} s: is the broker running?")
        self._drain_subscriptions()

    def publish(self, msg: Message, category: str | None = None) -> Message:
        """Send `msg` (stamped); returns the stamped copy. Raises ProtocolError if it is invalid."""
        self._seq += 1
        stamped = _stamped(msg, self._seq, msg.t_ns or self._now_ns(), self.source)
        payload = encode(stamped, self._max_bytes)
        self.socket.send_multipart([topic_for(stamped, category).encode(), payload])
        return stamped

    def send_raw(self, topic: bytes, payload: bytes) -> None:
        """Send frames as they are (tests of bad input, replay of recordings)."""
        self.socket.send_multipart([topic, payload])

    def _drain_subscriptions(self) -> None:
        while self.socket.poll(0, zmq.POLLIN):
            self.socket.recv_multipart(zmq.NOBLOCK)

    def close(self) -> None:
        self.socket.close()


def _stamped(msg: Message, seq: int, t_ns: int, source: str) -> Message:
    """A copy with the envelope filled in. Faster than dataclasses.replace, which re-runs __init__;
    safe because the body was already built (and is validated again by the encoder)."""
    copy = object.__new__(type(msg))
    copy.__dict__.update(msg.__dict__)
    copy.__dict__.update(seq=seq, t_ns=t_ns, source=source)
    return copy


@dataclass(frozen=True)
class Received:
    """One message off the bus: decoded, or the reason it could not be."""

    topic: str
    message: Message | None
    error: ProtocolError | None = None


class Subscriber:
    def __init__(self, ctx: zmq.Context, config: BusConfig, prefixes: Iterable[str] = ("",),
                 max_message_bytes: int | None = None) -> None:
        self._max_bytes = max_message_bytes or config.max_message_bytes or DEFAULT_MAX_BYTES
        self.socket = ctx.socket(zmq.SUB)
        self.socket.setsockopt(zmq.RCVHWM, config.hwm)
        self.socket.setsockopt(zmq.LINGER, 0)
        self._probe = ""
        # The last-value cache re-sends a state to every subscriber of its topic when someone new
        # subscribes; a byte-identical repeat carries nothing new.
        self._last_state: dict[str, bytes] = {}
        for p in prefixes:
            self.socket.setsockopt(zmq.SUBSCRIBE, p.encode())
        self.socket.connect(config.backend)

    def subscribe(self, prefix: str) -> None:
        self.socket.setsockopt(zmq.SUBSCRIBE, prefix.encode())

    def unsubscribe(self, prefix: str) -> None:
        self.socket.setsockopt(zmq.UNSUBSCRIBE, prefix.encode())

    def wait_ready(self, timeout_s: float = 5.0) -> list[Received]:
        """Block until the broker answers a probe subscription, so every later message reaches us.

        Returns whatever else arrived meanwhile (last values from the broker's cache among them)."""
        nonce = secrets.token_hex(8)
        self._probe = f"sys.{nonce}.hello"
        self.socket.setsockopt(zmq.SUBSCRIBE, self._probe.encode())
        deadline = time.monotonic() + timeout_s
        early: list[Received] = []
        try:
            while True:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise BusTimeout(f"no answer from the broker within {timeout_s} s: is it running?")
                got = self.recv(left)
                if got is None:
                    continue
                if got.topic == self._probe and isinstance(got.message, Hello):
                    return early
                early.append(got)
        finally:
            self.socket.setsockopt(zmq.UNSUBSCRIBE, self._probe.encode())

    def recv(self, timeout_s: float) -> Received | None:
        """One message, or None when nothing arrived within the timeout."""
        deadline = time.monotonic() + timeout_s
        while self.socket.poll(max(0, int((deadline - time.monotonic()) * 1000)), zmq.POLLIN):
            got = self._read()
            if got is not None:
                return got
        return None

    def drain(self, limit: int = 100_000) -> list[Received]:
        """Everything waiting now, without blocking."""
        out: list[Received] = []
        while len(out) < limit and self.socket.poll(0, zmq.POLLIN):
            got = self._read()
            if got is not None:
                out.append(got)
        return out

    def _read(self) -> Received | None:
        return self.accept(self.socket.recv_multipart(zmq.NOBLOCK))

    def accept(self, frames: list[bytes]) -> Received | None:
        """Decode frames read off this socket; None for what a subscriber skips: another subscriber's
        readiness probe, or a state the last-value cache re-sent unchanged. For callers that read the
        socket themselves (in batches) and must skip the same."""
        got = parse_frames(frames, self._max_bytes)
        msg = got.message
        if isinstance(msg, Hello) and got.topic != self._probe:
            return None  # another subscriber's readiness probe (seen by a catch-all subscription)
        if msg is not None and msg.CATEGORY == "state":
            # byte-identical = the same message re-sent (a restarted publisher's seq starts again at 1)
            if self._last_state.get(got.topic) == frames[1]:
                return None
            self._last_state[got.topic] = frames[1]
        return got

    def close(self) -> None:
        self.socket.close()


def parse_frames(frames: list[bytes], max_bytes: int = DEFAULT_MAX_BYTES) -> Received:
    """Decode [topic, payload]; a message whose topic disagrees with its content is rejected."""
    if len(frames) != 2:
        return Received("", None, ProtocolError("bad_frames", f"expected 2 frames, got {len(frames)}"))
    try:
        topic = frames[0].decode("utf-8")
    except UnicodeDecodeError:
        return Received(repr(frames[0][:64]), None, ProtocolError("bad_topic", "topic is not UTF-8"))
    try:
        msg = decode(frames[1], max_bytes)
        _, agent, type_name = split_topic(topic)
    except ProtocolError as exc:
        return Received(topic, None, exc)
    except ValueError as exc:
        return Received(topic, None, ProtocolError("bad_topic", str(exc)))
    if agent != msg.agent or type_name != msg.TYPE:
        return Received(topic, None, ProtocolError(
            "bad_topic", f"topic {topic!r} does not match a '{msg.TYPE}' message for agent '{msg.agent}'"))
    return Received(topic, msg)
