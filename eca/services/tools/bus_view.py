"""A compact live view of the bus for `eca up`: message rate, services alive, each agent's state.

It holds a fixed amount whatever arrives: a count for the rate (not one entry per message), the
instance's own agents only, and at most MAX_SERVICES_SHOWN heartbeat names (anyone can publish one).
"""

from __future__ import annotations

import time
from collections.abc import Sequence

from eca.protocol.bus import Received
from eca.protocol.messages import EmotionState, Error, EyesState, Heartbeat, RoleState

MAX_SERVICES_SHOWN = 32


class BusView:
    def __init__(self, agents: Sequence[str]) -> None:
        self.agents = list(agents)
        self.arrived = 0  # since the last summary
        self._since = time.monotonic()
        self.services: dict[str, float] = {}
        self.role: dict[str, str] = {}
        self.emotion: dict[str, str] = {}
        self.eyes: dict[str, str] = {}
        self.errors = 0
        self.last_error = ""

    def add(self, got: Received) -> None:
        self.arrived += 1
        msg = got.message
        if isinstance(msg, Heartbeat):
            if msg.service in self.services or len(self.services) < MAX_SERVICES_SHOWN:
                self.services[msg.service] = time.monotonic()
        elif isinstance(msg, Error):
            self.errors += 1
            self.last_error = f"{msg.service}: {msg.reason}"
        elif msg is None or msg.agent not in self.agents:
            return
        elif isinstance(msg, RoleState):
            self.role[msg.agent] = msg.role
        elif isinstance(msg, EmotionState):
            self.emotion[msg.agent] = f"{msg.name} {msg.intensity:.1f}"
        elif isinstance(msg, EyesState):
            self.eyes[msg.agent] = msg.mode

    def summary(self) -> str:
        now = time.monotonic()
        rate = self.arrived / max(now - self._since, 1e-3)
        self.arrived, self._since = 0, now
        alive = [f"{name}{'' if now - t < 2.0 else ' (silent)'}" for name, t in sorted(self.services.items())]
        agents = [f"{a}: {self.role.get(a, '?')}, {self.emotion.get(a, '?')}, eyes {self.eyes.get(a, '?')}"
                  for a in self.agents]
        line = f"bus {rate:.0f} msg/s | {', '.join(alive)} | {' | '.join(agents)}"
        if self.errors:
            line += f" | {self.errors} errors, last: {self.last_error[:80]}"
        return line
