"""What a face behaviour's attributes become: flexor offsets, head motions, gaze and emotion parameters.

The tables (face lexemes, FACS action units, head lexemes and degrees, default timings) come from
configs/bml.toml, the emotion names from configs/emotions.toml; both replaceable through $ECA_CONFIG_DIR. Each
builder takes an element's plain attributes and raises ValueError for a block that must be refused (a missing
required attribute, a number out of range) or Unrealizable for a behaviour the face cannot perform (an unknown
lexeme), which the parser turns into a warning.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass, fields
from types import MappingProxyType
from typing import Any, Literal, cast, get_args

from eca.agent.bml.model import (
    MAX_OFFSET_S,
    MAX_REPETITION,
    EmotionParams,
    FaceParams,
    GazeParams,
    HeadDirectionParams,
    HeadParams,
    RoleParams,
    WaitParams,
    parse_decimal,
)
from eca.agent.config import ConfigError, config_path, load_toml
from eca.agent.face.emotions import canonical_emotion_name
from eca.agent.face.flexors import FLEXOR_NAMES
from eca.agent.vocabulary import ROLES

HeadLexeme = Literal["nod", "shake", "tilt"]
HEAD_LEXEMES: tuple[HeadLexeme, ...] = get_args(HeadLexeme)
SIDED = ("blink", "lids", "brow", "smile", "sneer")  # flexors with a _l and a _r
SIDES = ("LEFT", "RIGHT", "BOTH")
OFFSET_DIRECTIONS = ("NONE", "RIGHT", "LEFT", "UP", "DOWN", "UPRIGHT", "UPLEFT", "DOWNLEFT", "DOWNRIGHT", "POLAR")
MAX_TARGET_CHARS = 128


class Unrealizable(Exception):
    """The behaviour is well formed but names something the face cannot do; the rest of the block runs."""


@dataclass(frozen=True)
class BehaviourTimings:
    """Default durations (seconds) of a behaviour whose sync attributes leave them free: bml.toml [timings]."""

    face_attack_s: float
    face_hold_s: float
    face_relax_s: float
    head_prepare_s: float
    head_stroke_s: float
    head_retract_s: float
    head_shift_s: float
    gaze_ready_s: float
    gaze_hold_s: float
    gaze_relax_s: float
    blink_closed_s: float
    blink_s: float
    wait_s: float
    unrealized_s: float

    @classmethod
    def from_config(cls) -> BehaviourTimings:
        return bml_tables().timings


@dataclass(frozen=True)
class BmlTables:
    lexemes: Mapping[str, Mapping[str, float]]  # face lexeme -> flexor values at amount 1 (sides spelled out)
    action_units: Mapping[int, Mapping[str, float]]  # AU -> flexor values at amount 1 (two-sided names kept)
    head_lexemes: Mapping[str, HeadLexeme]
    head_degrees: Mapping[HeadLexeme, tuple[float, float]]  # amount 0 and amount 1
    influences: tuple[str, ...]
    default_influence: str
    emotions: tuple[str, ...]
    emotion_transition_s: float
    timings: BehaviourTimings


def bml_tables() -> BmlTables:
    """The tables of the configs in use; read again when a file changes (a test's own $ECA_CONFIG_DIR)."""
    paths = (config_path("bml"), config_path("emotions"))
    try:
        stamps = tuple(path.stat().st_mtime_ns for path in paths)
    except OSError as exc:
        raise ConfigError(f"{exc.filename}: config file not found") from None
    return _load(str(paths[0]), str(paths[1]), stamps)


@functools.lru_cache(maxsize=4)
def _load(bml_path: str, emotions_path: str, stamps: tuple[int, ...]) -> BmlTables:
    raw = load_toml(bml_path)
    where = bml_path
    face = _table(raw, "face", where)
    head = _table(raw, "head", where)
    gaze = _table(raw, "gaze", where)
    timings = BehaviourTimings(**{field.name: _seconds(_table(raw, "timings", where), field.name, f"{where} [timings]")
                                  for field in fields(BehaviourTimings)})
    lexemes = {name.upper(): _both_sides(_flexor_row(row, f"{where} [face.lexemes] {name}"))
               for name, row in _table(face, "lexemes", where).items()}
    units: dict[int, Mapping[str, float]] = {}
    for key, row in _table(face, "aus", where).items():
        if not key.isdigit():
            raise ConfigError(f"{where} [face.aus]: '{key}' is not an action unit number")
        units[int(key)] = _flexor_row(row, f"{where} [face.aus] {key}")
    head_lexemes: dict[str, HeadLexeme] = {}
    for name, motion in _table(head, "lexemes", where).items():
        if motion not in HEAD_LEXEMES:
            raise ConfigError(f"{where} [head] lexemes.{name}: '{motion}' is not one of {HEAD_LEXEMES}")
        head_lexemes[name.upper()] = cast(HeadLexeme, motion)
    degrees = {motion: _degree_range(head, f"{motion}_deg", where) for motion in HEAD_LEXEMES}
    influences = tuple(str(name).upper() for name in gaze.get("influences", ()))
    default = str(gaze.get("default_influence", "")).upper()
    if default not in influences:
        raise ConfigError(f"{where} [gaze]: default_influence '{default}' is not one of influences {influences}")
    emotions = tuple(canonical_emotion_name(name) for name in load_toml(emotions_path))
    transition = _seconds(_table(raw, "emotion", where), "transition_s", f"{where} [emotion]")
    return BmlTables(_frozen(lexemes), _frozen(units), _frozen(head_lexemes), _frozen(degrees), influences,
                     default, emotions, transition, timings)


def _table(raw: Mapping[str, Any], key: str, where: str) -> Mapping[str, Any]:
    value = raw.get(key)
    if not isinstance(value, dict):
        raise ConfigError(f"{where}: missing table [{key}]")
    return value


def _seconds(table: Mapping[str, Any], key: str, where: str) -> float:
    value = table.get(key)
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 <= value <= MAX_OFFSET_S:
        raise ConfigError(f"{where}: '{key}' must be seconds in [0, {MAX_OFFSET_S:g}], got {value!r}")
    return float(value)


def _degree_range(table: Mapping[str, Any], key: str, where: str) -> tuple[float, float]:
    value = table.get(key)
    if (not isinstance(value, list) or len(value) != 2
            or not all(isinstance(v, int | float) and not isinstance(v, bool) and 0 <= v <= 90 for v in value)):
        raise ConfigError(f"{where} [head]: '{key}' must be [tiny, maximal] degrees in [0, 90], got {value!r}")
    return float(value[0]), float(value[1])


def _flexor_row(row: Any, where: str) -> dict[str, float]:
    if not isinstance(row, dict) or not row:
        raise ConfigError(f"{where}: must be a table of flexor = value")
    for name, value in row.items():
        if name not in FLEXOR_NAMES and name not in SIDED:
            raise ConfigError(f"{where}: '{name}' is not a flexor (eca/agent/face/flexors.py)")
        if isinstance(value, bool) or not isinstance(value, int | float) or not -1.0 <= value <= 1.0:
            raise ConfigError(f"{where}: {name} must lie in [-1, 1], got {value!r}")
    return {name: float(value) for name, value in row.items()}


def _both_sides(row: Mapping[str, float]) -> dict[str, float]:
    return _sided(row, "BOTH")


def _sided(row: Mapping[str, float], side: str) -> dict[str, float]:
    """The row with each two-sided name spelled out for `side` (LEFT, RIGHT or BOTH)."""
    out: dict[str, float] = {}
    for name, value in row.items():
        if name in SIDED:
            for suffix, which in (("_l", "LEFT"), ("_r", "RIGHT")):
                if side in (which, "BOTH"):
                    out[name + suffix] = value
        else:
            out[name] = value
    return out


def _frozen(mapping: Mapping[Any, Any]) -> Mapping[Any, Any]:
    return MappingProxyType(dict(mapping))


# -- attribute values --


def required(attrs: Mapping[str, str], name: str, kind: str) -> str:
    value = attrs.get(name, "").strip()
    if not value:
        raise ValueError(f"<{kind}> needs a '{name}' attribute")
    return value


def number(attrs: Mapping[str, str], name: str, default: float, low: float, high: float) -> float:
    text = attrs.get(name)
    if text is None:
        return default
    try:
        value = parse_decimal(text)
    except ValueError as exc:
        raise ValueError(f"attribute '{name}': {exc}") from None
    if not low <= value <= high:
        raise ValueError(f"attribute '{name}' = {text.strip()[:40]} lies outside [{low:g}, {high:g}]")
    return value


def whole_number(attrs: Mapping[str, str], names: tuple[str, ...], default: int, low: int, high: int) -> int:
    for name in names:
        text = attrs.get(name)
        if text is not None:
            stripped = text.strip()
            if not stripped.isdigit() or len(stripped) > 6 or not low <= int(stripped) <= high:
                raise ValueError(f"attribute '{name}' = '{stripped[:40]}' must be a whole number in [{low}, {high}]")
            return int(stripped)
    return default


def target(attrs: Mapping[str, str], kind: str) -> str:
    value = required(attrs, "target", kind)
    if len(value) > MAX_TARGET_CHARS or not value.isprintable():
        raise ValueError(f"attribute 'target' must be a printable name of at most {MAX_TARGET_CHARS} characters")
    return value


def _amount(attrs: Mapping[str, str]) -> float:
    return number(attrs, "amount", 0.5, 0.0, 1.0)


def _scaled(row: Mapping[str, float], amount: float) -> Mapping[str, float]:
    return MappingProxyType({name: min(1.0, max(-1.0, value * amount)) for name, value in row.items()})


# -- the builders --


def face_lexeme(attrs: Mapping[str, str], tables: BmlTables, kind: str) -> FaceParams:
    """faceLexeme, faceShift, and SmartBody's <face type="lexeme" lexeme=...>."""
    lexeme = required(attrs, "lexeme", kind)
    amount = _amount(attrs)
    row = tables.lexemes.get(lexeme.upper())
    if row is None:
        raise Unrealizable(f"face lexeme '{lexeme[:64]}' is not one eca knows (configs/bml.toml [face.lexemes])")
    return FaceParams(_scaled(row, amount), f"{kind} {lexeme.upper()}", kind == "faceShift")


def face_facs(attrs: Mapping[str, str], tables: BmlTables, kind: str) -> FaceParams:
    """faceFacs (au, side), and SmartBody's <face type="facs" au="1_left">."""
    written = required(attrs, "au", kind)
    number_part, _, side_part = written.partition("_")
    side = (attrs.get("side") or side_part or "BOTH").strip().upper()
    if not number_part.strip().isdigit() or len(number_part) > 4:
        raise ValueError(f"attribute 'au' = '{written[:40]}' must be an action unit number (SmartBody: 1_left)")
    amount = _amount(attrs)
    unit = int(number_part)
    if side not in SIDES:
        raise Unrealizable(f"side '{side[:20]}' is not LEFT, RIGHT or BOTH")
    row = tables.action_units.get(unit)
    if row is None:
        raise Unrealizable(f"action unit {unit} is not one eca can show (configs/bml.toml [face.aus])")
    return FaceParams(_scaled(_sided(row, side), amount), f"{kind} AU{unit} {side}", False)


def smartbody_face(attrs: Mapping[str, str], tables: BmlTables) -> tuple[str, FaceParams]:
    """SmartBody's and the older drafts' <face type="facs" au=...> or <face type="lexeme" lexeme=...>:
    (the kind it is, its params)."""
    kind = (attrs.get("type") or "").strip().lower()
    if kind == "facs" or (not kind and "au" in attrs):
        return "faceFacs", face_facs(attrs, tables, "face")
    if kind == "lexeme" or (not kind and "lexeme" in attrs):
        return "faceLexeme", face_lexeme(attrs, tables, "face")
    if not kind:
        raise ValueError("<face> needs type=\"facs\" with an 'au', or a 'lexeme'")
    raise Unrealizable(f"face type '{kind[:40]}' is not facs or lexeme")


def head(attrs: Mapping[str, str], tables: BmlTables) -> HeadParams | HeadDirectionParams:
    """head lexeme (BML 1.0) or type (SmartBody); repetition or SmartBody's repeats; amount."""
    written = (attrs.get("lexeme") or attrs.get("type") or "").strip()
    if not written:
        raise ValueError("<head> needs a 'lexeme' attribute (or SmartBody's 'type')")
    if written.upper() == "ORIENT":
        if not attrs.get("target", "").strip():
            raise Unrealizable("head ORIENT without a target: eca turns the head toward a target only")
        return HeadDirectionParams(target(attrs, "head"))
    repetitions = whole_number(attrs, ("repetition", "repeats"), 1, 1, MAX_REPETITION)
    amount = _amount(attrs)
    motion = tables.head_lexemes.get(written.upper())
    if motion is None:
        raise Unrealizable(f"head lexeme '{written[:64]}' is not one eca knows (configs/bml.toml [head] lexemes)")
    tiny, maximal = tables.head_degrees[motion]
    return HeadParams(motion, repetitions, tiny + amount * (maximal - tiny), written[:64])


def gaze(attrs: Mapping[str, str], tables: BmlTables, kind: str) -> GazeParams:
    where = target(attrs, kind)
    influence = (attrs.get("influence") or tables.default_influence).strip().upper()
    angle = number(attrs, "offsetAngle", 0.0, -180.0, 180.0)
    direction = (attrs.get("offsetDirection") or "NONE").strip().upper()
    if influence not in tables.influences:
        raise Unrealizable(f"gaze influence '{influence[:20]}' is not one of {', '.join(tables.influences)}")
    if direction not in OFFSET_DIRECTIONS:
        raise Unrealizable(f"offsetDirection '{direction[:20]}' is not one of {', '.join(OFFSET_DIRECTIONS)}")
    return GazeParams(where, influence, angle, direction, kind == "gazeShift")


def wait(attrs: Mapping[str, str]) -> WaitParams:
    if "max-wait" not in attrs:
        return WaitParams(None)
    return WaitParams(number(attrs, "max-wait", 0.0, 0.0, MAX_OFFSET_S))


def emotion(attrs: Mapping[str, str], tables: BmlTables) -> EmotionParams:
    name = canonical_emotion_name(required(attrs, "name", "eca:emotion"))
    intensity = number(attrs, "intensity", 1.0, 0.0, 1.0)
    transition = number(attrs, "transition", tables.emotion_transition_s, 0.0, MAX_OFFSET_S)
    if name not in tables.emotions:
        raise Unrealizable(f"emotion '{name[:40]}' is not one of {', '.join(tables.emotions)}")
    return EmotionParams(name, intensity, transition)


def role(attrs: Mapping[str, str]) -> RoleParams:
    value = required(attrs, "role", "eca:role").lower()
    if value not in ROLES:
        raise Unrealizable(f"role '{value[:40]}' is not one of {', '.join(ROLES)}")
    return RoleParams(value)
