"""Head motion: timed transitions of turn, nod and tilt (the paper's head parameter file:
duration, turn, nod, tilt), smooth and interruptible.

Each move is a cubic Hermite curve from the head's current position and velocity to the target at rest
after `duration_s`. From rest it is the classic ease-in-out (smoothstep); when a new command interrupts
a move, the new curve starts with the old one's velocity, so position and velocity stay continuous.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from eca.agent.face.flexors import FLEXOR_INDEX
from eca.agent.face.frame import FLEXOR_MAX, FLEXOR_MIN, dont_care_vector

HEAD_FLEXORS: tuple[str, str, str] = ("turn", "nod", "tilt")
_HEAD_INDEX = np.array([FLEXOR_INDEX[name] for name in HEAD_FLEXORS])


def check_head_pose(pose: Sequence[float], what: str = "head pose") -> np.ndarray:
    vector = np.array(pose, dtype=np.float64)
    if vector.shape != (3,):
        raise ValueError(f"{what} needs (turn, nod, tilt), got {pose!r}")
    for name, value in zip(HEAD_FLEXORS, vector, strict=True):
        if not (FLEXOR_MIN <= value <= FLEXOR_MAX):  # also rejects NaN
            raise ValueError(f"{what}: {name} = {value} lies outside [{FLEXOR_MIN}, {FLEXOR_MAX}]")
    return vector


@dataclass(frozen=True)
class _Segment:
    t0_ns: int
    start: np.ndarray  # (3,) flexor units
    start_velocity: np.ndarray  # (3,) flexor units per second
    target: np.ndarray  # (3,)
    duration_s: float


class HeadMotion:
    """The head's turn, nod and tilt over time; an action that cares only about those three flexors."""

    def __init__(self, start: Sequence[float] = (0.0, 0.0, 0.0), t_ns: int = 0) -> None:
        position = check_head_pose(start, "start head pose")
        self._segment = _Segment(int(t_ns), position, np.zeros(3), position, 0.0)

    @property
    def target(self) -> np.ndarray:
        return self._segment.target.copy()

    @property
    def arrives_ns(self) -> int:
        """When the current move reaches its target."""
        return self._segment.t0_ns + round(self._segment.duration_s * 1e9)

    def move_to(self, target: Sequence[float], duration_s: float, t_ns: int) -> None:
        """Start toward (turn, nod, tilt) at t_ns, arriving at rest after duration_s (0 = at once)."""
        goal = check_head_pose(target, "head target")
        if not math.isfinite(duration_s) or duration_s < 0:
            raise ValueError(f"head move duration must be a finite number of seconds >= 0, got {duration_s!r}")
        if t_ns < self._segment.t0_ns:
            raise ValueError(f"head move at {t_ns} ns starts before the previous one at {self._segment.t0_ns} ns")
        position, velocity = self.state_at(t_ns)
        if duration_s == 0:
            velocity = np.zeros(3)
        self._segment = _Segment(int(t_ns), position, velocity, goal, float(duration_s))

    def state_at(self, t_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """(position, velocity per second) of (turn, nod, tilt) at t_ns."""
        seg = self._segment
        elapsed_s = (int(t_ns) - seg.t0_ns) / 1e9
        if seg.duration_s == 0 or elapsed_s >= seg.duration_s:
            return seg.target.copy(), np.zeros(3)
        if elapsed_s <= 0:
            return seg.start.copy(), seg.start_velocity.copy()
        d = seg.duration_s
        s = elapsed_s / d
        # Hermite basis with the end tangent fixed at zero (arrive at rest).
        h00, h10, h01 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2
        dh00, dh10, dh01 = 6 * s**2 - 6 * s, 3 * s**2 - 4 * s + 1, -6 * s**2 + 6 * s
        tangent = d * seg.start_velocity
        position = h00 * seg.start + h10 * tangent + h01 * seg.target
        velocity = (dh00 * seg.start + dh10 * tangent + dh01 * seg.target) / d
        return position, velocity

    def _position_at(self, t_ns: int) -> np.ndarray:
        """state_at(t_ns)'s position alone (a new array): what every frame asks."""
        seg = self._segment
        elapsed_s = (int(t_ns) - seg.t0_ns) / 1e9
        if seg.duration_s == 0 or elapsed_s >= seg.duration_s:
            return seg.target.copy()
        if elapsed_s <= 0:
            return seg.start.copy()
        return self.state_at(t_ns)[0]

    def pose_at(self, t_ns: int) -> np.ndarray:
        """(turn, nod, tilt) at t_ns, within [-1, 1] (a fast reversal may overshoot; it is clipped)."""
        position = self._position_at(t_ns)
        np.maximum(position, FLEXOR_MIN, out=position)  # np.clip's Python wrapper costs more than both
        return np.minimum(position, FLEXOR_MAX, out=position)

    def values_at(self, t_ns: int) -> np.ndarray:
        vector = dont_care_vector()
        vector[_HEAD_INDEX] = self.pose_at(t_ns)
        return vector

    def sparse_at(self, t_ns: int) -> tuple[np.ndarray, np.ndarray]:
        return _HEAD_INDEX, self.pose_at(t_ns)


