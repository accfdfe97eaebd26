"""Script animation elements, the cues the service layer publishes, and the timeline that orders them.

Times are seconds from the start of the script (float). An element occupies [start_s, end_s): it is
the one in force for its kind and agent until the next element of that kind starts; after the last
one ends its values stay (nothing snaps back by itself).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from eca.agent.face.flexors import FLEXOR_INDEX, N_FLEXORS
from eca.agent.script.vocab import ElementKind, EyeMode, Role


@dataclass(frozen=True)
class AnimationElement:
    """The paper's script animation element: one transition, with a value per flexor.

    `flexors` holds N_FLEXORS values in FLEXOR_NAMES order, NaN meaning "do not care" (the layers
    below decide). The semantic payload (emotion, eye mode, head targets, role) rides along so a
    generator need not reverse-engineer it from flexor values. `role` is the agent's role in force at
    `start_s` (filled in by the timeline from status elements; None before any is known).
    """

    start_s: float
    duration_s: float
    kind: ElementKind
    agent: str
    flexors: tuple[float, ...]
    role: Role | None = None
    transition_s: float = 0.0
    emotion: str | None = None
    intensity: float | None = None
    eye_mode: EyeMode | None = None
    yaw_deg: float | None = None
    pitch_deg: float | None = None
    head: tuple[float | None, float | None, float | None] | None = None
    file: str = ""
    line: int = 0

    @property
    def end_s(self) -> float:
        return self.start_s + self.duration_s

    def flexor_vector(self) -> np.ndarray:
        return np.array(self.flexors, dtype=np.float64)

    def cares_about(self, flexor: str) -> bool:
        return not math.isnan(self.flexors[FLEXOR_INDEX[flexor]])


def flexor_tuple(values: dict[str, float]) -> tuple[float, ...]:
    """A do-not-care vector with the named flexors set."""
    out = [math.nan] * N_FLEXORS
    for name, value in values.items():
        out[FLEXOR_INDEX[name]] = float(value)
    return tuple(out)


@dataclass(frozen=True)
class RoleCue:
    t_s: float
    agent: str
    role: Role


@dataclass(frozen=True)
class EmotionCue:
    t_s: float
    agent: str
    name: str
    intensity: float
    transition_s: float


def keep_unset(values: tuple[float | None, ...], current: tuple[float, ...]) -> tuple[float, ...]:
    """Each value, or the current one where the value is None (a cue that leaves that axis alone)."""
    return tuple(c if v is None else v for v, c in zip(values, current, strict=True))


@dataclass(frozen=True)
class HeadCue:
    """Move the head to the targets (flexor values; None = leave that axis) over `duration_s`."""

    t_s: float
    agent: str
    turn: float | None
    nod: float | None
    tilt: float | None
    duration_s: float

    def targets(self, current: tuple[float, float, float]) -> tuple[float, float, float]:
        """(turn, nod, tilt) after this cue, keeping the axes it leaves alone at `current`."""
        return keep_unset((self.turn, self.nod, self.tilt), current)  # type: ignore[return-value]


@dataclass(frozen=True)
class GazeCue:
    """Switch the eye mode and/or set the gaze target (degrees in the head frame); None = unchanged."""

    t_s: float
    agent: str
    mode: EyeMode | None
    yaw_deg: float | None
    pitch_deg: float | None

    def target(self, current: tuple[float, float]) -> tuple[float, float] | None:
        """(yaw, pitch) of the gaze target after this cue, or None when the cue sets no target."""
        if self.yaw_deg is None and self.pitch_deg is None:
            return None
        return keep_unset((self.yaw_deg, self.pitch_deg), current)  # type: ignore[return-value]


@dataclass(frozen=True)
class SayCue:
    """Speak one utterance: `audio_path` (absolute) when given, else `text` through the voice."""

    t_s: float
    agent: str
    utterance_id: str
    text: str
    audio_path: str | None
    duration_s: float


@dataclass(frozen=True)
class TurnCue:
    """A turn of a dialogue of several agents: `speaker` (one of its agents or the user; None for a silence)
    speaks to `addressees` from `t_s` for `duration_s`. Who looks at whom follows from it
    (agent/gaze/situated.py); it drives no agent by itself, so it has no `agent`."""

    t_s: float
    speaker: str | None
    addressees: tuple[str, ...]
    duration_s: float


Cue = RoleCue | EmotionCue | HeadCue | GazeCue | SayCue | TurnCue

# At one instant the role switches before anything else so that speech starts on a talking face; a turn
# comes after every agent's own cues of its instant, so the people to look at are chosen in the new roles.
_CUE_ORDER = {RoleCue: 0, EmotionCue: 1, HeadCue: 2, GazeCue: 3, TurnCue: 4, SayCue: 5}
_KIND_ORDER = {"status": 0, "emotion": 1, "head": 2, "gaze": 3}


def element_cue(element: AnimationElement) -> RoleCue | EmotionCue | HeadCue | GazeCue:
    """The bus command an element starts with."""
    e = element
    if e.kind == "status":
        assert e.role is not None
        return RoleCue(e.start_s, e.agent, e.role)
    if e.kind == "emotion":
        assert e.emotion is not None and e.intensity is not None
        return EmotionCue(e.start_s, e.agent, e.emotion, e.intensity, e.transition_s)
    if e.kind == "head":
        turn, nod, tilt = e.head or (None, None, None)
        return HeadCue(e.start_s, e.agent, turn, nod, tilt, e.transition_s)
    return GazeCue(e.start_s, e.agent, e.eye_mode, e.yaw_deg, e.pitch_deg)


@dataclass(frozen=True)
class Timeline:
    """Every element and cue of a script, ordered by time, and its total length in seconds."""

    elements: tuple[AnimationElement, ...]
    cues: tuple[Cue, ...]
    length_s: float
    agents: tuple[str, ...]

    def cues_between(self, t0_s: float, t1_s: float) -> list[Cue]:
        """The cues with t0_s <= t_s < t1_s, in order: what a player publishes over one tick."""
        return [c for c in self.cues if t0_s <= c.t_s < t1_s]

    def elements_at(self, t_s: float, kind: ElementKind, agent: str) -> AnimationElement | None:
        """The element of `kind` in force for `agent` at `t_s`: the last one started, or None."""
        found = None
        for e in self.elements:
            if e.start_s > t_s:
                break
            if e.kind == kind and e.agent == agent:
                found = e
        return found


def _with_roles(elements: Sequence[AnimationElement]) -> list[AnimationElement]:
    current: dict[str, Role] = {}
    out = []
    for e in elements:
        if e.kind == "status":
            assert e.role is not None
            current[e.agent] = e.role
            out.append(e)
        else:
            out.append(dataclasses.replace(e, role=current.get(e.agent)))
    return out


def _tidy(t_s: float) -> float:
    # Summed durations drift (0.1 + 0.2); cues compared across files should meet at the same instant.
    return round(t_s, 9)


def _changes_nothing(cue: Cue, last: dict[tuple[type, str], Cue]) -> bool:
    """A role or emotion cue equal to the one in force for that agent (a restatement) changes nothing."""
    if isinstance(cue, RoleCue | EmotionCue):
        key = (type(cue), cue.agent)
        before = last.get(key)
        last[key] = cue
        if isinstance(cue, RoleCue):
            return isinstance(before, RoleCue) and before.role == cue.role
        return isinstance(before, EmotionCue) and (before.name, before.intensity) == (cue.name, cue.intensity)
    return False


def merge(
    elements: Iterable[AnimationElement], says: Iterable[SayCue] = (), min_length_s: float = 0.0,
    turns: Iterable[TurnCue] = (),
) -> Timeline:
    """One time-ordered timeline; ties keep the kinds' order (status first) then the input order.

    Every element stays in `elements`; a role or emotion cue that restates the one in force is left
    out of `cues`, so a parameter file may repeat what the dialogue already says. `turns` are the turns
    of a dialogue of several agents (none for one agent).
    """
    tidy = [dataclasses.replace(e, start_s=_tidy(e.start_s)) for e in elements]
    indexed = sorted(enumerate(tidy), key=lambda p: (p[1].start_s, _KIND_ORDER[p[1].kind], p[0]))
    ordered = _with_roles([e for _, e in indexed])
    say_list = [dataclasses.replace(s, t_s=_tidy(s.t_s)) for s in says]
    cues: list[Cue] = [element_cue(e) for e in ordered]
    cues.extend(say_list)
    cues.extend(dataclasses.replace(turn, t_s=_tidy(turn.t_s)) for turn in turns)
    cues = [c for _, c in sorted(enumerate(cues), key=lambda p: (p[1].t_s, _CUE_ORDER[type(p[1])], p[0]))]
    last: dict[tuple[type, str], Cue] = {}
    cues = [c for c in cues if not _changes_nothing(c, last)]
    length = max(
        [min_length_s, *(e.end_s for e in ordered), *(s.t_s + s.duration_s for s in say_list)]
    )
    agents = tuple(dict.fromkeys([*(e.agent for e in ordered), *(s.agent for s in say_list)]))
    return Timeline(tuple(ordered), tuple(cues), _tidy(length), agents)
