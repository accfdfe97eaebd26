"""The broker: an XSUB/XPUB proxy with a last-value cache of state topics (zguide: "Last Value Cache").

Publishers connect to the XSUB side, subscribers to the XPUB side. The broker subscribes to
everything upstream, so it sees every state message and keeps the last one per topic; when a
subscription arrives (XPUB_VERBOSE passes every one, duplicates too) it sends the cached values that
match the new prefix, so a late joiner such as a restarted renderer has the current state at once.
Re-sent values also reach older subscribers of that topic; state messages are idempotent, so that
is harmless. A subscription to `sys.<nonce>.hello` is answered with a Hello: the subscriber's
readiness barrier.

A restarted broker starts with an empty cache; the owners of the states publish them again when they
see it subscribe (services/processes/runtime.py `on_new_broker`). Each state's `t_ns` orders its versions: a
state older than the cached one of its topic is stale (say, a re-publication racing a newer change) and
is neither cached nor forwarded, and one stamped in the future is forwarded but not cached, so no
publisher can pin a topic. The cache holds at most `MAX_CACHED_TOPICS` topics (the least recently
changed go first), so no flood of new topics can grow it without bound.

Agents come and go at run time (`create_agent`, `remove_agent`): the dialogue service's `state.*.agents` lists
the live ones. When it changes, the broker forgets the cached states of every agent it does not list, so a
visitor's agent, created and removed, leaves nothing behind; and from then on it caches a state of an agent
missing from the list only when the dialogue service sends it (a new agent's states come just before the list
that names it): what another service still says of a removed agent is forwarded, not kept.

With CURVE keys (docs/protocol.md §15) both sockets are CURVE servers and the broker is its context's ZAP
handler, in its own loop: a handshake is let in only with a client public key in `curve_allowed_dir` (or the
host's own key, with which its services connect), so nothing an unknown key sends reaches the proxy. Each
refusal is reported on `error.*.error` (kind `unauthorized`, the peer's address and key), rate-limited, so a
flood of bad handshakes costs the bus a few messages a second at most.
"""

from __future__ import annotations

import dataclasses
import fcntl
import logging
import os
import time
from pathlib import Path
from typing import Any

import zmq

from eca.protocol.bus import TopicCounts, parse_frames
from eca.protocol.codec import ProtocolError, encode
from eca.protocol.curve import CurveKeyError, CurveKeys, link_options, load_allowed, server_options
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import ALL_AGENTS, AgentsState, Error, Heartbeat, Hello, Message
from eca.protocol.topics import STATE_PREFIX, topic_for
from eca.services.processes.heap import freeze_startup_objects
from eca.services.processes.liveness import LivenessSender

log = logging.getLogger("broker")
BROKER_LOCK = "broker.lock"  # in the runtime directory
MAX_CACHED_TOPICS = 65_536
FUTURE_SLACK_NS = 5_000_000_000  # a state stamped further ahead of this host's clock is not cached
AGENTS_OWNER = "dialogue"  # the source whose state.*.agents says which agents live
_ALL = ALL_AGENTS.encode()


class BrokerAlreadyRunning(RuntimeError):
    pass


ZAP_ENDPOINT = "inproc://zeromq.zap.01"  # where libzmq asks its context's handler (RFC 27)
REPORT_KEY_EVERY_NS = 10_000_000_000  # one report per refused key (and address) at most this often
REPORT_MIN_GAP_NS = 250_000_000  # and at most four reports a second in all
MAX_REPORTED_KEYS = 4096  # refused keys remembered for the rate limit (a flood of fresh keys cycles them)


class ZapHandler:
    """The ZAP handler of the broker's context: admits CURVE handshakes whose client key is allowed.

    Run from the broker's loop (no thread: a refusal is reported through the broker's own socket, which no
    other thread may touch). The allowed folder is read again when it changes, so a key added or removed
    takes effect at the next handshake without a restart."""

    def __init__(self, ctx: zmq.Context[zmq.Socket[bytes]], keys: CurveKeys) -> None:
        self.keys = keys
        self.allowed: dict[bytes, str] = {}
        self._dir_mtime_ns = -1
        self.refused = 0
        self.unreported = 0  # refusals not reported (the rate limit) since the last report
        self._reported: dict[bytes, int] = {}  # key + address -> when it was last reported
        self._last_report_ns = 0
        self._reload()
        self.socket = ctx.socket(zmq.REP)
        self.socket.setsockopt(zmq.LINGER, 0)
        try:
            self.socket.bind(ZAP_ENDPOINT)
        except zmq.ZMQError as exc:
            self.socket.close()
            raise zmq.ZMQError(exc.errno, f"another ZAP handler serves this context ({exc})") from None

    def _reload(self) -> None:
        allowed = {self.keys.client_public: "this host's own key"}
        folder = self.keys.allowed_dir
        if folder is not None:
            try:
                mtime = folder.stat().st_mtime_ns
            except OSError:
                mtime = -2
            if mtime == self._dir_mtime_ns:
                return
            self._dir_mtime_ns = mtime
            try:
                allowed.update(load_allowed(folder))
            except CurveKeyError as exc:  # a bad file dropped in later: keep the list that was good
                log.error("allowed keys not re-read: %s", exc)
                if self.allowed:
                    return
        self.allowed = allowed

    def handle(self, report: Any) -> None:
        """Answer one ZAP request; `report(address, key_z85, reason)` is called for a refusal due a report."""
        frames = self.socket.recv_multipart(zmq.NOBLOCK)
        if len(frames) < 6:  # only libzmq talks here (inproc), but a reply must go back whatever came
            self.socket.send_multipart([b"1.0", frames[1] if len(frames) > 1 else b"", b"500", b"bad request",
                                        b"", b""])
            return
        request_id, address, mechanism, credentials = frames[1], frames[3], frames[5], frames[6:]
        if mechanism == b"CURVE" and len(credentials) == 1 and len(credentials[0]) == 32:
            key = zmq.utils.z85.encode(credentials[0])
            self._reload()
            if key in self.allowed:
                self.socket.send_multipart([b"1.0", request_id, b"200", b"OK", key, b""])
                return
            reason = "the key is not in the broker's allowed keys"
        else:
            key = b""
            reason = f"mechanism {mechanism[:16].decode(errors='replace')} is not allowed (CURVE only)"
        self.socket.send_multipart([b"1.0", request_id, b"400", b"unknown key", b"", b""])
        self.refused += 1
        now = time.monotonic_ns()
        tag = key + b"@" + address
        if now - self._last_report_ns < REPORT_MIN_GAP_NS or now - self._reported.get(tag, -REPORT_KEY_EVERY_NS) \
                < REPORT_KEY_EVERY_NS:
            self.unreported += 1
            return
        if tag not in self._reported and len(self._reported) >= MAX_REPORTED_KEYS:
            del self._reported[next(iter(self._reported))]
        self._reported.pop(tag, None)
        self._reported[tag] = now
        self._last_report_ns = now
        report(address.decode(errors="replace")[:64], key.decode(), reason)

    def close(self) -> None:
        self.socket.close()


class Broker:
    def __init__(self, config: BusConfig, ctx: zmq.Context[zmq.Socket[bytes]] | None = None) -> None:
        self.config = config
        self.ctx = ctx or zmq.Context.instance()
        self.cache: dict[bytes, list[bytes]] = {}
        self._cached_t_ns: dict[bytes, int] = {}
        self._by_agent: dict[bytes, set[bytes]] = {}  # agent -> its cached topics, to forget them at once
        self._live: frozenset[bytes] | None = None  # the agents the latest state.*.agents lists (None: none yet)
        self.stale = 0  # states dropped because the cache held a newer one of their topic
        self.failures = 0  # messages the broker failed on (a bug): dropped, counted
        self.started_ns = time.monotonic_ns()
        self._seq = TopicCounts()
        self._lock_fd: int | None = None
        self._lock_runtime_dir(config.runtime_dir)
        self.zap: ZapHandler | None = None
        if config.curve is not None:
            try:  # the handler first: a CURVE socket bound before it would let every key in
                self.zap = ZapHandler(self.ctx, config.curve)
            except BaseException:
                self._unlock()
                raise
        self.frontend = self.ctx.socket(zmq.XSUB)
        self.frontend.setsockopt(zmq.RCVHWM, config.hwm)
        self.frontend.setsockopt(zmq.LINGER, 0)
        # Protects the broker's memory from a runaway publisher; the codec's cap is the real check.
        self.frontend.setsockopt(zmq.MAXMSGSIZE, 4 * config.max_message_bytes)
        self.backend = self.ctx.socket(zmq.XPUB)
        self.backend.setsockopt(zmq.SNDHWM, config.hwm)
        self.backend.setsockopt(zmq.LINGER, 0)
        self.backend.setsockopt(zmq.XPUB_VERBOSE, 1)
        try:
            for sock in (self.frontend, self.backend):
                if config.curve is not None:
                    server_options(sock, config.curve)
                if config.remote_link:  # a subscriber gone silent past the timeout is dropped, its queue freed
                    link_options(sock, config.heartbeat_interval_s, config.heartbeat_timeout_s)
            self.frontend.bind(config.frontend)
            self.backend.bind(config.backend)
        except (zmq.ZMQError, CurveKeyError):
            self.close()  # a failed start leaves no socket or lock behind
            raise
        self.frontend.send(b"\x01")  # subscribe to everything: the cache must see every state message
        self.poller = zmq.Poller()
        self.poller.register(self.frontend, zmq.POLLIN)
        self.poller.register(self.backend, zmq.POLLIN)
        if self.zap is not None:
            self.poller.register(self.zap.socket, zmq.POLLIN)
        self.forwarded = 0

    def _lock_runtime_dir(self, runtime_dir: Path) -> None:
        # A second bind on a filesystem ipc path silently steals it; a lock file refuses instead.
        fd = os.open(runtime_dir / BROKER_LOCK, os.O_RDWR | os.O_CREAT, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise BrokerAlreadyRunning(f"a broker already serves instance '{self.config.instance}' "
                                       f"in {runtime_dir}") from None
        self._lock_fd = fd

    def step(self, timeout_ms: int) -> int:
        """Move everything that is waiting (up to a batch); returns the number of messages handled."""
        handled = 0
        events = dict(self.poller.poll(timeout_ms))
        if self.frontend in events:
            for _ in range(1000):
                try:
                    frames = self.frontend.recv_multipart(zmq.NOBLOCK)
                except zmq.Again:
                    break
                self._guarded(self._forward, frames)
                handled += 1
        if self.backend in events:
            for _ in range(1000):
                try:
                    event = self.backend.recv(zmq.NOBLOCK)
                except zmq.Again:
                    break
                self._guarded(self._on_subscription, event)
                handled += 1
        if self.zap is not None and self.zap.socket in events:
            for _ in range(100):
                if not self.zap.socket.poll(0, zmq.POLLIN):
                    break
                self._guarded(self.zap.handle, self._report_refused)
                handled += 1
        return handled

    def _report_refused(self, address: str, key: str, reason: str) -> None:
        assert self.zap is not None
        more = f"; {self.zap.unreported} more refusals not reported since the last report" \
            if self.zap.unreported else ""
        self.zap.unreported = 0
        log.warning("refused a CURVE handshake from %s, key %s: %s", address, key or "-", reason)
        self._send_own(Error(agent=ALL_AGENTS, kind="unauthorized", service="broker",
                             reason=f"refused a connection from {address} with key {key or '-'}: {reason}{more}"))

    def _guarded(self, handle: Any, item: Any) -> None:
        # Whatever one message does to a bug in here, the broker and its cache stay up for the rest.
        try:
            handle(item)
        except Exception:
            self.failures += 1
            if self.failures == 1:
                log.exception("failed on one message (dropped it; further failures are only counted)")

    def _forward(self, frames: list[bytes]) -> None:
        if len(frames) == 2 and frames[0].startswith(STATE_PREFIX) and not self._cache_state(frames):
            self.stale += 1
            return
        self.backend.send_multipart(frames)
        self.forwarded += 1

    def _cache_state(self, frames: list[bytes]) -> bool:
        """Cache a state message if it is valid and not stale; False if it is stale (to be dropped)."""
        # Only valid state is cached: a late joiner must never be handed garbage as "current".
        msg = parse_frames(frames, self.config.max_message_bytes).message
        if msg is None:
            return True
        topic = frames[0]
        cached_t_ns = self._cached_t_ns.get(topic)
        if cached_t_ns is not None and msg.t_ns < cached_t_ns:
            return False
        if msg.t_ns > time.monotonic_ns() + FUTURE_SLACK_NS:
            return True
        agent = topic.split(b".", 2)[1]
        if self._live is not None and agent not in self._live and agent != _ALL and msg.source != AGENTS_OWNER:
            return True  # an agent removed (its last words from a service that had not heard yet): not kept
        if cached_t_ns is not None:
            del self.cache[topic]  # re-inserted at the end: the dict's order is the order of change
        elif len(self.cache) >= MAX_CACHED_TOPICS:
            self._forget(next(iter(self.cache)))
        self.cache[topic] = frames
        self._cached_t_ns[topic] = msg.t_ns
        self._by_agent.setdefault(agent, set()).add(topic)
        if isinstance(msg, AgentsState) and msg.source == AGENTS_OWNER:
            self._follow(msg)
        return True

    def _follow(self, listing: AgentsState) -> None:
        """Forget the cached states of every agent the new list of live agents does not name."""
        self._live = frozenset(a.encode() for a in listing.agents)
        for agent in [a for a in self._by_agent if a not in self._live and a != _ALL]:
            for topic in list(self._by_agent[agent]):
                self._forget(topic)

    def _forget(self, topic: bytes) -> None:
        del self.cache[topic], self._cached_t_ns[topic]
        agent = topic.split(b".", 2)[1]
        topics = self._by_agent.get(agent)
        if topics is not None:
            topics.discard(topic)
            if not topics:
                del self._by_agent[agent]

    def _on_subscription(self, event: bytes) -> None:
        if not event or event[0] != 1:
            return  # an unsubscription: nothing to do
        prefix = event[1:]
        if prefix.startswith(b"sys.") and prefix.endswith(b".hello") and prefix.count(b".") == 2:
            nonce = prefix.decode("utf-8", "replace").split(".")[1]
            self._send_own(Hello(agent=nonce))
            return
        for topic, frames in list(self.cache.items()):
            if topic.startswith(prefix):
                self.backend.send_multipart(frames)

    def heartbeat(self) -> Heartbeat:
        refused = self.zap.refused if self.zap is not None else 0
        return self._send_own(Heartbeat(agent=ALL_AGENTS, service="broker", pid=os.getpid(),
                                        started_ns=self.started_ns, dropped=self.stale + self.failures,
                                        bad_messages=refused))  # type: ignore[return-value]

    def _send_own(self, msg: Message) -> Message:
        topic = topic_for(msg)
        seq = self._seq.next(topic)
        self._seq.sent(topic, seq)
        stamped = dataclasses.replace(msg, seq=seq, t_ns=time.monotonic_ns(), source="broker")
        try:
            payload = encode(stamped)
        except ProtocolError as exc:  # a probe with a malformed nonce: ignore it, never crash
            log.warning("not answering %s: %s", topic[:80], exc)
            return stamped
        self.backend.send_multipart([topic.encode(), payload])
        return stamped

    def close(self) -> None:
        self.frontend.close()
        self.backend.close()
        if self.zap is not None:
            self.zap.close()
        self._unlock()

    def _unlock(self) -> None:
        if self._lock_fd is not None:
            # the socket files are this broker's (it holds the lock): none stays behind a clean stop
            for endpoint in (self.config.frontend, self.config.backend):
                if endpoint.startswith("ipc://"):
                    Path(endpoint.removeprefix("ipc://")).unlink(missing_ok=True)
            os.close(self._lock_fd)
            self._lock_fd = None


def run_broker(config: BusConfig, parent_pid: int | None = None, liveness: str | None = None) -> int:
    """The broker process's loop: move messages, beat, stop on SIGINT/SIGTERM or supervisor death."""
    import signal
    import threading

    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        broker = Broker(config)
    except (BrokerAlreadyRunning, zmq.ZMQError, CurveKeyError) as exc:
        log.error("cannot start: %s", exc)
        return 2
    freeze_startup_objects()
    log.info("ready (pid %d): publishers -> %s, subscribers -> %s", os.getpid(), config.frontend,
             config.backend)
    supervisor = LivenessSender(broker.ctx, liveness) if liveness else None
    interval_ns = int(config.heartbeat_interval_s * 1e9)
    next_beat = 0
    try:
        while not stop.is_set():
            now = time.monotonic_ns()
            if now >= next_beat:
                beat = broker.heartbeat()
                if supervisor is not None:
                    supervisor.beat(beat)
                next_beat = now + interval_ns
                if parent_pid is not None and os.getppid() != parent_pid:
                    log.warning("supervisor %d is gone: stopping", parent_pid)
                    break
            broker.step(min(100, max(0, (next_beat - now) // 1_000_000)))
    finally:
        if supervisor is not None:
            supervisor.close()
        broker.close()
    log.info("stopped")
    return 0
