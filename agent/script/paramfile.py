"""The paper's PLY-like parameter files: a header of typed properties, then `;`-separated transitions.

    header
    # head motion
    element transition 2
    property int duration
    property double turn_value
    property double nod_value
    property double tilt_value
    end_header
    2;1;0.8;0
    3;-1;-1;0.7

The kind of file (emotion, gaze, head, status) follows from its property names; docs/scripts.md has
the schema of each. Durations are seconds; without a `start` property transitions run back to back.
Parsing is all-or-nothing: the first problem raises ScriptError with its line and column.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import cast

from agent.config import load_toml
from agent.script.elements import AnimationElement, flexor_tuple
from agent.script.errors import ScriptError
from agent.script.poses import emotion_pose
from agent.script.textfile import decode_text, read_bytes, split_lines
from agent.script.vocab import (
    EYE_MODES,
    ROLES,
    ElementKind,
    Role,
    emotion_names,
    parse_emotion,
    parse_eye_mode,
    parse_role,
)

DEFAULT_AGENT = "agent"
Value = int | float | str
DEFAULT_EMOTION_TRANSITION_S = 0.5
TYPES = ("int", "double", "float", "string")
NUMERIC = ("int", "double", "float")

_INT_RE = re.compile(r"[+-]?[0-9]+")
_FLOAT_RE = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
AGENT_ID_RE = re.compile(r"[A-Za-z0-9_.-]{1,64}")


@dataclass(frozen=True)
class _Prop:
    """What a property may hold: its kinds (None = every kind), types, and canonical key."""

    key: str
    kinds: tuple[ElementKind, ...] | None
    types: tuple[str, ...]


_PROPS: dict[str, _Prop] = {
    "duration": _Prop("duration", None, NUMERIC),
    "start": _Prop("start", None, NUMERIC),
    "agent": _Prop("agent", None, ("string",)),
    "transition": _Prop("transition", ("head", "emotion"), NUMERIC),
    "turn_value": _Prop("turn", ("head",), NUMERIC),
    "nod_value": _Prop("nod", ("head",), NUMERIC),
    "tilt_value": _Prop("tilt", ("head",), NUMERIC),
    "turn": _Prop("turn", ("head",), NUMERIC),
    "nod": _Prop("nod", ("head",), NUMERIC),
    "tilt": _Prop("tilt", ("head",), NUMERIC),
    "emotion": _Prop("emotion", ("emotion",), ("string", "int")),
    "intensity": _Prop("intensity", ("emotion",), NUMERIC),
    "mode": _Prop("mode", ("gaze",), ("string",)),
    "eye_mode": _Prop("mode", ("gaze",), ("string",)),
    "yaw": _Prop("yaw", ("gaze",), NUMERIC),
    "pitch": _Prop("pitch", ("gaze",), NUMERIC),
    "look_x": _Prop("look_x", ("gaze",), NUMERIC),
    "look_y": _Prop("look_y", ("gaze",), NUMERIC),
    "role": _Prop("role", ("status",), ("string", "int")),
}
# A property of exactly one kind decides the kind of the file.
_KIND_NAMES = {"emotion": "emotion transitions", "gaze": "eye gaze movements",
               "head": "head movements", "status": "talking/listening status"}


@dataclass(frozen=True)
class _Column:
    name: str  # as written in the file
    key: str
    type: str
    line: int
    column: int


@dataclass(frozen=True)
class ParamFile:
    """A parsed parameter file: its kind and its elements in file order."""

    path: str
    kind: ElementKind
    elements: tuple[AnimationElement, ...]

    @property
    def kind_title(self) -> str:
        return _KIND_NAMES[self.kind]

    @property
    def length_s(self) -> float:
        return max((e.end_s for e in self.elements), default=0.0)


@lru_cache(maxsize=1)
def eye_range_deg() -> tuple[float, float]:
    """Degrees of gaze at look_x = +1 and look_y = +1."""
    eyes = load_toml("flexor_units")["eyes"]
    return float(eyes["look_x_deg"]), float(eyes["look_y_deg"])


def _tokens(line: str) -> list[tuple[str, int]]:
    return [(m.group(), m.start() + 1) for m in re.finditer(r"\S+", line)]


class _Parser:
    def __init__(self, name: str, agent: str, offset_s: float) -> None:
        self.name = name
        self.agent = agent
        self.offset_s = offset_s
        self.count = -1
        self.count_pos = (0, 0)
        self.columns: list[_Column] = []
        self.kind: ElementKind | None = None

    def fail(self, line: int, column: int, message: str) -> ScriptError:
        return ScriptError(self.name, line, column, message)

    # --- header -------------------------------------------------------------------------------

    def header(self, lines: list[str]) -> int:
        """Reads the header; returns the index of the first data line."""
        first = lines[0].strip()
        if first != "header":
            shown = first if len(first) <= 40 else first[:40] + "..."
            raise self.fail(1, 1, f"expected 'header' on the first line, found {shown!r}")
        for i in range(1, len(lines)):
            tokens = _tokens(lines[i])
            if not tokens or tokens[0][0].startswith("#") or tokens[0][0] == "comment":
                continue
            word, col = tokens[0]
            if word == "end_header":
                if len(tokens) > 1:
                    raise self.fail(i + 1, tokens[1][1], "unexpected text after 'end_header'")
                self.finish_header(i + 1)
                return i + 1
            if word == "element":
                self.element(i + 1, tokens)
            elif word == "property":
                self.property(i + 1, tokens)
            else:
                raise self.fail(i + 1, col, f"unknown header keyword {word!r}; expected element, "
                                            "property, comment or end_header")
        raise self.fail(len(lines), 1, "missing 'end_header': the header never ends")

    def element(self, line: int, tokens: list[tuple[str, int]]) -> None:
        if self.count >= 0:
            raise self.fail(line, tokens[0][1], "a second 'element' line; a file holds one element list")
        if len(tokens) != 3:
            raise self.fail(line, tokens[0][1], "expected 'element transition COUNT'")
        (name, name_col), (count, count_col) = tokens[1], tokens[2]
        if name != "transition":
            raise self.fail(line, name_col, f"unknown element {name!r}; expected 'transition'")
        if not re.fullmatch(r"[0-9]+", count) or len(count) > 9:
            raise self.fail(line, count_col, f"element count {count!r} is not a non-negative integer")
        self.count = int(count)
        self.count_pos = (line, count_col)

    def property(self, line: int, tokens: list[tuple[str, int]]) -> None:
        if self.count < 0:
            raise self.fail(line, tokens[0][1], "'property' before 'element transition COUNT'")
        if len(tokens) != 3:
            raise self.fail(line, tokens[0][1], "expected 'property TYPE NAME'")
        (ptype, type_col), (name, name_col) = tokens[1], tokens[2]
        if ptype not in TYPES:
            raise self.fail(line, type_col, f"unknown property type {ptype!r}; expected one of "
                                            f"{', '.join(TYPES)}")
        spec = _PROPS.get(name)
        if spec is None:
            raise self.fail(line, name_col, f"unknown property {name!r}; known properties: "
                                            f"{', '.join(_PROPS)}")
        if ptype not in spec.types:
            raise self.fail(line, type_col, f"property {name} must be of type "
                                            f"{' or '.join(spec.types)}, not {ptype}")
        for other in self.columns:
            if other.key == spec.key:
                raise self.fail(line, name_col, f"property {name} repeats {other.name} "
                                                f"(line {other.line})")
        if spec.kinds is not None and len(spec.kinds) == 1:
            kind = spec.kinds[0]
            if self.kind is not None and self.kind != kind:
                raise self.fail(line, name_col, f"property {name} belongs to {_KIND_NAMES[kind]} but "
                                                f"earlier properties make this a file of "
                                                f"{_KIND_NAMES[self.kind]}")
            self.kind = kind
        self.columns.append(_Column(name, spec.key, ptype, line, name_col))

    def finish_header(self, line: int) -> None:
        if self.count < 0:
            raise self.fail(line, 1, "'end_header' before 'element transition COUNT'")
        keys = {c.key: c for c in self.columns}
        if "duration" not in keys:
            raise self.fail(line, 1, "missing property 'duration' (seconds)")
        if self.kind is None:
            raise self.fail(line, 1, "cannot tell the kind of file: declare emotion, role, mode/yaw/"
                                     "pitch/look_x/look_y, or turn_value/nod_value/tilt_value")
        for c in self.columns:
            spec = _PROPS[c.name]
            if spec.kinds is not None and self.kind not in spec.kinds:
                raise self.fail(c.line, c.column, f"property {c.name} has no meaning in a file of "
                                                  f"{_KIND_NAMES[self.kind]}")
        for a, b in (("yaw", "pitch"), ("look_x", "look_y")):
            if (a in keys) != (b in keys):
                have, lack = (a, b) if a in keys else (b, a)
                raise self.fail(keys[have].line, keys[have].column, f"property {have} needs {lack} too")
        if "yaw" in keys and "look_x" in keys:
            raise self.fail(keys["look_x"].line, keys["look_x"].column,
                            "give the gaze target as yaw/pitch or as look_x/look_y, not both")

    # --- data ---------------------------------------------------------------------------------

    def data(self, lines: list[str], first: int) -> tuple[AnimationElement, ...]:
        rows: list[tuple[int, str]] = []
        for i in range(first, len(lines)):
            stripped = lines[i].strip()
            if not stripped or stripped.startswith("#"):
                continue
            if len(rows) == self.count:
                raise self.fail(i + 1, 1, f"too many data lines: the header declares {self.count} "
                                          f"transition{'s' if self.count != 1 else ''}")
            rows.append((i + 1, lines[i]))
        if len(rows) < self.count:
            line, col = self.count_pos
            raise self.fail(line, col, f"too few data lines: the header declares {self.count} "
                                       f"transitions, the file has {len(rows)}")
        elements = []
        clock = self.offset_s
        last_start: float | None = None
        for line, text in rows:
            values = self.split(line, text)
            element = self.element_of(line, values, clock, last_start)
            last_start = element.start_s
            clock = element.end_s
            elements.append(element)
        return tuple(elements)

    def split(self, line: int, text: str) -> dict[str, tuple[Value, int]]:
        fields: list[tuple[str, int]] = []
        pos = 0
        for part in text.split(";"):
            lead = len(part) - len(part.lstrip())
            fields.append((part.strip(), pos + lead + 1))
            pos += len(part) + 1
        if len(fields) != len(self.columns):
            n = len(self.columns)
            col = fields[n][1] if len(fields) > n else len(text.rstrip()) + 1
            raise self.fail(line, col, f"expected {n} value{'s' if n != 1 else ''} separated by ';' "
                                       f"({', '.join(c.name for c in self.columns)}), found {len(fields)}")
        return {c.key: (self.value(line, c, raw, col), col)
                for c, (raw, col) in zip(self.columns, fields, strict=True)}

    def value(self, line: int, c: _Column, raw: str, col: int) -> Value:
        if c.type == "string":
            if not raw:
                raise self.fail(line, col, f"empty value for property {c.name}")
            return raw
        pattern = _INT_RE if c.type == "int" else _FLOAT_RE
        if len(raw) > 40 and pattern.fullmatch(raw):
            # int() refuses thousands of digits with a ValueError of its own; no real value is this long
            raise self.fail(line, col, f"value for property {c.name} is {len(raw)} characters long")
        if not pattern.fullmatch(raw):
            shown = raw if len(raw) <= 30 else raw[:30] + "..."
            raise self.fail(line, col, f"value {shown!r} does not parse as {c.type} for property {c.name}")
        number = int(raw) if c.type == "int" else float(raw)
        if not math.isfinite(number) or abs(number) > 1e9:
            raise self.fail(line, col, f"value {raw!r} for property {c.name} is too large")
        return number

    def element_of(self, line: int, values: dict[str, tuple[Value, int]], clock: float,
                   last_start: float | None) -> AnimationElement:
        def number(key: str, lo: float, hi: float, unit: str = "") -> float | None:
            if key not in values:
                return None
            value, col = values[key]
            x = float(value)
            if not lo <= x <= hi:
                name = next(c.name for c in self.columns if c.key == key)
                raise self.fail(line, col, f"value {value} for property {name} is out of range "
                                           f"[{lo:g}, {hi:g}]{unit}")
            return x

        duration = values["duration"]
        if float(duration[0]) <= 0:
            raise self.fail(line, duration[1], f"duration {duration[0]} must be greater than 0 seconds")
        duration_s = float(duration[0])
        start_s = clock
        if "start" in values:
            start_value = number("start", 0.0, 1e9, " seconds")
            assert start_value is not None
            start_s = self.offset_s + start_value
            if last_start is not None and start_s < last_start:
                raise self.fail(line, values["start"][1], f"start {values['start'][0]} comes before the "
                                                          "previous transition's start; list transitions "
                                                          "in time order")
        agent = self.agent
        if "agent" in values:
            agent = str(values["agent"][0])
            if not AGENT_ID_RE.fullmatch(agent):
                raise self.fail(line, values["agent"][1], f"agent id {agent!r} must be 1-64 letters, "
                                                          "digits, '_', '-' or '.'")
        transition = number("transition", 0.0, duration_s, " seconds (at most the duration)")
        common = dict(start_s=start_s, duration_s=duration_s, agent=agent, file=self.name, line=line)
        assert self.kind is not None
        if self.kind == "head":
            axes = (number("turn", -1.0, 1.0), number("nod", -1.0, 1.0), number("tilt", -1.0, 1.0))
            flexors = {k: v for k, v in zip(("turn", "nod", "tilt"), axes, strict=True) if v is not None}
            return AnimationElement(kind="head", flexors=flexor_tuple(flexors), head=axes,
                                    transition_s=duration_s if transition is None else transition, **common)
        if self.kind == "emotion":
            name = self.choice(line, values["emotion"], emotion_names(), parse_emotion, "emotion")
            intensity = number("intensity", 0.0, 1.0)
            intensity = 1.0 if intensity is None else intensity
            if transition is None:
                transition = min(DEFAULT_EMOTION_TRANSITION_S, duration_s)
            return AnimationElement(kind="emotion", flexors=emotion_pose(name, intensity), emotion=name,
                                    intensity=intensity, transition_s=transition, **common)
        if self.kind == "status":
            role = cast(Role, self.choice(line, values["role"], ROLES, parse_role, "role"))
            return AnimationElement(kind="status", flexors=flexor_tuple({}), role=role,
                                    **common)
        return self.gaze(line, values, number, common)

    def gaze(self, line: int, values: dict[str, tuple[Value, int]],
             number: Callable[..., float | None], common: dict) -> AnimationElement:
        mode = None
        if "mode" in values:
            mode = parse_eye_mode(str(values["mode"][0]))
            if mode is None:
                raise self.fail(line, values["mode"][1], f"unknown eye mode {values['mode'][0]!r}; "
                                                         f"expected one of {', '.join(EYE_MODES)}")
        x_deg, y_deg = eye_range_deg()
        yaw = number("yaw", -x_deg, x_deg, " degrees")
        pitch = number("pitch", -y_deg, y_deg, " degrees")
        look_x = number("look_x", -1.0, 1.0)
        look_y = number("look_y", -1.0, 1.0)
        if look_x is not None and look_y is not None:
            yaw, pitch = look_x * x_deg, look_y * y_deg
        flexors = {}
        if yaw is not None and pitch is not None:
            flexors = {"look_x": yaw / x_deg, "look_y": pitch / y_deg}
        return AnimationElement(kind="gaze", flexors=flexor_tuple(flexors), eye_mode=mode, yaw_deg=yaw,
                                pitch_deg=pitch, **common)

    def choice(self, line: int, value: tuple[Value, int], names: tuple[str, ...],
               parse: Callable[[str], str | None], what: str) -> str:
        raw, col = value
        if isinstance(raw, int):
            if not 0 <= raw < len(names):
                raise self.fail(line, col, f"{what} index {raw} is out of range [0, {len(names) - 1}] "
                                           f"({', '.join(names)})")
            return names[raw]
        name = parse(str(raw))
        if name is None:
            raise self.fail(line, col, f"unknown {what} {raw!r}; expected one of {', '.join(names)}")
        return name


def parse_params(data: bytes | str, name: str = "<params>", *, agent: str = DEFAULT_AGENT,
                 offset_s: float = 0.0) -> ParamFile:
    """Parse a parameter file's content; `name` is the file name errors report."""
    text = decode_text(data.encode("utf-8", "surrogatepass") if isinstance(data, str) else data, name)
    lines = split_lines(text)
    parser = _Parser(name, agent, offset_s)
    first = parser.header(lines)
    elements = parser.data(lines, first)
    assert parser.kind is not None
    return ParamFile(name, parser.kind, elements)


def load_params(path: str | Path, *, agent: str = DEFAULT_AGENT, offset_s: float = 0.0) -> ParamFile:
    """Read and parse a parameter file; every problem raises ScriptError naming `path`."""
    return parse_params(read_bytes(path), str(path), agent=agent, offset_s=offset_s)
