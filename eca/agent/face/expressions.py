"""Facial expressions on the master clock (a BML faceLexeme or faceFacs): flexor offsets added over the
emotion (the compositor's expression layer), each with the standard's envelope: rising from its start to full
strength at its attack peak, held until relax, gone at its end. Rise and fall are smoothstep curves, so a
brow raise starts and lands softly. An expression with an id replaces the one it names (a block that is
interrupted sends its expressions again with an earlier end).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from eca.agent.face.flexors import FLEXOR_INDEX
from eca.agent.face.frame import FLEXOR_MAX, FLEXOR_MIN, dont_care_vector

MAX_EXPRESSIONS = 32  # held at once: a BML block has a few; a flood never grows the face without bound


@dataclass(frozen=True)
class Expression:
    id: str
    onset_ns: int
    peak_ns: int
    relax_ns: int
    end_ns: int
    offsets: np.ndarray  # flexor vector, 0 where the expression leaves a flexor alone
    cares: np.ndarray  # bool: the flexors it moves

    def strength_at(self, t_ns: int) -> float:
        if t_ns < self.onset_ns or t_ns >= self.end_ns:
            return 0.0
        if t_ns < self.peak_ns:
            return _smoothstep((t_ns - self.onset_ns) / (self.peak_ns - self.onset_ns))
        if t_ns < self.relax_ns:
            return 1.0
        return 1.0 - _smoothstep((t_ns - self.relax_ns) / (self.end_ns - self.relax_ns))


def _smoothstep(x: float) -> float:
    return x * x * (3.0 - 2.0 * x)


class Expressions:
    """The expressions held, as a trajectory-layer action: the sum of each one's offsets times its strength,
    NaN ("do not care") where none moves a flexor."""

    def __init__(self) -> None:
        self._held: dict[str, Expression] = {}

    def __len__(self) -> int:
        return len(self._held)

    def set(self, expression_id: str, onset_ns: int, peak_ns: int, relax_ns: int, end_ns: int,
            flexors: Mapping[str, float]) -> None:
        """Hold (or replace) the expression `expression_id`: `flexors` (name -> offset in flexor units at full
        strength) over onset <= peak <= relax <= end."""
        if not onset_ns <= peak_ns <= relax_ns <= end_ns:
            raise ValueError(f"expression {expression_id!r}: onset <= peak <= relax <= end does not hold")
        offsets = np.zeros(len(FLEXOR_INDEX))
        cares = np.zeros(len(FLEXOR_INDEX), dtype=bool)
        for name, value in flexors.items():
            if name not in FLEXOR_INDEX:
                raise ValueError(f"expression {expression_id!r}: no flexor named {name!r}")
            if not (math.isfinite(value) and FLEXOR_MIN <= value <= FLEXOR_MAX):
                raise ValueError(f"expression {expression_id!r}: {name} = {value!r} lies outside "
                                 f"[{FLEXOR_MIN}, {FLEXOR_MAX}]")
            offsets[FLEXOR_INDEX[name]] = value
            cares[FLEXOR_INDEX[name]] = True
        self._held.pop(expression_id, None)
        if end_ns > onset_ns and cares.any():
            self._held[expression_id] = Expression(expression_id, int(onset_ns), int(peak_ns), int(relax_ns),
                                                   int(end_ns), offsets, cares)
        if len(self._held) > MAX_EXPRESSIONS:
            oldest = sorted(self._held.values(), key=lambda e: e.onset_ns)[: len(self._held) - MAX_EXPRESSIONS]
            for expression in oldest:
                del self._held[expression.id]

    def values_at(self, t_ns: int) -> np.ndarray:
        vector = dont_care_vector()
        gone = []
        for expression in self._held.values():
            if t_ns >= expression.end_ns:
                gone.append(expression.id)
                continue
            strength = expression.strength_at(t_ns)
            if strength > 0.0:
                cares = expression.cares
                vector[cares] = np.nan_to_num(vector[cares]) + strength * expression.offsets[cares]
        for expression_id in gone:  # times only move forward for a face
            del self._held[expression_id]
        return vector

    def sparse_at(self, t_ns: int) -> tuple[np.ndarray, np.ndarray] | None:
        if not self._held:  # most frames: nothing held
            return None
        vector = self.values_at(t_ns)
        cares = np.flatnonzero(vector == vector)  # not NaN
        return (cares, vector[cares]) if cares.size else None
