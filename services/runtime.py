"""The base every eca process runs on: config, bus sockets, a poll loop, heartbeats, bad input, signals.

A service subclass names its subscriptions, registers one handler per message type and, if it has
periodic work, a tick rate. The loop never blocks longer than the next due tick or heartbeat (and at
most 100 ms, so a stop request or the death of the supervisor is noticed promptly).
"""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import Any, TypeVar

import zmq

from agent.clock import Clock, MonotonicClock
from protocol.bus import Publisher, Received, Subscriber
from protocol.codec import ProtocolError, is_agent_id
from protocol.endpoints import BusConfig
from protocol.messages import ALL_AGENTS, Error, Heartbeat, Message

M = TypeVar("M", bound=Message)
_MAX_WAIT_S = 0.1


class Rejected(ValueError):
    """Raised by a handler for a well-formed message it refuses (unknown emotion, unknown request).

    The handler must raise before it changes any state; the runtime reports the reason on the error
    topic."""

    def __init__(self, reason: str, request_id: str = "", kind: str = "rejected") -> None:
        super().__init__(reason)
        self.reason = reason
        self.request_id = request_id
        self.kind = kind


def setup_logging(name: str, level: int = logging.INFO) -> None:
    logging.basicConfig(level=level, stream=sys.stderr, force=True,
                        format=f"[{name}] %(levelname)s %(message)s")


class Service:
    """One eca process: bus in -> models -> bus out."""

    name = "service"
    tick_hz: float | None = None

    def __init__(self, config: BusConfig, *, clock: Clock | None = None, ctx: zmq.Context | None = None,
                 parent_pid: int | None = None) -> None:
        self.config = config
        self.clock = clock or MonotonicClock()
        self.ctx = ctx or zmq.Context.instance()
        self.log = logging.getLogger(self.name)
        self.parent_pid = parent_pid
        self.started_ns = self.clock.now_ns()
        self.bad_messages: Counter[str] = Counter()
        self._handlers: dict[type[Message], Callable[[Any], None]] = {}
        self._stop = threading.Event()
        self.pub: Publisher | None = None
        self.sub: Subscriber | None = None
        self._next_beat_ns = 0
        self._next_tick_ns = 0

    # --- what subclasses fill in -------------------------------------------------------------

    def subscriptions(self) -> list[str]:
        return []

    def setup(self) -> None:
        """Called once the sockets are ready, before the first message."""

    def on_tick(self, now_ns: int) -> None:
        """Periodic work at `tick_hz`."""

    def teardown(self) -> None:
        """Called once after the loop ends."""

    def handle(self, cls: type[M], handler: Callable[[M], None]) -> None:
        self._handlers[cls] = handler

    # --- the loop --------------------------------------------------------------------------------

    def request_stop(self) -> None:
        self._stop.set()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def connect(self, timeout_s: float = 10.0) -> None:
        self.pub = Publisher(self.ctx, self.config, self.name, now_ns=self.clock.now_ns)
        self.sub = Subscriber(self.ctx, self.config, self.subscriptions())
        self.pub.wait_ready(timeout_s)
        self.on_early(self.sub.wait_ready(timeout_s))
        self.setup()

    def on_early(self, early: list[Received]) -> None:
        """Messages that arrived before the subscription was confirmed: the last-value cache's
        current state among them. The default handles them like any other."""
        for got in early:
            self.dispatch(got)

    def run(self, install_signals: bool = True) -> int:
        if install_signals:
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, lambda *_: self._stop.set())
        try:
            self.connect()
            self.log.info("ready (pid %d)", os.getpid())
            while not self._stop.is_set():
                self.run_once()
        finally:
            self.teardown()
            self.close()
        self.log.info("stopped")
        return 0

    def beat_if_due(self, now: int) -> None:
        if now >= self._next_beat_ns:
            self.beat()
            self._next_beat_ns = now + int(self.config.heartbeat_interval_s * 1e9)

    def run_once(self) -> None:
        assert self.sub is not None
        now = self.clock.now_ns()
        self.beat_if_due(now)
        if self.tick_hz and now >= self._next_tick_ns:
            self.on_tick(now)
            period = int(1e9 / self.tick_hz)
            self._next_tick_ns = max(self._next_tick_ns + period, now + period // 4)
        due = min(self._next_beat_ns, self._next_tick_ns if self.tick_hz else self._next_beat_ns)
        wait_s = min(_MAX_WAIT_S, max(0.0, (due - self.clock.now_ns()) / 1e9))
        got = self.sub.recv(wait_s)
        if got is not None:
            self.dispatch(got)
            for more in self.sub.drain(1000):
                self.dispatch(more)
            self.after_batch()
        if self.parent_pid is not None and os.getppid() != self.parent_pid:
            self.log.warning("supervisor %d is gone: stopping", self.parent_pid)
            self._stop.set()

    def after_batch(self) -> None:
        """Called once after each batch of messages is handled: work a batch makes due (say, publishing
        what the messages changed) is done once per batch, not once per message."""

    def beat(self) -> None:
        assert self.pub is not None
        self.pub.publish(Heartbeat(agent=ALL_AGENTS, service=self.name, pid=os.getpid(),
                                   started_ns=self.started_ns, bad_messages=sum(self.bad_messages.values())))

    def dispatch(self, got: Received) -> None:
        if got.error is not None:
            self.reject(got.topic, got.error.kind, str(got.error))
            return
        msg = got.message
        assert msg is not None
        handler = self._handlers.get(type(msg))
        if handler is None:
            return  # subscribed by prefix; not every type under it concerns this service
        try:
            handler(msg)
        except Rejected as exc:
            self.reject(got.topic, exc.kind, exc.reason, exc.request_id or getattr(msg, "request_id", ""),
                        agent=msg.agent)
        except ProtocolError as exc:
            self.reject(got.topic, exc.kind, str(exc), getattr(msg, "request_id", ""), agent=msg.agent)
        except Exception as exc:  # a bug must not take the service down; it is reported and counted
            self.log.exception("handler for %s failed", got.topic)
            self.reject(got.topic, "internal", f"{type(exc).__name__}: {exc}",
                        getattr(msg, "request_id", ""), agent=msg.agent)

    def reject(self, topic: str, kind: str, reason: str, request_id: str = "",
               agent: str = ALL_AGENTS) -> None:
        """Count a bad message, log the reason once per kind, and publish it on the error topic."""
        self.bad_messages[kind] += 1
        if self.bad_messages[kind] == 1:
            self.log.warning("rejected %s (%s): %s", topic or "<no topic>", kind, reason)
        if self.pub is None:
            return
        if agent == ALL_AGENTS and topic.count(".") == 2:
            candidate = topic.split(".")[1]
            agent = candidate if is_agent_id(candidate) else ALL_AGENTS
        self.pub.publish(Error(agent=agent if is_agent_id(agent) else ALL_AGENTS, reason=reason[:2000],
                               kind=kind[:64], topic=topic[:256], request_id=request_id[:64], service=self.name))

    def publish(self, msg: Message, category: str | None = None) -> Message:
        assert self.pub is not None
        return self.pub.publish(msg, category)

    def close(self) -> None:
        for sock in (self.pub, self.sub):
            if sock is not None:
                sock.close()


def wait_until(predicate: Callable[[], bool], timeout_s: float, poll_s: float = 0.01) -> bool:
    """Poll `predicate` until it holds or the timeout passes (for tests and the supervisor)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(poll_s)
    return predicate()
