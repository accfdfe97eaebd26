"""One flexor frame: the face's whole state at one instant, as a named, ordered vector."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from eca.agent.face.flexors import FLEXOR_INDEX, FLEXOR_NAMES, N_FLEXORS

# A layer or pose that leaves a flexor to the layers below it writes NaN there (the paper's
# "do not care value" of a script animation element). Never compare with ==: use np.isnan.
DONT_CARE = float("nan")

FLEXOR_MIN = -1.0
FLEXOR_MAX = 1.0


def dont_care_vector() -> np.ndarray:
    """A flexor vector that cares about nothing."""
    return np.full(N_FLEXORS, DONT_CARE, dtype=np.float64)


def flexor_index(name: str) -> int:
    """The position of a flexor in the vector; an unknown name raises ValueError listing the known ones."""
    try:
        return FLEXOR_INDEX[name]
    except KeyError:
        raise ValueError(f"unknown flexor {name!r}; known flexors: {', '.join(FLEXOR_NAMES)}") from None


def check_flexor_value(name: str, value: object, where: str = "") -> float:
    """The value as float; ValueError naming the flexor (and `where`) unless it is a number in [-1, 1]."""
    prefix = f"{where}: " if where else ""
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        raise ValueError(f"{prefix}flexor {name!r} must be a number, got {value!r}")
    number = float(value)
    if math.isnan(number):
        raise ValueError(f"{prefix}flexor {name!r} is NaN; a frame holds a value for every flexor")
    if not FLEXOR_MIN <= number <= FLEXOR_MAX:
        raise ValueError(f"{prefix}flexor {name!r} = {number} lies outside [{FLEXOR_MIN}, {FLEXOR_MAX}]")
    return number


@dataclass(frozen=True)
class FlexorFrame:
    """The value of every flexor at time `t_ns` (monotonic nanoseconds), in FLEXOR_NAMES order.

    A frame is complete: unlike a layer it has no "do not care" entries, and every value lies in [-1, 1].
    """

    values: np.ndarray
    t_ns: int = 0

    def __post_init__(self) -> None:
        values = np.array(self.values, dtype=np.float64)
        if values.shape != (N_FLEXORS,):
            raise ValueError(f"a flexor frame needs shape ({N_FLEXORS},), got {values.shape}")
        bad = np.flatnonzero(~np.isfinite(values) | (values < FLEXOR_MIN) | (values > FLEXOR_MAX))
        if bad.size:
            i = int(bad[0])
            check_flexor_value(FLEXOR_NAMES[i], float(values[i]))
        values.flags.writeable = False
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "t_ns", int(self.t_ns))

    @classmethod
    def composed(cls, values: np.ndarray, t_ns: int) -> FlexorFrame:
        """A frame of values a compositor has just clipped into [-1, 1] (finite, shape checked there):
        taken as they are, without checking them again on every frame. The frame owns `values`."""
        frame = object.__new__(cls)
        values.flags.writeable = False
        object.__setattr__(frame, "values", values)
        object.__setattr__(frame, "t_ns", int(t_ns))
        return frame

    @property
    def names(self) -> tuple[str, ...]:
        return FLEXOR_NAMES

    @classmethod
    def neutral(cls, t_ns: int = 0) -> FlexorFrame:
        """Every flexor relaxed (0)."""
        return cls(np.zeros(N_FLEXORS), t_ns)

    def get(self, name: str) -> float:
        return float(self.values[flexor_index(name)])

    def as_dict(self) -> dict[str, float]:
        return {name: float(v) for name, v in zip(FLEXOR_NAMES, self.values, strict=True)}

    @classmethod
    def from_dict(cls, values: Mapping[str, object], t_ns: int = 0, where: str = "") -> FlexorFrame:
        """A frame from {flexor: value}; flexors not named are relaxed (0).

        Unknown names, non-numbers, NaN and values outside [-1, 1] raise ValueError naming the flexor.
        """
        prefix = f"{where}: " if where else ""
        vector = np.zeros(N_FLEXORS)
        for name, value in values.items():
            if name not in FLEXOR_INDEX:
                raise ValueError(f"{prefix}unknown flexor {name!r}; known flexors: {', '.join(FLEXOR_NAMES)}")
            vector[FLEXOR_INDEX[name]] = check_flexor_value(name, value, where)
        return cls(vector, t_ns)

    def with_values(self, **changes: float) -> FlexorFrame:
        """A copy with some flexors changed, e.g. frame.with_values(smile_l=0.5)."""
        vector = self.values.copy()
        for name, value in changes.items():
            vector[flexor_index(name)] = check_flexor_value(name, value)
        return FlexorFrame(vector, self.t_ns)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, FlexorFrame):
            return NotImplemented
        return self.t_ns == other.t_ns and bool(np.array_equal(self.values, other.values))

    __hash__ = None  # type: ignore[assignment]
