"""The supervisor's timing logic: start in order, readiness by first heartbeat, restart with backoff.

Processes and time come in through the constructor (a process factory and a clock), so this logic
is tested with fake processes on virtual time; `services.tools.up` wires it to real interpreters and the bus.
"""

from __future__ import annotations

import signal
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

from eca.agent.clock import Clock


class ProcessHandle(Protocol):
    pid: int

    def poll(self) -> int | None: ...

    def send_signal(self, sig: int) -> None: ...

    def kill(self) -> None: ...


ProcessFactory = Callable[[str], ProcessHandle]


@dataclass(frozen=True)
class RestartPolicy:
    heartbeat_timeout_s: float = 1.5
    ready_timeout_s: float = 15.0
    backoff_s: tuple[float, ...] = (0.05, 0.25, 0.5, 1.0, 2.0)
    restart_limit: int = 5
    restart_window_s: float = 60.0
    stop_grace_s: float = 1.0


@dataclass
class Supervised:
    name: str
    process: ProcessHandle | None = None
    started_ns: int = 0
    last_beat_ns: int | None = None  # since the current start
    restart_at_ns: int | None = None
    restarts: deque[int] = field(default_factory=deque)  # times of recent restarts
    given_up: bool = False
    stopping_since_ns: int | None = None

    @property
    def ready(self) -> bool:
        return self.process is not None and self.last_beat_ns is not None


class Supervisor:
    def __init__(self, names: Sequence[str], factory: ProcessFactory, clock: Clock,
                 policy: RestartPolicy | None = None, say: Callable[[str], None] = print) -> None:
        self.services = [Supervised(n) for n in names]
        self.by_name = {s.name: s for s in self.services}
        self.factory = factory
        self.clock = clock
        self.policy = policy or RestartPolicy()
        self.say = say
        self.retired: list[ProcessHandle] = []  # killed and replaced, not yet reaped (no zombie outlives them)

    def start(self, name: str) -> None:
        svc = self.by_name[name]
        svc.process = self.factory(name)
        svc.started_ns = self.clock.now_ns()
        svc.last_beat_ns = None
        svc.restart_at_ns = None
        svc.stopping_since_ns = None

    def on_heartbeat(self, name: str, pid: int) -> None:
        svc = self.by_name.get(name)
        if svc is None or svc.process is None or svc.process.pid != pid:
            return  # a beat from an instance we no longer run (or never ran)
        first = svc.last_beat_ns is None
        svc.last_beat_ns = self.clock.now_ns()
        if first and svc.restarts:
            self.say(f"{name} is back (pid {pid})")

    def all_ready(self, names: Sequence[str] | None = None) -> bool:
        return all(self.by_name[n].ready for n in (names or [s.name for s in self.services]))

    def check(self) -> None:
        """Notice exits and silent services; restart what is due; reap what was killed. Call it often."""
        now = self.clock.now_ns()
        p = self.policy
        self.retired = [proc for proc in self.retired if proc.poll() is None]
        for svc in self.services:
            if svc.given_up:
                continue
            if svc.restart_at_ns is not None:
                if now >= svc.restart_at_ns:
                    self.start(svc.name)
                continue
            if svc.process is None:
                continue
            code = svc.process.poll()
            if code is not None:
                self._failed(svc, f"exited with code {code}", now)
                continue
            silent_since = svc.last_beat_ns if svc.last_beat_ns is not None else svc.started_ns
            limit_s = p.heartbeat_timeout_s if svc.last_beat_ns is not None else p.ready_timeout_s
            if now - silent_since > limit_s * 1e9:
                svc.process.kill()  # hung: only a kill is sure to end it
                self.retired.append(svc.process)  # polled until the kill has taken: then it is reaped
                self._failed(svc, f"sent no heartbeat for {limit_s:g} s", now)

    def _failed(self, svc: Supervised, why: str, now: int) -> None:
        p = self.policy
        window_ns = p.restart_window_s * 1e9
        while svc.restarts and now - svc.restarts[0] > window_ns:
            svc.restarts.popleft()
        svc.process = None
        if len(svc.restarts) >= p.restart_limit:
            svc.given_up = True
            self.say(f"{svc.name} {why}; it failed {len(svc.restarts) + 1} times within "
                     f"{p.restart_window_s:g} s, so it is not restarted again")
            return
        delay_s = p.backoff_s[min(len(svc.restarts), len(p.backoff_s) - 1)]
        svc.restarts.append(now)
        svc.restart_at_ns = now + int(delay_s * 1e9)
        self.say(f"{svc.name} {why}; restarting in {delay_s:g} s")

    def begin_stop(self) -> None:
        """Ask every running service to stop, last started first (SIGTERM)."""
        now = self.clock.now_ns()
        for svc in reversed(self.services):
            svc.restart_at_ns = None
            if svc.process is not None and svc.process.poll() is None:
                svc.process.send_signal(signal.SIGTERM)
                svc.stopping_since_ns = now

    def finish_stop(self) -> bool:
        """SIGKILL whatever outlived the grace period; True once every process has ended."""
        now = self.clock.now_ns()
        self.retired = [proc for proc in self.retired if proc.poll() is None]
        done = not self.retired
        for svc in self.services:
            if svc.process is None or svc.process.poll() is not None:
                continue
            done = False
            if svc.stopping_since_ns is not None and now - svc.stopping_since_ns > self.policy.stop_grace_s * 1e9:
                self.say(f"{svc.name} did not stop within {self.policy.stop_grace_s:g} s: killing it")
                svc.process.kill()
                svc.stopping_since_ns = None
        return done
