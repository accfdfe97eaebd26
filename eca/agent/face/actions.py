"""Actions: time-varying combinations of flexors (Perlin's ResponsiveFace; the paper's section 4).

An action answers one question: which flexor values does it ask for at time t? It returns a full flexor
vector with NaN ("do not care") where it leaves the flexor to the layers below. Emotions are constant
actions (`Pose`); head moves (agent/face/head.py) and keyframed gestures vary in time.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal, Protocol, runtime_checkable

import numpy as np

from eca.agent.clock import seconds
from eca.agent.face.flexors import N_FLEXORS
from eca.agent.face.frame import FLEXOR_MAX, FLEXOR_MIN, check_flexor_value, dont_care_vector, flexor_index

Easing = Literal["step", "linear", "smooth"]


@runtime_checkable
class Action(Protocol):
    def values_at(self, t_ns: int) -> np.ndarray:
        """The flexor vector this action asks for at t_ns: shape (N_FLEXORS,), NaN = do not care."""
        ...


# What a sparse action asks for at a time: (flexor indices, their values), each index once and no NaN among the
# values; None when it cares about nothing then.
SparseValues = tuple[np.ndarray, np.ndarray] | None


@runtime_checkable
class SparseAction(Action, Protocol):
    """An action that can also say only the flexors it cares about: what the compositor asks of the face's own
    layers at every frame, where a full vector of NaN and a mask per layer cost more than the values do."""

    def sparse_at(self, t_ns: int) -> SparseValues:
        """values_at(t_ns) at its flexors that are not NaN: the same numbers."""
        ...


def as_pose_vector(values: np.ndarray | Sequence[float], what: str = "pose") -> np.ndarray:
    """A float64 flexor vector, NaN allowed, checked for shape and range."""
    vector = np.array(values, dtype=np.float64)
    if vector.shape != (N_FLEXORS,):
        raise ValueError(f"{what} needs shape ({N_FLEXORS},), got {vector.shape}")
    cared = vector[~np.isnan(vector)]
    if np.any(np.isinf(cared)) or np.any((cared < FLEXOR_MIN) | (cared > FLEXOR_MAX)):
        raise ValueError(f"{what} holds values outside [{FLEXOR_MIN}, {FLEXOR_MAX}]: {vector}")
    return vector


@dataclass(frozen=True)
class Pose:
    """A constant action: the same flexor values at every time (an emotion, a held expression)."""

    values: np.ndarray

    def __post_init__(self) -> None:
        vector = as_pose_vector(self.values)
        vector.flags.writeable = False
        object.__setattr__(self, "values", vector)

    @classmethod
    def from_dict(cls, values: Mapping[str, float]) -> Pose:
        vector = dont_care_vector()
        for name, value in values.items():
            vector[flexor_index(name)] = check_flexor_value(name, value)
        return cls(vector)

    def values_at(self, t_ns: int) -> np.ndarray:
        return self.values.copy()


def ease(fraction: np.ndarray | float, easing: Easing) -> np.ndarray:
    """Map progress in [0, 1] through an easing curve; 'smooth' is smoothstep (zero slope at both ends)."""
    s = np.clip(np.asarray(fraction, dtype=np.float64), 0.0, 1.0)
    if easing == "linear":
        return s
    if easing == "smooth":
        return s * s * (3.0 - 2.0 * s)
    if easing == "step":
        return (s >= 1.0).astype(np.float64)
    raise ValueError(f"unknown easing {easing!r}; known: step, linear, smooth")


@dataclass(frozen=True)
class Keyframes:
    """Poses at times, interpolated between neighbouring keys; held before the first and after the last.

    A flexor that is NaN in either of the two keys around t is "do not care" between them.
    """

    times_ns: tuple[int, ...]
    poses: np.ndarray  # (n_keys, N_FLEXORS)
    easing: Easing = "smooth"

    def __post_init__(self) -> None:
        times = tuple(int(t) for t in self.times_ns)
        poses = np.array(self.poses, dtype=np.float64)
        if not times:
            raise ValueError("keyframes need at least one key")
        if poses.shape != (len(times), N_FLEXORS):
            raise ValueError(f"keyframes need poses of shape ({len(times)}, {N_FLEXORS}), got {poses.shape}")
        if any(b <= a for a, b in zip(times, times[1:], strict=False)):
            raise ValueError(f"keyframe times must increase strictly, got {times}")
        for i, pose in enumerate(poses):
            as_pose_vector(pose, f"keyframe {i}")
        ease(0.5, self.easing)  # rejects an unknown easing now rather than at the first frame
        poses.flags.writeable = False
        object.__setattr__(self, "times_ns", times)
        object.__setattr__(self, "poses", poses)

    @classmethod
    def from_seconds(
        cls, keys: Sequence[tuple[float, Mapping[str, float]]], start_ns: int = 0, easing: Easing = "smooth"
    ) -> Keyframes:
        """Keys as (seconds after start_ns, {flexor: value}); unnamed flexors are "do not care"."""
        times = tuple(start_ns + round(t_s * 1e9) for t_s, _ in keys)
        poses = np.stack([Pose.from_dict(values).values for _, values in keys]) if keys else np.empty((0,))
        return cls(times, poses, easing)

    def values_at(self, t_ns: int) -> np.ndarray:
        times = self.times_ns
        if t_ns <= times[0]:
            return self.poses[0].copy()
        if t_ns >= times[-1]:
            return self.poses[-1].copy()
        after = int(np.searchsorted(times, t_ns, side="right"))
        t_a, t_b = times[after - 1], times[after]
        weight = ease((t_ns - t_a) / (t_b - t_a), self.easing)
        a, b = self.poses[after - 1], self.poses[after]
        return a + weight * (b - a)  # NaN in either key stays NaN


@dataclass(frozen=True)
class Envelope:
    """A pose that swells in, holds and fades out: a brow flash, a nod of assent, a wince.

    The pose scales by an attack-hold-release envelope (smoothstep ramps) from start_ns; outside the
    envelope the action does not care, so it is meant for an additive layer or a short override.
    """

    pose: Pose
    start_ns: int
    attack_s: float
    hold_s: float
    release_s: float

    def __post_init__(self) -> None:
        for name in ("attack_s", "hold_s", "release_s"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"envelope {name} must be a finite number >= 0, got {value!r}")

    @property
    def end_ns(self) -> int:
        return self.start_ns + round((self.attack_s + self.hold_s + self.release_s) * 1e9)

    def gain_at(self, t_ns: int) -> float:
        t = seconds(t_ns - self.start_ns)
        if t < 0 or t_ns > self.end_ns:
            return 0.0
        rise = 1.0 if self.attack_s == 0 else float(ease(t / self.attack_s, "smooth"))
        fall_from = self.attack_s + self.hold_s
        fall = 1.0 if self.release_s == 0 else 1.0 - float(ease((t - fall_from) / self.release_s, "smooth"))
        return min(rise, fall)

    def values_at(self, t_ns: int) -> np.ndarray:
        if not self.start_ns <= t_ns <= self.end_ns:
            return dont_care_vector()
        return self.pose.values * self.gain_at(t_ns)
