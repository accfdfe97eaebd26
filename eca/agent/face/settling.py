"""Per-flexor settling toward a target, solved in closed form so any frame rate gives the same values.

Perlin's ResponsiveFace moves each flexor toward its target so that it covers 95% of the way within the
flexor's settle time. We use the exponential with that property:

    value(t) = target + (start - target) * exp(-ln(20) * (t - t0) / settle)

where t0 is when the target last changed and start is the value at t0 (taken from the transition that
was then running, so an interrupted transition continues from where it was: no jumps).
"""

from __future__ import annotations

import math

import numpy as np

from eca.agent.face.flexors import FLEXOR_NAMES, N_FLEXORS

# exp(-LN_20) = 0.05: 95% of the way at t - t0 = settle (Perlin's definition of the settle time).
LN_20 = math.log(20.0)


def _settle_vector(settle_s: np.ndarray | float, what: str) -> np.ndarray:
    vector = np.broadcast_to(np.asarray(settle_s, dtype=np.float64), (N_FLEXORS,)).copy()
    bad = np.flatnonzero(~np.isfinite(vector) | (vector < 0))
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"{what} for {FLEXOR_NAMES[i]!r} must be a finite number >= 0, got {vector[i]}")
    return vector


class Settler:
    """The settled value of every flexor, given the targets and the times they changed."""

    def __init__(self, settle_s: np.ndarray | float, initial: np.ndarray | None = None, t_ns: int = 0) -> None:
        self.default_settle_s = _settle_vector(settle_s, "settle time")
        start = np.zeros(N_FLEXORS) if initial is None else np.array(initial, dtype=np.float64)
        if start.shape != (N_FLEXORS,) or not np.all(np.isfinite(start)):
            raise ValueError(f"initial values need shape ({N_FLEXORS},) and no NaN, got {start}")
        self._t0_ns = np.full(N_FLEXORS, int(t_ns), dtype=np.int64)
        self._start = start.copy()
        self._target = start.copy()
        self._settle_s = self.default_settle_s.copy()
        self._last_change_ns = int(t_ns)
        self._divisor = np.where(self._settle_s == 0, 1.0, self._settle_s)  # the settle times, 1 where 0
        self._gap = np.zeros(N_FLEXORS)  # start - target; 0 where the settle time is 0 (at the target at once)
        self.version = 0  # bumped at each change of the transitions (a batch of many faces keeps their arrays)

    @property
    def targets(self) -> np.ndarray:
        return self._target.copy()

    def value_at(self, t_ns: int) -> np.ndarray:
        """Settled values at t_ns; before a flexor's last change it reads that change's start value."""
        return settled_many(self.transitions(), t_ns)

    def transitions(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(target, gap, t0_ns, divisor): what value_at evaluates, for evaluating many settlers as one array (read
        only; `version` says when they change)."""
        return self._target, self._gap, self._t0_ns, self._divisor

    def retarget(self, target: np.ndarray, t_ns: int, settle_s: np.ndarray | float | None = None) -> None:
        """New targets from t_ns; only flexors whose target changes start a new transition.

        `settle_s` overrides the default settle time for the transitions this call starts.
        """
        target = np.asarray(target, dtype=np.float64)
        if target.shape != (N_FLEXORS,) or not np.all(np.isfinite(target)):
            raise ValueError(f"targets need shape ({N_FLEXORS},) and no NaN, got {target}")
        if t_ns < self._last_change_ns:
            raise ValueError(f"targets changed at {t_ns} ns, before the previous change at {self._last_change_ns} ns")
        settle = self.default_settle_s if settle_s is None else _settle_vector(settle_s, "settle time")
        changed = target != self._target
        if not np.any(changed):
            return
        current = self.value_at(t_ns)
        self._start[changed] = current[changed]
        self._target[changed] = target[changed]
        self._t0_ns[changed] = int(t_ns)
        self._settle_s[changed] = settle[changed]
        self._last_change_ns = int(t_ns)
        at_once = self._settle_s == 0
        self._divisor = np.where(at_once, 1.0, self._settle_s)
        self._gap = np.where(at_once, 0.0, self._start - self._target)
        self.version += 1


def settled_many(transitions: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], t_ns: int) -> np.ndarray:
    """The settled values at t_ns of one settler's transitions() (Settler.value_at), or of many stacked row by row."""
    target, gap, t0_ns, divisor = transitions
    elapsed_s = np.maximum(int(t_ns) - t0_ns, 0) / 1e9
    # A flexor with no settle time is at its target: its gap is 0 (and its divisor 1, not 0).
    return target + gap * np.exp(-LN_20 * elapsed_s / divisor)
