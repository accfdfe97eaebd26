"""Clocks in integer nanoseconds, so every model can run on real or virtual time."""

from __future__ import annotations

import time
from typing import Protocol

NS_PER_S = 1_000_000_000


class Clock(Protocol):
    def now_ns(self) -> int: ...


class MonotonicClock:
    """The process's monotonic clock, the time base of every bus timestamp."""

    def now_ns(self) -> int:
        return time.monotonic_ns()


class VirtualClock:
    """A clock that only moves when told to; tests and offline renders drive models with it."""

    def __init__(self, start_ns: int = 0) -> None:
        self._now_ns = int(start_ns)

    def now_ns(self) -> int:
        return self._now_ns

    def advance_ns(self, delta_ns: int) -> int:
        if delta_ns < 0:
            raise ValueError(f"a clock cannot go back: delta_ns={delta_ns}")
        self._now_ns += int(delta_ns)
        return self._now_ns

    def advance_s(self, delta_s: float) -> int:
        return self.advance_ns(round(delta_s * NS_PER_S))

    def set_ns(self, t_ns: int) -> None:
        if t_ns < self._now_ns:
            raise ValueError(f"a clock cannot go back: {t_ns} < {self._now_ns}")
        self._now_ns = int(t_ns)


def seconds(t_ns: int) -> float:
    return t_ns / NS_PER_S


def nanoseconds(t_s: float) -> int:
    return round(t_s * NS_PER_S)
