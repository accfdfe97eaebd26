"""Head gestures: nods (a listener's backchannel, a BML head NOD), shakes and tilts, added on top of the
head's moves in the compositor's gesture layer.

A gesture is `repetitions` strokes over `duration`; repetition i fills [onset + i*d/n, onset + (i+1)*d/n) and
has its stroke at the middle. A nod dips the chin and a tilt leans the head (a raised-cosine bump of the nod or
tilt flexor, deepest at the stroke); a shake turns the head to one side and the other (a sine of the turn
flexor, crossing the middle fastest at the stroke). Gestures that overlap add up. A gesture with an id replaces
the one it names (a BML block that is interrupted cuts its gestures short).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from eca.agent.face.flexors import FLEXOR_INDEX
from eca.agent.face.frame import dont_care_vector

HeadLexeme = Literal["nod", "shake", "tilt"]
HEAD_LEXEMES: tuple[HeadLexeme, ...] = ("nod", "shake", "tilt")
MAX_GESTURES = 32  # kept at once: far more than overlap in any real exchange
MAX_REPETITIONS = 20
_FLEXOR = {"nod": FLEXOR_INDEX["nod"], "shake": FLEXOR_INDEX["turn"], "tilt": FLEXOR_INDEX["tilt"]}


@dataclass(frozen=True)
class HeadGesture:
    lexeme: HeadLexeme
    onset_ns: int
    duration_ns: int
    repetitions: int
    depth: float  # flexor units at each stroke
    id: str = ""

    @property
    def end_ns(self) -> int:
        return self.onset_ns + self.duration_ns

    def stroke_ns(self, repetition: int = 0) -> int:
        return self.onset_ns + (2 * repetition + 1) * self.duration_ns // (2 * self.repetitions)

    def value_at(self, t_ns: int) -> float:
        phase = (t_ns - self.onset_ns) / self.duration_ns * self.repetitions
        within = phase - math.floor(phase)  # 0..1 inside the current repetition
        if self.lexeme == "shake":
            return self.depth * math.sin(2.0 * math.pi * within)
        bump = self.depth * 0.5 * (1.0 - math.cos(2.0 * math.pi * within))
        return -bump if self.lexeme == "nod" else bump  # a nod's stroke is the chin down (nod < 0)


class HeadGestures:
    """The gestures under way, as a trajectory-layer action (caring about nothing between gestures)."""

    def __init__(self) -> None:
        self._gestures: list[HeadGesture] = []

    def __len__(self) -> int:
        return len(self._gestures)

    def add(self, lexeme: HeadLexeme, t_ns: int, depth: float, duration_s: float, repetitions: int = 1,
            gesture_id: str = "") -> None:
        """From t_ns, `repetitions` strokes of `depth` flexor units within `duration_s`; a non-empty
        `gesture_id` replaces the gesture of that id (duration 0 only ends it)."""
        if lexeme not in _FLEXOR:
            raise ValueError(f"a head gesture is one of {', '.join(HEAD_LEXEMES)}, got {lexeme!r}")
        if gesture_id:
            self._gestures = [g for g in self._gestures if g.id != gesture_id]
            if duration_s == 0:
                return
        if not (math.isfinite(depth) and 0.0 < depth <= 1.0):
            raise ValueError(f"a head gesture's depth must lie in (0, 1] flexor units, got {depth!r}")
        if not (math.isfinite(duration_s) and duration_s > 0):
            raise ValueError(f"a head gesture lasts a finite number of seconds > 0, got {duration_s!r}")
        if not 1 <= repetitions <= MAX_REPETITIONS:
            raise ValueError(f"a head gesture has 1..{MAX_REPETITIONS} repetitions, got {repetitions!r}")
        self._gestures.append(HeadGesture(lexeme, int(t_ns), round(duration_s * 1e9), repetitions, float(depth),
                                          gesture_id))
        if len(self._gestures) > MAX_GESTURES:  # a flood from outside never grows the face without bound
            self._gestures.sort(key=lambda g: g.onset_ns)
            del self._gestures[: len(self._gestures) - MAX_GESTURES]

    def cut(self, gesture_id: str, t_ns: int) -> None:
        """The gesture of that id stops at t_ns (back to rest at once if it was under way)."""
        self._gestures = [g for g in self._gestures if g.id != gesture_id or g.onset_ns < t_ns]
        self._gestures = [g if g.id != gesture_id or g.end_ns <= t_ns else
                          HeadGesture(g.lexeme, g.onset_ns, t_ns - g.onset_ns, g.repetitions, g.depth, g.id)
                          for g in self._gestures]

    def values_at(self, t_ns: int) -> np.ndarray:
        vector = dont_care_vector()
        cared = self.sparse_at(t_ns)
        if cared is not None:
            vector[cared[0]] = cared[1]
        return vector

    def sparse_at(self, t_ns: int) -> tuple[np.ndarray, np.ndarray] | None:
        moved: dict[int, float] = {}  # flexor -> the sum of the gestures under way on it
        for gesture in self._gestures:
            if gesture.onset_ns <= t_ns < gesture.end_ns:
                index = _FLEXOR[gesture.lexeme]
                moved[index] = moved.get(index, 0.0) + gesture.value_at(t_ns)
        # Gestures long over can go: times only move forward for a face.
        if len(self._gestures) > 8:
            self._gestures = [g for g in self._gestures if g.end_ns > t_ns]
        if not moved:
            return None
        return np.fromiter(moved.keys(), np.intp, len(moved)), np.fromiter(moved.values(), np.float64, len(moved))
