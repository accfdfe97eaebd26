"""A BML block as data: its behaviours with their parameters, its time references and constraints, its schedule.

Also the small grammars every part shares: ids, decimal numbers and sync references
(`[blockId:]offset` | `[blockId:]behaviourId:syncId[:iteration][±offset]`, OpenBMLParser's SyncRef), and the
XML element as read (with its position), which the parser and the speech text both walk.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

from eca.agent.bml.errors import BmlWarning

# The same number as eca.protocol.messages.MAX_BML_CHARS (the bus's bound on a `cmd.<agent>.bml` request);
# agent/ may not import protocol/, so it is written twice and a test holds the two alike.
MAX_BML_CHARS = 65_536
MAX_DEPTH = 32  # as agent/script/xmltree.py: far deeper than any real block
MAX_BEHAVIOURS = 200
MAX_CONSTRAINTS = 100  # <synchronize>, <before> and <after> elements together
MAX_CONSTRAINT_REFS = 50  # <sync> references in one of them
MAX_MARKS = 50  # sync marks in one speech
MAX_REPETITION = 20
MAX_OFFSET_S = 600.0  # any time written in a block, in seconds
MAX_WARNINGS = 100  # a block of a thousand unknown attributes does not flood the feedback

BML_NS = "http://www.bml-initiative.org/bml/bml-1.0"
MINDMAKERS_NS = "http://www.mindmakers.org/projects/BML"
CORE_EXTENSIONS_NS = "http://www.bml-initiative.org/bml/coreextensions-1.0"
ECA_NS = "urn:eca:bml:1.0"
SMARTBODY_NS = "http://ict.usc.edu"
CORE_NAMESPACES = frozenset({BML_NS, MINDMAKERS_NS, ""})

ID_PATTERN = re.compile(r"[A-Za-z0-9_.-]{1,64}")
_NUMBER = r"(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)"
_SIGNED_NUMBER = re.compile(rf"\s*([+-]?)\s*({_NUMBER})\s*")
_TRAILING_OFFSET = re.compile(rf"(.*?)\s*([+-])\s*({_NUMBER})\s*")


def is_id(text: str) -> bool:
    return ID_PATTERN.fullmatch(text) is not None


def parse_decimal(text: str) -> float:
    """A plain decimal number (`-1.5`, `.25`, `3`); ValueError for anything else: no exponents, nan or inf,
    which a sender never means and which would poison every time computed from them."""
    match = _SIGNED_NUMBER.fullmatch(text) if len(text) <= 40 else None
    if match is None:
        raise ValueError(f"'{text[:40]}' is not a decimal number")
    value = float(match.group(1) + match.group(2))
    if not math.isfinite(value):  # 400 digits overflow to inf
        raise ValueError(f"'{text[:40]}' is out of range")
    return value


@dataclass(frozen=True)
class SyncRef:
    """A time reference as written in a sync attribute or a <sync ref>.

    block None = this block. behaviour None = an absolute time: offset_s from this block's start. In a
    reference to another block, behaviour "bml" names that block itself (sync "start" or "end"). A head's
    later strokes are sync "stroke:2", "stroke:3", ... (written `h1:stroke:2`).
    """

    block: str | None
    behaviour: str | None
    sync: str | None
    offset_s: float
    text: str


def parse_sync_ref(text: str, *, block_id: str, carrier: str | None) -> SyncRef:
    """Read one reference; `carrier` is the behaviour whose attribute holds it (None in a constraint), which
    `self` names. ValueError with the reason for a malformed one."""
    raw = text.strip()
    if not raw or len(raw) > 300:
        raise ValueError(f"'{raw[:60]}' is not a time reference")
    number = _SIGNED_NUMBER.fullmatch(raw)
    if number is not None:
        return SyncRef(None, None, None, _bounded_offset(number.group(1), number.group(2)), raw)
    parts = raw.split(":")
    offset = 0.0
    tail = _TRAILING_OFFSET.fullmatch(parts[-1])
    block_offset = _SIGNED_NUMBER.fullmatch(parts[1]) if len(parts) == 2 else None
    if block_offset is not None:  # otherBlock:offset, seconds from that block's start
        other = parts[0].strip()
        _check_ids(raw, [other])
        offset = _bounded_offset(block_offset.group(1), block_offset.group(2))
        if other == block_id:
            return SyncRef(None, None, None, offset, raw)
        return SyncRef(other, "bml", "start", offset, raw)
    if tail is not None and tail.group(1).strip():
        parts[-1] = tail.group(1)
        offset = _bounded_offset(tail.group(2), tail.group(3))
    names = [part.strip() for part in parts]
    _check_ids(raw, names)
    block: str | None = None
    if len(names) == 2:
        behaviour, sync = names
    elif len(names) == 3 and names[1] == "stroke" and names[2].isdigit():
        behaviour, sync = names[0], _stroke(raw, names[2])
    elif len(names) == 3 and not names[2].isdigit():
        block, behaviour, sync = names
    elif len(names) == 4 and names[2] == "stroke" and names[3].isdigit():
        block, behaviour, sync = names[0], names[1], _stroke(raw, names[3])
    else:  # OpenBMLParser too: an iteration number follows 'stroke' only
        raise ValueError(f"'{raw}' is not a time reference: write [block:]behaviour:sync[+-seconds], "
                         "[block:]behaviour:stroke:n or [block:]seconds")
    if block == block_id:
        block = None
    if behaviour == "self":
        if block is not None or carrier is None:
            raise ValueError(f"'{raw}': 'self' names the behaviour that carries the attribute, and there is none here")
        behaviour = carrier
    if behaviour == "bml":
        if block is None:
            if sync != "start":
                raise ValueError(f"'{raw}': a block can refer to its own start only")
            return SyncRef(None, None, None, offset, raw)
        if sync not in ("start", "end"):
            raise ValueError(f"'{raw}': a block's sync points are start and end")
    return SyncRef(block, behaviour, sync, offset, raw)


def _bounded_offset(sign: str, digits: str) -> float:
    value = float(sign + digits)
    if not abs(value) <= MAX_OFFSET_S:
        raise ValueError(f"the offset {sign}{digits[:20]} s lies beyond {MAX_OFFSET_S:g} s")
    return value


def _check_ids(raw: str, names: list[str]) -> None:
    for name in names:
        if not is_id(name):
            raise ValueError(f"'{raw}': '{name[:64]}' is not an id (letters, digits, '_', '.', '-'; at most 64)")


def _stroke(raw: str, digits: str) -> str:
    iteration = int(digits[:6])
    if not 1 <= iteration <= MAX_REPETITION:
        raise ValueError(f"'{raw}': a stroke's iteration lies in 1..{MAX_REPETITION}")
    return "stroke" if iteration == 1 else f"stroke:{iteration}"


@dataclass
class XmlElement:
    """One element as read: its namespace resolved, its text and child elements in document order."""

    namespace: str  # the URI; "" for none; "unbound:p" for an undeclared prefix p
    name: str  # the local name
    tag: str  # as written, prefix included
    attrs: dict[tuple[str, str], str]  # (namespace, local name) -> value; plain attributes have namespace ""
    line: int
    column: int
    content: list[XmlElement | str] = field(default_factory=list)

    def elements(self) -> list[XmlElement]:
        return [item for item in self.content if isinstance(item, XmlElement)]

    def attr(self, name: str) -> str | None:
        return self.attrs.get(("", name))


# -- the behaviours' parameters --


@dataclass(frozen=True)
class SpeechParams:
    text: str  # the words, marks removed, whitespace collapsed
    ssml: str  # <speak>the words with <mark name="ID"/> at each sync mark</speak>, escaped: espeak-ng -m's input
    marks: tuple[str, ...]  # sync ids in text order
    audio_path: str | None  # eca extension (eca:audio): a recorded file instead of text-to-speech


@dataclass(frozen=True)
class GazeParams:
    target: str
    influence: str  # EYES, HEAD, NECK, SHOULDER, WAIST or WHOLE
    offset_angle_deg: float
    offset_direction: str  # NONE, RIGHT, LEFT, UP, DOWN, UPRIGHT, UPLEFT, DOWNLEFT, DOWNRIGHT or POLAR
    shift: bool  # gazeShift: the new rest gaze, which persists


@dataclass(frozen=True)
class FaceParams:
    flexors: Mapping[str, float]  # offsets in flexor units, scaled by amount, clipped to [-1, 1]
    what: str  # as asked, e.g. "faceLexeme RAISE_BROWS" or "faceFacs AU12 LEFT"
    shift: bool  # faceShift: the new rest face, which persists


@dataclass(frozen=True)
class HeadParams:
    lexeme: Literal["nod", "shake", "tilt"]
    repetitions: int
    amplitude_deg: float
    what: str  # the lexeme as written, e.g. "TOSS"


@dataclass(frozen=True)
class HeadDirectionParams:
    target: str


@dataclass(frozen=True)
class WaitParams:
    max_wait_s: float | None  # max-wait; None: the wait lasts as long as its sync attributes say


@dataclass(frozen=True)
class BlinkParams:
    pass


@dataclass(frozen=True)
class EmotionParams:
    name: str  # one of configs/emotions.toml's tables, canonical (lower case, '-')
    intensity: float
    transition_s: float


@dataclass(frozen=True)
class RoleParams:
    role: Literal["talking", "listening", "silence"]


Params = (
    SpeechParams | GazeParams | FaceParams | HeadParams | HeadDirectionParams | WaitParams | BlinkParams
    | EmotionParams | RoleParams
)


@dataclass(frozen=True)
class Behaviour:
    id: str
    kind: str  # speech, gaze, gazeShift, faceLexeme, faceFacs, faceShift, head, headDirectionShift, wait, blink,
    #            emotion, role
    line: int
    sync: Mapping[str, SyncRef]  # the sync attributes given on the element
    params: Params


@dataclass(frozen=True)
class UnrealizedBehaviour:
    """A behaviour the face cannot perform (a gesture, an unknown lexeme), kept so that references to its sync
    points still resolve: it is scheduled with its kind's sync points over `[timings] unrealized_s`."""

    id: str
    kind: str  # the element's name, e.g. gesture
    line: int
    sync: Mapping[str, SyncRef]


@dataclass(frozen=True)
class Constraint:
    """synchronize: every ref at one time. before / after: refs[0] is the anchor (the element's `ref`
    attribute, else its first <sync>); every later ref's time (+ its offset) is no later / no earlier than the
    anchor's (+ its offset)."""

    kind: Literal["synchronize", "before", "after"]
    refs: tuple[SyncRef, ...]
    line: int


@dataclass(frozen=True)
class Block:
    id: str
    character: str
    composition: Literal["MERGE", "APPEND", "REPLACE"]
    behaviours: tuple[Behaviour, ...]
    constraints: tuple[Constraint, ...]
    warnings: tuple[BmlWarning, ...]
    unrealized: tuple[UnrealizedBehaviour, ...] = ()
    name: str = "bml"  # the name parse_block was given, for the schedule's messages


# The default sync points of each kind, in time order (BMLRealizerTester DefaultSyncPoints for BML 1.0; eca's
# own kinds after). A head's strokes after the first add "stroke:2".."stroke:n" between stroke and strokeEnd.
_FACE = ("start", "attackPeak", "relax", "end")
_STROKED = ("start", "ready", "strokeStart", "stroke", "strokeEnd", "relax", "end")
_SHIFT = ("start", "end")
SYNC_POINTS: Mapping[str, tuple[str, ...]] = {
    "speech": _SHIFT,
    "gaze": ("start", "ready", "relax", "end"),
    "gazeShift": _SHIFT,
    "face": _FACE,
    "faceLexeme": _FACE,
    "faceFacs": _FACE,
    "faceShift": _SHIFT,
    "head": _STROKED,
    "headDirectionShift": _SHIFT,
    "wait": _SHIFT,
    "blink": _FACE,  # closing, closed, opening
    "emotion": _SHIFT,  # the transition to the new emotion
    "role": _SHIFT,
    "gesture": _STROKED,
    "pointing": _STROKED,
    "posture": ("start", "ready", "relax", "end"),
    "postureShift": _SHIFT,
    "gestureShift": _SHIFT,
    "locomotion": _SHIFT,
}
SYNC_NAMES = frozenset(name for names in SYNC_POINTS.values() for name in names)


def sync_points(kind: str) -> tuple[str, ...]:
    """The default sync points of a behaviour kind, in time order; start and end for a kind not known."""
    return SYNC_POINTS.get(kind, _SHIFT)


# -- the schedule --


@dataclass(frozen=True)
class SpeechTiming:
    duration_s: float
    marks: Mapping[str, float]  # mark id -> seconds from the speech's start


@dataclass(frozen=True)
class Timeline:
    block: str
    start_s: float
    end_s: float
    # (behaviour id, sync id) -> absolute seconds: every sync point of every behaviour in block.behaviours (speech
    # marks included), in document and time order; unrealized behaviours are not here
    times: Mapping[tuple[str, str], float]

    def in_order(self) -> list[tuple[float, str, str]]:
        """(time, behaviour, sync) by time; ties keep the document and sync-point order."""
        return sorted(((t, b, s) for (b, s), t in self.times.items()), key=lambda item: item[0])

    def as_known(self) -> dict[tuple[str, str, str], float]:
        """This block's times as a later block's `known`: (block, behaviour, sync), with the block's own start
        and end under behaviour "bml"."""
        known = {(self.block, b, s): t for (b, s), t in self.times.items()}
        known[(self.block, "bml", "start")] = self.start_s
        known[(self.block, "bml", "end")] = self.end_s
        return known
