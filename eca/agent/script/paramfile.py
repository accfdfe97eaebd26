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
Parsing is all-or-nothing: a file with any problem makes no elements. Every problem found is raised
at once (ScriptErrors, each with its line and column): a refused line is reported and reading goes on
with the next one.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, cast

from eca.agent.face.settings import load_flexor_units
from eca.agent.script.elements import AnimationElement, flexor_tuple
from eca.agent.script.errors import ScriptError, ScriptErrors, raise_collected
from eca.agent.script.poses import emotion_pose
from eca.agent.script.textfile import decode_text, read_bytes, split_lines
from eca.agent.script.vocab import (
    DEFAULT_AGENT,
    EYE_MODES,
    ROLES,
    ElementKind,
    Role,
    emotion_names,
    parse_emotion,
    parse_eye_mode,
    parse_role,
)

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
    usable: bool = True  # False: the declaration was refused; its values are read but mean nothing


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
    units = load_flexor_units()
    return units.look_x_deg, units.look_y_deg


def _tokens(line: str) -> list[tuple[str, int]]:
    return [(m.group(), m.start() + 1) for m in re.finditer(r"\S+", line)]


Fields = dict[str, tuple[Value, int]]  # property key -> (value, column)


class _Parser:
    """Reads a file line by line, recording every problem and going on where the rest still has a
    meaning: a refused header line leaves its column in place (so data lines still split right) but
    its values unused, and a refused data line makes no element."""

    def __init__(self, name: str, agent: str, offset_s: float) -> None:
        self.name = name
        self.agent = agent
        self.offset_s = offset_s
        self.count = -1  # -1: no usable `element` line
        self.count_pos = (0, 0)
        self.element_seen = False
        self.columns: list[_Column] = []
        self.columns_known = True  # False once a header line may have declared a column we cannot see
        self.header_refused = False
        self.kind: ElementKind | None = None
        self.errors: list[ScriptError] = []

    def report(self, line: int, column: int, message: str) -> None:
        self.errors.append(ScriptError(self.name, line, column, message))

    # --- header -------------------------------------------------------------------------------

    def header(self, lines: list[str]) -> int | None:
        """Reads the header; returns the index of the first data line, or None if there is none."""
        first = lines[0].strip()
        if first != "header":
            # Not a parameter file at all: reading on would only report the consequences.
            shown = first if len(first) <= 40 else first[:40] + "..."
            self.report(1, 1, f"expected 'header' on the first line, found {shown!r}")
            return None
        for i in range(1, len(lines)):
            tokens = _tokens(lines[i])
            if not tokens or tokens[0][0].startswith("#") or tokens[0][0] == "comment":
                continue
            word, col = tokens[0]
            if word == "end_header":
                if len(tokens) > 1:
                    self.report(i + 1, tokens[1][1], "unexpected text after 'end_header'")
                self.finish_header(i + 1)
                return i + 1
            if word == "element":
                self.element(i + 1, tokens)
            elif word == "property":
                self.property(i + 1, tokens)
            else:
                self.refuse_header_line(i + 1, col, f"unknown header keyword {word!r}; expected element, "
                                                    "property, comment or end_header")
                self.columns_known = False  # it may have been meant as a property
        self.report(len(lines), 1, "missing 'end_header': the header never ends")
        return None

    def refuse_header_line(self, line: int, column: int, message: str) -> None:
        self.report(line, column, message)
        self.header_refused = True

    def element(self, line: int, tokens: list[tuple[str, int]]) -> None:
        if self.element_seen:
            self.refuse_header_line(line, tokens[0][1], "a second 'element' line; a file holds one element list")
            return
        self.element_seen = True
        if len(tokens) != 3:
            self.refuse_header_line(line, tokens[0][1], "expected 'element transition COUNT'")
            return
        (name, name_col), (count, count_col) = tokens[1], tokens[2]
        if name != "transition":
            self.refuse_header_line(line, name_col, f"unknown element {name!r}; expected 'transition'")
        if not re.fullmatch(r"[0-9]+", count) or len(count) > 9:
            self.refuse_header_line(line, count_col, f"element count {count!r} is not a non-negative integer")
            return
        self.count = int(count)
        self.count_pos = (line, count_col)

    def property(self, line: int, tokens: list[tuple[str, int]]) -> None:
        if not self.element_seen:
            self.refuse_header_line(line, tokens[0][1], "'property' before 'element transition COUNT'")
        if len(tokens) != 3:
            self.refuse_header_line(line, tokens[0][1], "expected 'property TYPE NAME'")
            self.columns_known = False
            return
        (ptype, type_col), (name, name_col) = tokens[1], tokens[2]
        problem = self.property_problem(ptype, name)
        if problem is not None:
            self.refuse_header_line(line, type_col if problem[0] == "type" else name_col, problem[1])
        spec = _PROPS.get(name)
        usable = problem is None and spec is not None
        if usable and spec is not None and spec.kinds is not None and len(spec.kinds) == 1:
            self.kind = spec.kinds[0]
        self.columns.append(_Column(name, spec.key if spec is not None else name, ptype, line, name_col, usable))

    def property_problem(self, ptype: str, name: str) -> tuple[str, str] | None:
        """("type" or "name", message) when a `property TYPE NAME` line cannot be used."""
        if ptype not in TYPES:
            return "type", f"unknown property type {ptype!r}; expected one of {', '.join(TYPES)}"
        spec = _PROPS.get(name)
        if spec is None:
            return "name", f"unknown property {name!r}; known properties: {', '.join(_PROPS)}"
        if ptype not in spec.types:
            return "type", f"property {name} must be of type {' or '.join(spec.types)}, not {ptype}"
        for other in self.columns:
            if other.key == spec.key and other.usable:
                return "name", f"property {name} repeats {other.name} (line {other.line})"
        if spec.kinds is not None and len(spec.kinds) == 1:
            kind = spec.kinds[0]
            if self.kind is not None and self.kind != kind:
                return "name", (f"property {name} belongs to {_KIND_NAMES[kind]} but earlier properties "
                                f"make this a file of {_KIND_NAMES[self.kind]}")
        return None

    def finish_header(self, line: int) -> None:
        """Checks of the header as a whole; skipped once a line was refused, since the refused line may
        be the one that would have satisfied them."""
        if self.header_refused:
            return
        if not self.element_seen:
            self.refuse_header_line(line, 1, "'end_header' before 'element transition COUNT'")
        keys = {c.key: c for c in self.columns}
        if "duration" not in keys:
            self.refuse_header_line(line, 1, "missing property 'duration' (seconds)")
        if self.kind is None:
            self.refuse_header_line(line, 1, "cannot tell the kind of file: declare emotion, role, mode/yaw/"
                                             "pitch/look_x/look_y, or turn_value/nod_value/tilt_value")
        for i, c in enumerate(self.columns):
            spec = _PROPS[c.name]
            if self.kind is not None and spec.kinds is not None and self.kind not in spec.kinds:
                self.refuse_header_line(c.line, c.column, f"property {c.name} has no meaning in a file of "
                                                          f"{_KIND_NAMES[self.kind]}")
                self.columns[i] = dataclasses.replace(c, usable=False)
        for a, b in (("yaw", "pitch"), ("look_x", "look_y")):
            if (a in keys) != (b in keys):
                have, lack = (a, b) if a in keys else (b, a)
                self.refuse_header_line(keys[have].line, keys[have].column, f"property {have} needs {lack} too")
        if "yaw" in keys and "look_x" in keys:
            self.refuse_header_line(keys["look_x"].line, keys["look_x"].column,
                                    "give the gaze target as yaw/pitch or as look_x/look_y, not both")

    # --- data ---------------------------------------------------------------------------------

    def data(self, lines: list[str], first: int) -> tuple[AnimationElement, ...]:
        if not self.columns_known:
            return ()  # which value is which is unknown: checking them would report nonsense
        rows: list[tuple[int, str]] = []
        for i in range(first, len(lines)):
            stripped = lines[i].strip()
            if not stripped or stripped.startswith("#"):
                continue
            if len(rows) == self.count:
                self.report(i + 1, 1, f"too many data lines: the header declares {self.count} "
                                      f"transition{'s' if self.count != 1 else ''}")
            rows.append((i + 1, lines[i]))
        if len(rows) < self.count:
            line, col = self.count_pos
            self.report(line, col, f"too few data lines: the header declares {self.count} "
                                   f"transitions, the file has {len(rows)}")
        elements = []
        clock = self.offset_s
        last_start: float | None = None
        for line, text in rows:
            values = self.split(line, text)
            if values is None or self.kind is None:
                continue
            element = self.element_of(line, values, clock, last_start)
            if element is not None:
                last_start = element.start_s
                clock = element.end_s
                elements.append(element)
        return tuple(elements)

    def split(self, line: int, text: str) -> Fields | None:
        """The line's values by property key (usable columns whose value parses); None if the line
        does not hold one value per column."""
        fields: list[tuple[str, int]] = []
        pos = 0
        for part in text.split(";"):
            lead = len(part) - len(part.lstrip())
            fields.append((part.strip(), pos + lead + 1))
            pos += len(part) + 1
        if len(fields) != len(self.columns):
            n = len(self.columns)
            col = fields[n][1] if len(fields) > n else len(text.rstrip()) + 1
            self.report(line, col, f"expected {n} value{'s' if n != 1 else ''} separated by ';' "
                                   f"({', '.join(c.name for c in self.columns)}), found {len(fields)}")
            return None
        values: Fields = {}
        for c, (raw, col) in zip(self.columns, fields, strict=True):
            if c.type not in TYPES:
                continue  # an unknown type: nothing to read the value as
            value = self.value(line, c, raw, col)
            if value is not None and c.usable:
                values[c.key] = (value, col)
        return values

    def value(self, line: int, c: _Column, raw: str, col: int) -> Value | None:
        if c.type == "string":
            if not raw:
                self.report(line, col, f"empty value for property {c.name}")
                return None
            return raw
        pattern = _INT_RE if c.type == "int" else _FLOAT_RE
        if len(raw) > 40 and pattern.fullmatch(raw):
            # int() refuses thousands of digits with a ValueError of its own; no real value is this long
            self.report(line, col, f"value for property {c.name} is {len(raw)} characters long")
            return None
        if not pattern.fullmatch(raw):
            shown = raw if len(raw) <= 30 else raw[:30] + "..."
            self.report(line, col, f"value {shown!r} does not parse as {c.type} for property {c.name}")
            return None
        number = int(raw) if c.type == "int" else float(raw)
        if not math.isfinite(number) or abs(number) > 1e9:
            self.report(line, col, f"value {raw!r} for property {c.name} is too large")
            return None
        return number

    def number(self, line: int, values: Fields, key: str, lo: float, hi: float, unit: str = "") -> float | None:
        """The value of `key` within [lo, hi]; None (reported) when out of range, None when absent."""
        if key not in values:
            return None
        value, col = values[key]
        x = float(value)
        if not lo <= x <= hi:
            name = next(c.name for c in self.columns if c.key == key and c.usable)
            self.report(line, col, f"value {value} for property {name} is out of range [{lo:g}, {hi:g}]{unit}")
            return None
        return x

    def element_of(self, line: int, values: Fields, clock: float,
                   last_start: float | None) -> AnimationElement | None:
        """The line's element, after checking every value it has; None when any check failed."""
        errors_before = len(self.errors)
        duration_s = None
        if "duration" in values:
            duration, duration_col = values["duration"]
            if float(duration) <= 0:
                self.report(line, duration_col, f"duration {duration} must be greater than 0 seconds")
            else:
                duration_s = float(duration)
        start_s = clock
        start_value = self.number(line, values, "start", 0.0, 1e9, " seconds")
        if start_value is not None:
            start_s = self.offset_s + start_value
            if last_start is not None and start_s < last_start:
                self.report(line, values["start"][1], f"start {values['start'][0]} comes before the previous "
                                                      "transition's start; list transitions in time order")
        agent = self.agent
        if "agent" in values:
            agent = str(values["agent"][0])
            if not AGENT_ID_RE.fullmatch(agent):
                self.report(line, values["agent"][1], f"agent id {agent!r} must be 1-64 letters, digits, "
                                                      "'_', '-' or '.'")
        if duration_s is not None:
            transition = self.number(line, values, "transition", 0.0, duration_s,
                                     " seconds (at most the duration)")
        else:
            transition = self.number(line, values, "transition", 0.0, 1e9, " seconds")
        payload = self.payload(line, values, duration_s, transition)
        if payload is None or duration_s is None or len(self.errors) > errors_before or self.header_refused:
            return None
        return AnimationElement(start_s=start_s, duration_s=duration_s, agent=agent, file=self.name, line=line,
                                **payload)

    def payload(self, line: int, values: Fields, duration_s: float | None,
                transition: float | None) -> dict[str, Any] | None:
        """The kind's own fields of an element, checked; None when a required one is missing or wrong."""
        if self.kind == "head":
            axes = tuple(self.number(line, values, k, -1.0, 1.0) for k in ("turn", "nod", "tilt"))
            flexors = {k: v for k, v in zip(("turn", "nod", "tilt"), axes, strict=True) if v is not None}
            return dict(kind="head", flexors=flexor_tuple(flexors), head=axes,
                        transition_s=(duration_s or 0.0) if transition is None else transition)
        if self.kind == "emotion":
            name = self.choice(line, values.get("emotion"), emotion_names(), parse_emotion, "emotion")
            intensity = self.number(line, values, "intensity", 0.0, 1.0)
            if "intensity" not in values:
                intensity = 1.0
            if name is None or intensity is None:
                return None
            if transition is None:
                transition = min(DEFAULT_EMOTION_TRANSITION_S, duration_s or 0.0)
            return dict(kind="emotion", flexors=emotion_pose(name, intensity), emotion=name,
                        intensity=intensity, transition_s=transition)
        if self.kind == "status":
            role = self.choice(line, values.get("role"), ROLES, parse_role, "role")
            return None if role is None else dict(kind="status", flexors=flexor_tuple({}), role=cast(Role, role))
        return self.gaze(line, values)

    def gaze(self, line: int, values: Fields) -> dict[str, Any] | None:
        mode = None
        if "mode" in values:
            mode = parse_eye_mode(str(values["mode"][0]))
            if mode is None:
                self.report(line, values["mode"][1], f"unknown eye mode {values['mode'][0]!r}; "
                                                     f"expected one of {', '.join(EYE_MODES)}")
        x_deg, y_deg = eye_range_deg()
        yaw = self.number(line, values, "yaw", -x_deg, x_deg, " degrees")
        pitch = self.number(line, values, "pitch", -y_deg, y_deg, " degrees")
        look_x = self.number(line, values, "look_x", -1.0, 1.0)
        look_y = self.number(line, values, "look_y", -1.0, 1.0)
        if look_x is not None and look_y is not None:
            yaw, pitch = look_x * x_deg, look_y * y_deg
        flexors = {}
        if yaw is not None and pitch is not None:
            flexors = {"look_x": yaw / x_deg, "look_y": pitch / y_deg}
        return dict(kind="gaze", flexors=flexor_tuple(flexors), eye_mode=mode, yaw_deg=yaw, pitch_deg=pitch)

    def choice(self, line: int, value: tuple[Value, int] | None, names: tuple[str, ...],
               parse: Callable[[str], str | None], what: str) -> str | None:
        if value is None:
            return None  # its column was refused, or its value did not parse: reported already
        raw, col = value
        if isinstance(raw, int):
            if not 0 <= raw < len(names):
                self.report(line, col, f"{what} index {raw} is out of range [0, {len(names) - 1}] "
                                       f"({', '.join(names)})")
                return None
            return names[raw]
        name = parse(str(raw))
        if name is None:
            self.report(line, col, f"unknown {what} {raw!r}; expected one of {', '.join(names)}")
        return name


def parse_params(data: bytes | str, name: str = "<params>", *, agent: str = DEFAULT_AGENT,
                 offset_s: float = 0.0) -> ParamFile:
    """Parse a parameter file's content; `name` is the file name errors report.

    Every problem found is raised at once as ScriptErrors, in line and column order.
    """
    try:
        text = decode_text(data.encode("utf-8", "surrogatepass") if isinstance(data, str) else data, name)
    except ScriptError as exc:
        raise ScriptErrors([exc]) from None
    lines = split_lines(text)
    parser = _Parser(name, agent, offset_s)
    first = parser.header(lines)
    elements = parser.data(lines, first) if first is not None else ()
    raise_collected(parser.errors, name)
    assert parser.kind is not None
    return ParamFile(name, parser.kind, elements)


def load_params(path: str | Path, *, agent: str = DEFAULT_AGENT, offset_s: float = 0.0) -> ParamFile:
    """Read and parse a parameter file; every problem raises ScriptErrors naming `path`."""
    try:
        data = read_bytes(path)
    except ScriptError as exc:
        raise ScriptErrors([exc]) from None
    return parse_params(data, str(path), agent=agent, offset_s=offset_s)
