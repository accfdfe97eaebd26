"""A compact live view of the bus for `eca up`: message rate, services alive, each agent's state."""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Sequence

from protocol.bus import Received
from protocol.messages import EmotionState, Error, EyesState, Heartbeat, RoleState


class BusView:
    def __init__(self, agents: Sequence[str], window_s: float = 5.0) -> None:
        self.agents = list(agents)
        self.window_s = window_s
        self.arrivals: deque[float] = deque()
        self.services: dict[str, float] = {}
        self.role: dict[str, str] = {}
        self.emotion: dict[str, str] = {}
        self.eyes: dict[str, str] = {}
        self.errors = 0
        self.last_error = ""

    def add(self, got: Received) -> None:
        now = time.monotonic()
        self.arrivals.append(now)
        msg = got.message
        if isinstance(msg, Heartbeat):
            self.services[msg.service] = now
        elif isinstance(msg, RoleState):
            self.role[msg.agent] = msg.role
        elif isinstance(msg, EmotionState):
            self.emotion[msg.agent] = f"{msg.name} {msg.intensity:.1f}"
        elif isinstance(msg, EyesState):
            self.eyes[msg.agent] = msg.mode
        elif isinstance(msg, Error):
            self.errors += 1
            self.last_error = f"{msg.service}: {msg.reason}"

    def summary(self) -> str:
        now = time.monotonic()
        while self.arrivals and now - self.arrivals[0] > self.window_s:
            self.arrivals.popleft()
        alive = [f"{name}{'' if now - t < 2.0 else ' (silent)'}" for name, t in sorted(self.services.items())]
        agents = [f"{a}: {self.role.get(a, '?')}, {self.emotion.get(a, '?')}, eyes {self.eyes.get(a, '?')}"
                  for a in self.agents]
        line = f"bus {len(self.arrivals) / self.window_s:.0f} msg/s | {', '.join(alive)} | {' | '.join(agents)}"
        if self.errors:
            line += f" | {self.errors} errors, last: {self.last_error[:80]}"
        return line
