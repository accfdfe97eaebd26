"""The base every eca process runs on: config, bus sockets, a poll loop, heartbeats, bad input, signals.

A service subclass names its subscriptions, registers one handler per message type and, if it has
periodic work, a tick rate. The loop never blocks longer than the next due tick or heartbeat (and at
most 100 ms, so a stop request or the death of the supervisor is noticed promptly), and handles at
most `BATCH_LIMIT` messages between two looks at its heartbeat, so a flood cannot silence it.

Floods: of the state messages in one batch, only the newest per topic is decoded and handled (a state
is a last value; the older ones are counted as `coalesced` in the heartbeat). Restarts: a broker that
restarts comes back with an empty cache; `on_new_broker` is where the owner of a state publishes it
again. Under `eca up` a service also beats straight to the supervisor (services/processes/liveness.py), and
waits for a broker that is not there yet instead of giving up.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import shlex
import signal
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

import zmq

from eca.agent.clock import Clock, MonotonicClock
from eca.protocol.bus import BusTimeout, Publisher, Received, Subscriber
from eca.protocol.codec import ProtocolError, is_agent_id
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import ALL_AGENTS, Error, Heartbeat, Message
from eca.services.processes.heap import trim
from eca.services.processes.liveness import LivenessSender

M = TypeVar("M", bound=Message)
_MAX_WAIT_S = 0.1
BATCH_LIMIT = 1000  # messages handled between two looks at the heartbeat and the tick
_STATE = b"state."


class CannotStart(RuntimeError):
    """A service cannot start (its message says why, in one line): it stops with exit code 1."""


class BrokerUnavailable(CannotStart):
    """No broker answered a starting service that has no supervisor to wait for."""


class Rejected(ValueError):
    """Raised by a handler for a well-formed message it refuses (unknown emotion, unknown request).

    The handler must raise before it changes any state; the runtime reports the reason on the error
    topic."""

    def __init__(self, reason: str, request_id: str = "", kind: str = "rejected") -> None:
        super().__init__(reason)
        self.reason = reason
        self.request_id = request_id
        self.kind = kind


def one_maths_thread() -> None:
    """Keep numpy's matrix products on the thread that calls them, in a service process about to import numpy.

    numpy's OpenBLAS starts a worker per core the first time a product is large enough, and a worker spins
    between jobs instead of sleeping when they come often: a service multiplying every frame slot then burns a core
    in a spinning worker and takes it from the voice and the others. The web service poses all its agents' faces in
    one product (AvatarDriver.drive_many), which crosses OpenBLAS' threshold from 22 agents on
    (bench/conversations.py: the web service at 129 % of a core with 24 conversations, 80 of it that thread; 53 %
    without it). A service's products are small and real-time: one thread is all they need. Called before numpy is
    loaded (the library reads its setting when it loads); an operator's own setting wins."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def setup_logging(name: str, level: int = logging.INFO) -> None:
    logging.basicConfig(level=level, stream=sys.stderr, force=True,
                        format=f"[{name}] %(levelname)s %(message)s")


class Service:
    """One eca process: bus in -> models -> bus out."""

    name = "service"
    tick_hz: float | None = None

    def __init__(self, config: BusConfig, *, clock: Clock | None = None, ctx: zmq.Context | None = None,
                 parent_pid: int | None = None, liveness: str | None = None) -> None:
        self.config = config
        self.clock = clock or MonotonicClock()
        self.ctx = ctx or zmq.Context.instance()
        self.log = logging.getLogger(self.name)
        self.parent_pid = parent_pid
        self.started_ns = self.clock.now_ns()
        self.bad_messages: Counter[str] = Counter()
        self.coalesced = 0  # state messages skipped because a newer one of the topic came in the same batch
        self.dropped = 0  # messages or reports a service discarded at one of its bounds
        self._handlers: dict[type[Message], Callable[[Any], None]] = {}
        self._stop = threading.Event()
        self.pub: Publisher | None = None
        self.sub: Subscriber | None = None
        self._liveness = LivenessSender(self.ctx, liveness) if liveness else None
        self._liveness_endpoint = liveness
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

    def on_new_broker(self) -> None:
        """A broker restarted (its last-value cache is empty): the owner of a state publishes it again."""

    def handle(self, cls: type[M], handler: Callable[[M], None]) -> None:
        self._handlers[cls] = handler

    # --- the loop --------------------------------------------------------------------------------

    def request_stop(self) -> None:
        self._stop.set()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def connect(self, timeout_s: float | None = None) -> None:
        """Open the sockets and pass both readiness barriers, then `setup`.

        Under a supervisor (a liveness channel) it waits for the broker as long as it takes, beating to
        the supervisor meanwhile: a broker that is restarting is no reason to restart this service too.
        Alone it gives up after `timeout_s` (default: the config's connect_timeout_s) with
        BrokerUnavailable."""
        if timeout_s is None:
            timeout_s = None if self._liveness is not None else self.config.connect_timeout_s
        self.pub = Publisher(self.ctx, self.config, self.name, now_ns=self.clock.now_ns)
        self.sub = Subscriber(self.ctx, self.config, self.subscriptions())
        early = self._wait_for_broker(timeout_s)
        self.on_early(early)
        self.setup()

    def _wait_for_broker(self, timeout_s: float | None) -> list[Received]:
        assert self.pub is not None and self.sub is not None
        step_s = self.config.heartbeat_interval_s
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        said = False
        publisher_ready = False
        while True:
            try:
                if not publisher_ready:
                    self.pub.wait_ready(step_s)
                    publisher_ready = True
                return self.sub.wait_ready(step_s)
            except BusTimeout:
                pass
            if self._stop.is_set():
                raise BrokerUnavailable("stopped while waiting for the broker")
            if deadline is not None and time.monotonic() >= deadline:
                raise BrokerUnavailable(f"no broker answered at {self.config.backend} within {timeout_s:g} s; "
                                        "start one with `eca up` (or `python -m eca.services.processes.run broker`)")
            if not said:
                said = True
                self.log.info("waiting for the broker at %s", self.config.backend)
            self._beat_to_supervisor()
            self._check_parent()

    def on_early(self, early: list[Received]) -> None:
        """Messages that arrived before the subscription was confirmed: the last-value cache's
        current state among them. The default handles them like any other."""
        for got in early:
            self.dispatch(got)

    def run(self, install_signals: bool = True, on_ready: Callable[[], None] | None = None) -> int:
        """The process's life: connect, loop until stopped, tear down; 1 when it cannot start. `on_ready` is
        called once connected (a test running the service in a thread waits on it)."""
        if install_signals:
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, lambda *_: self._stop.set())
        try:
            try:
                self.connect()
            except CannotStart as exc:
                if self._stop.is_set():
                    return 0
                self.log.error("cannot start: %s", exc)
                return 1
            self.log.info("ready (pid %d)", os.getpid())
            if on_ready is not None:
                on_ready()
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
            trim()  # what a burst of messages left free in the heap goes back to the system
        self._check_broker()

    def _check_broker(self) -> None:
        assert self.pub is not None
        if self.pub.new_broker():
            self.log.info("the broker restarted")
            self.on_new_broker()

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
        if self.sub.socket.poll(math.ceil(wait_s * 1000), zmq.POLLIN):
            batch = self.read_batch(BATCH_LIMIT)
            for got in batch:
                self.dispatch(got)
            if batch:
                self.after_batch()
        self._check_parent()

    def read_batch(self, limit: int) -> list[Received]:
        """Up to `limit` messages waiting now, decoded, with each state topic's older messages in the
        batch skipped undecoded (counted in `coalesced`): a state is a last value, and under a flood
        decoding every superseded one is what would make the service fall behind."""
        assert self.sub is not None
        raw = self.sub.read_frames(limit)
        keep = latest_per_state_topic(raw)
        self.coalesced += len(raw) - len(keep)
        out = []
        for frames in keep:
            got = self.sub.accept(frames)
            if got is not None:
                out.append(got)
        return out

    def _check_parent(self) -> None:
        if self.parent_pid is not None and os.getppid() != self.parent_pid:
            self.log.warning("supervisor %d is gone: stopping", self.parent_pid)
            self._stop.set()

    def after_batch(self) -> None:
        """Called once after each batch of messages is handled: work a batch makes due (say, publishing
        what the messages changed) is done once per batch, not once per message."""

    def heartbeat(self) -> Heartbeat:
        return Heartbeat(agent=ALL_AGENTS, service=self.name, pid=os.getpid(), started_ns=self.started_ns,
                         bad_messages=sum(self.bad_messages.values()), coalesced=self.coalesced,
                         dropped=self.dropped)

    def beat(self) -> None:
        assert self.pub is not None
        beat = self.pub.publish(self.heartbeat())
        if self._liveness is not None:
            self._liveness.beat(beat)

    @contextmanager
    def keeping_alive(self, max_s: float = 30.0) -> Iterator[None]:
        """Beat to the supervisor from a thread of its own (its own socket) while the loop does one long, bounded
        piece of work that cannot beat in between (a GL context made and the faces' first frames drawn while a
        page loads): the loop is working, not hung. The beats stop after `max_s`, so work that never ends is
        still taken for a hang."""
        if self._liveness_endpoint is None:
            yield
            return
        done = threading.Event()
        endpoint = self._liveness_endpoint

        def beat() -> None:
            sender = LivenessSender(self.ctx, endpoint)
            deadline = time.monotonic() + max_s
            try:
                while not done.wait(self.config.heartbeat_interval_s) and time.monotonic() < deadline:
                    sender.beat(self.heartbeat())
            finally:
                sender.close()

        thread = threading.Thread(target=beat, name=f"{self.name}-keeping-alive", daemon=True)
        thread.start()
        try:
            yield
        finally:
            done.set()
            thread.join()

    def _beat_to_supervisor(self) -> None:
        if self._liveness is not None:
            self._liveness.beat(self.heartbeat())

    def dispatch(self, got: Received) -> None:
        if got.error is not None:
            err = got.error
            self.reject(got.topic, err.kind, str(err), err.request_id, agent=err.agent or ALL_AGENTS)
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
            self.reject(got.topic, "internal", f"the {self.name} service failed on this message (an eca bug: "
                        f"{type(exc).__name__})", getattr(msg, "request_id", ""), agent=msg.agent)

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
        # A new broker's cache gets the states published before this one first: a client that finds
        # the newest state there finds the older ones beside it, not a cache that lacks them.
        self._check_broker()
        assert self.pub is not None
        return self.pub.publish(msg, category)

    def close(self) -> None:
        for sock in (self.pub, self.sub, self._liveness):
            if sock is not None:
                sock.close()


def latest_per_state_topic(batch: list[list[bytes]]) -> list[list[bytes]]:
    """The batch in order, less every state message that a later one of the same topic supersedes."""
    latest: dict[bytes, int] = {}
    for i, frames in enumerate(batch):
        if frames[0].startswith(_STATE):
            latest[frames[0]] = i
    if len(latest) == sum(1 for frames in batch if frames[0].startswith(_STATE)):
        return batch
    return [frames for i, frames in enumerate(batch) if not frames[0].startswith(_STATE) or latest[frames[0]] == i]


def wait_until(predicate: Callable[[], bool], timeout_s: float, poll_s: float = 0.01) -> bool:
    """Poll `predicate` until it holds or the timeout passes (for tests and the supervisor)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(poll_s)
    return predicate()


def parse_service_args(name: str, argv: list[str], parser: argparse.ArgumentParser) -> argparse.Namespace:
    """A service's own command-line arguments (`parser` built with add_help=False, exit_on_error=False):
    anything it does not know, or a bad value, is one ERROR line naming the service, and exit status 2."""
    try:
        args, unknown = parser.parse_known_args(argv)
        if unknown:
            raise ValueError(f"unknown {name} arguments: {shlex.join(unknown)}")
    except (argparse.ArgumentError, ValueError) as exc:
        print(f"[{name}] ERROR {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    return args
