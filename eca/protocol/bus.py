"""Sockets onto the eca bus: a publisher and a subscriber that speak the codec, with readiness barriers.

Publishers connect an XPUB to the broker's XSUB. The broker subscribes to everything, and an XPUB
sees that subscription arrive: that is the publisher's readiness barrier (no message sent before it is
lost to the slow-joiner problem). The XPUB is verbose, so a broker that restarts (and subscribes again
over the same reconnected pipe) is seen too: `new_broker()` tells the owner of a state to publish it
again for the new broker's empty cache (the zguide's Clone pattern).
Subscribers connect a SUB to the broker's XPUB; their barrier is a probe subscription
`sys.<nonce>.hello` that the broker answers once the subscription is live.
Every option (HWM, linger, CURVE keys, ZMTP heartbeats) is set before connect: options set later do not take.
Over TCP (a link that can drop and heal, docs/protocol.md §15) each socket sends ZMTP heartbeats, so a link
that stays silent past the heartbeat timeout is dropped and made again when the network is back: the
subscriber's subscriptions reach the broker again, and its last-value cache answers them with the current
states (the Clone pattern's snapshot) instead of a backlog of old ones.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import zmq

from eca.protocol.codec import DEFAULT_MAX_BYTES, ProtocolError, decode, encode
from eca.protocol.curve import client_options, link_options
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import Hello, Message
from eca.protocol.topics import split_topic, topic_for


class BusTimeout(TimeoutError):
    """A readiness barrier or a wait did not complete in time."""


MAX_TOPICS_KEPT = 65_536  # per socket: topics whose count or last state is remembered
STALE_WINDOW_NS = 60_000_000_000  # a state older than the held one by more than this is taken as new


class TopicCounts:
    """Messages sent per topic, for `seq`. Bounded: peers choose topics (an error goes to the offending
    message's agent), so the oldest topics are forgotten past MAX_TOPICS_KEPT (a forgotten topic counts
    from 1 again, as after a restart)."""

    def __init__(self) -> None:
        self._counts: dict[str, int] = {}

    def next(self, topic: str) -> int:
        return self._counts.get(topic, 0) + 1

    def sent(self, topic: str, seq: int) -> None:
        if topic not in self._counts and len(self._counts) >= MAX_TOPICS_KEPT:
            del self._counts[next(iter(self._counts))]
        self._counts[topic] = seq


def _now_ns() -> int:
    return time.monotonic_ns()


_AUTH_FAILED = zmq.EVENT_HANDSHAKE_FAILED_AUTH | zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL


class _Link:
    """The options of a socket onto the broker (CURVE keys, heartbeats over TCP) and, with CURVE, a monitor
    of its handshakes: a broker that refuses this host's key says nothing to the sockets themselves (their
    messages just go nowhere), so without it a refused client could only say "no broker"."""

    def __init__(self, sock: zmq.Socket[bytes], config: BusConfig) -> None:
        self._config = config
        self._monitor: zmq.Socket[bytes] | None = None
        if config.curve is not None:
            client_options(sock, config.curve)
            self._monitor = sock.get_monitor_socket(_AUTH_FAILED)
        if config.remote_link:
            link_options(sock, config.heartbeat_interval_s, config.heartbeat_timeout_s)
        self._sock = sock

    def refused(self) -> str | None:
        """Why the broker refused this socket's handshake, when it did (never blocks)."""
        if self._monitor is None:
            return None
        from zmq.utils.monitor import recv_monitor_message

        why = None
        while self._monitor.poll(0, zmq.POLLIN):
            event = recv_monitor_message(self._monitor, zmq.NOBLOCK)
            keys = self._config.curve
            assert keys is not None
            if event["event"] == zmq.EVENT_HANDSHAKE_FAILED_AUTH:
                why = (f"the broker at {event['endpoint'].decode(errors='replace')} refused this host's key "
                       f"{keys.client_public.decode()} ({keys.client_key_file}; status {event['value']}): add its "
                       f"public key file to the broker's curve_allowed_dir")
            else:
                why = (f"the CURVE handshake with {event['endpoint'].decode(errors='replace')} failed: is "
                       f"curve_server_key ({keys.server_key_file}) the broker's key?")
        return why

    def timeout(self, default: str) -> BusTimeout:
        return BusTimeout(self.refused() or default)

    def close(self) -> None:
        if self._monitor is not None:
            self._sock.disable_monitor()
            self._monitor.close(linger=0)
            self._monitor = None


class Publisher:
    """Stamps each message with sequence number, time and source, validates it, and sends it.

    `seq` counts per topic: the n-th message this publisher sent on that topic, so a subscriber of any
    prefix can tell a lost message (a gap) from messages on topics it does not receive."""

    def __init__(self, ctx: zmq.Context[zmq.Socket[bytes]], config: BusConfig, source: str,
                 now_ns: Callable[[], int] = _now_ns) -> None:
        self.source = source
        self._now_ns = now_ns
        self._max_bytes = config.max_message_bytes
        self._seq = TopicCounts()
        self.brokers_seen = 0  # subscriptions from a broker: the first connection, then one per restart
        self.socket = ctx.socket(zmq.XPUB)
        self.socket.setsockopt(zmq.SNDHWM, config.hwm)
        self.socket.setsockopt(zmq.LINGER, 500)  # let the last events out on a clean stop
        # every subscription frame, repeats included: a restarted broker re-subscribes over the same pipe
        self.socket.setsockopt(zmq.XPUB_VERBOSE, 1)
        self.link = _Link(self.socket, config)
        self.socket.connect(config.frontend)

    def wait_ready(self, timeout_s: float = 5.0) -> None:
        """Block until the broker's subscription arrives, so nothing sent afterwards is lost."""
        if not self.socket.poll(int(timeout_s * 1000), zmq.POLLIN):
            raise self.link.timeout(f"no broker subscription within {timeout_s:g} s: is the broker running?")
        self._drain_subscriptions()

    def new_broker(self) -> bool:
        """Whether a broker subscribed since the last call after the first: a broker restarted, and
        whatever its last-value cache held is gone. Never blocks."""
        before = self.brokers_seen
        self._drain_subscriptions()
        return before > 0 and self.brokers_seen > before

    def publish(self, msg: Message, category: str | None = None) -> Message:
        """Send `msg` (stamped); returns the stamped copy. Raises ProtocolError if it is invalid."""
        topic, payload, stamped = self.prepare(msg, category)
        self.socket.send_multipart([topic, payload])
        return stamped

    def prepare(self, msg: Message, category: str | None = None) -> tuple[bytes, bytes, Message]:
        """Stamp and encode `msg` as `publish` would, without sending it: (topic, payload, stamped copy).
        Counts toward the topic's `seq`, so send what it returns (with `send_raw`) before anything else
        on that topic."""
        topic = topic_for(msg, category)
        seq = self._seq.next(topic)
        stamped = _stamped(msg, seq, msg.t_ns or self._now_ns(), self.source)
        payload = encode(stamped, self._max_bytes)  # an invalid message raises here and leaves no gap in seq
        self._seq.sent(topic, seq)
        return topic.encode(), payload, stamped

    def send_raw(self, topic: bytes, payload: bytes) -> None:
        """Send frames as they are: a state re-published exactly as it was first sent (same seq, time and
        bytes, so subscribers recognise the repeat), replay of recordings, tests of bad input."""
        self.socket.send_multipart([topic, payload])

    def _drain_subscriptions(self) -> None:
        while self.socket.poll(0, zmq.POLLIN):
            frame = self.socket.recv_multipart(zmq.NOBLOCK)[0]
            if frame == b"\x01":  # the broker's subscribe-to-everything
                self.brokers_seen += 1

    def close(self) -> None:
        self.link.close()
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
    def __init__(self, ctx: zmq.Context[zmq.Socket[bytes]], config: BusConfig, prefixes: Iterable[str] = ("",),
                 max_message_bytes: int | None = None) -> None:
        self._max_bytes = max_message_bytes or config.max_message_bytes or DEFAULT_MAX_BYTES
        self.socket = ctx.socket(zmq.SUB)
        self.socket.setsockopt(zmq.RCVHWM, config.hwm)
        self.socket.setsockopt(zmq.LINGER, 0)
        self._probe = ""
        # The last-value cache re-sends a state to every subscriber of its topic when someone new
        # subscribes; a byte-identical repeat carries nothing new.
        self._last_state: dict[str, bytes] = {}
        # (source, t_ns) of the last state taken per topic: an older one from the same publisher is stale
        self._last_stamp: dict[str, tuple[str, int]] = {}
        self.stale = 0  # states skipped as older than the one already held for their topic
        for p in prefixes:
            self.socket.setsockopt(zmq.SUBSCRIBE, p.encode())
        self.link = _Link(self.socket, config)
        self.socket.connect(config.backend)

    def subscribe(self, prefix: str) -> None:
        self.socket.setsockopt(zmq.SUBSCRIBE, prefix.encode())

    def unsubscribe(self, prefix: str) -> None:
        self.socket.setsockopt(zmq.UNSUBSCRIBE, prefix.encode())

    def wait_ready(self, timeout_s: float = 5.0) -> list[Received]:
        """Block until the broker answers a probe subscription, so every later message reaches us.

        Returns whatever else arrived meanwhile (last values from the broker's cache among them)."""
        nonce = os.urandom(8).hex()  # as secrets.token_hex(8), without loading OpenSSL (hashlib) in every process
        self._probe = f"sys.{nonce}.hello"
        self.socket.setsockopt(zmq.SUBSCRIBE, self._probe.encode())
        deadline = time.monotonic() + timeout_s
        early: list[Received] = []
        try:
            while True:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise self.link.timeout(f"no answer from the broker within {timeout_s} s: is it running?")
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

    def read_frames(self, limit: int) -> list[list[bytes]]:
        """Up to `limit` messages waiting now, undecoded (for callers that choose what to decode)."""
        frames: list[list[bytes]] = []
        while len(frames) < limit:
            try:
                frames.append(self.socket.recv_multipart(zmq.NOBLOCK))
            except zmq.Again:
                break
        return frames

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
            if self._is_stale(got.topic, msg):
                self.stale += 1
                return None
            if got.topic not in self._last_state and len(self._last_state) >= MAX_TOPICS_KEPT:
                del self._last_state[next(iter(self._last_state))]  # bounded: peers choose topics
                self._last_stamp.pop(next(iter(self._last_stamp)), None)
            self._last_state[got.topic] = frames[1]
            self._last_stamp[got.topic] = (msg.source, msg.t_ns)
        return got

    def _is_stale(self, topic: str, msg: Message) -> bool:
        """Whether `msg` is older than the state already taken for `topic` from the same publisher: one that
        waited out a partition behind a newer one is never applied as current (docs/protocol.md §15). Only
        stamps of one source are compared (monotonic clocks of different hosts are not comparable), and one
        older by more than STALE_WINDOW_NS is taken as new: its host restarted its clock (a reboot), or the
        one held was stamped far ahead, and no publisher pins a topic at a subscriber for longer."""
        held = self._last_stamp.get(topic)
        if held is None or held[0] != msg.source or not msg.t_ns or not held[1]:
            return False
        return held[1] - STALE_WINDOW_NS <= msg.t_ns < held[1]

    def close(self) -> None:
        self.link.close()
        self.socket.close()


class LinkWatch:
    """Whether the broker is there, from its own heartbeats (`sys.*.heartbeat` from `broker`, docs/protocol.md
    §10): none for the heartbeat timeout means the link is down (a partition, a broker gone), whatever the
    sockets think. Its own SUB socket, so it neither takes nor misses the owner's messages; `up()` reads what
    came and never blocks."""

    def __init__(self, ctx: zmq.Context[zmq.Socket[bytes]], config: BusConfig) -> None:
        self.timeout_ns = int(config.heartbeat_timeout_s * 1e9)
        self.socket = ctx.socket(zmq.SUB)
        self.socket.setsockopt(zmq.RCVHWM, 1000)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.SUBSCRIBE, b"sys.*.heartbeat")
        self.link = _Link(self.socket, config)
        self.socket.connect(config.backend)
        self.last_beat_ns = time.monotonic_ns()  # its owner passed the readiness barriers just now
        self.beats = 0
        self.broker_started_ns = 0  # the broker's started_ns: a new value means a new broker

    def up(self) -> bool:
        while self.socket.poll(0, zmq.POLLIN):
            frames = self.socket.recv_multipart(zmq.NOBLOCK)
            if len(frames) != 2 or b"broker" not in frames[1]:
                continue  # another service's beat: decoding it is not needed to know that
            msg = parse_frames(frames).message
            if msg is not None and getattr(msg, "service", "") == "broker" and msg.source == "broker":
                self.last_beat_ns = time.monotonic_ns()
                self.beats += 1
                self.broker_started_ns = getattr(msg, "started_ns", 0)
        return self.silent_ns() <= self.timeout_ns

    def silent_ns(self) -> int:
        """How long since the broker's last heartbeat arrived."""
        return time.monotonic_ns() - self.last_beat_ns

    def close(self) -> None:
        self.link.close()
        self.socket.close()


MAX_TOPIC_BYTES = 256  # `<category>.<agent>.<type>` needs far less; the Error message's topic field holds this


def parse_frames(frames: list[bytes], max_bytes: int = DEFAULT_MAX_BYTES) -> Received:
    """Decode [topic, payload]; a message whose topic disagrees with its content is rejected.

    Never raises: whatever the frames hold, the answer is a message or the reason there is none, and
    the reason's topic is the first frame when that reads as one (so the error reaches the agent's
    error topic even for a message with the wrong number of frames)."""
    try:
        got = _parse_frames(frames, max_bytes)
    except Exception as exc:  # a bug in decoding must cost one message, never the process that reads it
        return Received(_topic_of(frames), None, ProtocolError(
            "internal", f"the message could not be decoded (an eca bug: {type(exc).__name__})"))
    if got.error is not None:
        # The error outlives this call (in the Received), and its traceback, and that of the exception it
        # was raised from, hold the decoder's frames, their callers' and so the caller's whole batch of
        # messages, in a cycle only a full garbage collection frees: under a flood of garbage, memory kept.
        got.error.__traceback__ = None
        got.error.__context__ = None
    return got


def _parse_frames(frames: list[bytes], max_bytes: int) -> Received:
    topic = _topic_of(frames)
    if len(frames) != 2:
        return Received(topic, None, ProtocolError("bad_frames", f"expected 2 frames (topic, payload), "
                                                                 f"got {len(frames)}"))
    if len(frames[0]) > MAX_TOPIC_BYTES:
        return Received(topic, None, ProtocolError("bad_topic", f"the topic is {len(frames[0])} bytes, over the "
                                                                f"limit of {MAX_TOPIC_BYTES}"))
    try:
        frames[0].decode("utf-8")
    except UnicodeDecodeError:
        return Received(topic, None, ProtocolError("bad_topic", "the topic is not UTF-8"))
    try:
        msg = decode(frames[1], max_bytes)
        _, agent, type_name = split_topic(topic)
    except ProtocolError as exc:
        return Received(topic, None, exc)
    except ValueError as exc:
        return Received(topic, None, ProtocolError("bad_topic", str(exc)))
    if agent != msg.agent or type_name != msg.TYPE:
        return Received(topic, None, ProtocolError(
            "bad_topic", f"topic {topic!r} does not match a '{msg.TYPE}' message for agent '{msg.agent}'",
            agent=msg.agent, request_id=getattr(msg, "request_id", "") or ""))
    return Received(topic, msg)


def _topic_of(frames: list[bytes]) -> str:
    """The first frame as text for reports: cut to the topic limit, undecodable bytes replaced."""
    if not frames:
        return ""
    return bytes(frames[0][:MAX_TOPIC_BYTES]).decode("utf-8", "replace")
