"""The versioned msgpack codec. Decoding validates strictly; every problem is one `ProtocolError`.

On the wire a message is a msgpack map: the envelope keys `v`, `type`, `agent`, `seq`, `t_ns`,
`source` and the body fields of its type, nothing else. Nothing from the bus is ever unpickled or
evaluated: msgpack gives plain data, and only the known dataclasses are built from it.
"""

from __future__ import annotations

import dataclasses
import math
import re
import sys
import types
import typing
from collections.abc import Callable
from typing import Any, Literal

import msgpack

from eca.protocol.messages import AGENT_ID_PATTERN, ALL_AGENTS, MESSAGE_TYPES, PROTOCOL_VERSION, Message

DEFAULT_MAX_BYTES = 4 * 1024 * 1024
# msgpack's packer starts with a 256 KiB buffer of its own for every message it packs. In a process that keeps
# allocations that large mapped (a fixed glibc mmap threshold under 256 KiB, as eca's services set one so that a
# flood's memory goes back), every message then mapped and unmapped that buffer: 8 us a message instead of 0.7.
# A smaller start holds a message of any size just the same: the buffer grows as it fills.
PACK_BUFFER_BYTES = 16 * 1024
ENVELOPE_KEYS = ("v", "type")
_AGENT_ID = re.compile(AGENT_ID_PATTERN)


def packb(obj: Any) -> bytes:
    """msgpack bytes of `obj` (bin type for bytes), through a packer whose buffer starts small."""
    data: bytes = msgpack.packb(obj, use_bin_type=True, buf_size=PACK_BUFFER_BYTES)
    return data


def is_agent_id(text: str) -> bool:
    """Whether `text` is a valid agent id: 1-32 letters, digits, '_' or '-', or '*' (no single agent)."""
    return text == ALL_AGENTS or _AGENT_ID.fullmatch(text) is not None


class ProtocolError(ValueError):
    """A message that is not valid eca protocol; `field` and `kind` say where and what.

    `agent` and `request_id` are what the offending map said they were, when that much of it could be
    read (a valid agent id, a request id string of 1-64 characters), so an error about a command still
    reaches the agent's error topic with the request's id; empty otherwise."""

    def __init__(self, kind: str, problem: str, field: str = "", *, agent: str = "", request_id: str = "") -> None:
        self.kind = kind
        self.field = field
        self.problem = problem
        self.agent = agent
        self.request_id = request_id
        where = f"field '{field}': " if field else ""
        super().__init__(f"{where}{problem}")


@dataclasses.dataclass(frozen=True)
class FieldSpec:
    name: str
    kind: Any  # the annotation, resolved
    required: bool
    lo: float | None
    hi: float | None
    max_len: int | None
    item_max_len: int | None = None  # each string of a list of strings
    min_len: int | None = None  # the fewest entries of a list


_SPECS: dict[type[Message], tuple[FieldSpec, ...]] = {}


def field_specs(cls: type[Message]) -> tuple[FieldSpec, ...]:
    specs = _SPECS.get(cls)
    if specs is None:
        hints = typing.get_type_hints(cls)
        missing = dataclasses.MISSING
        specs = _SPECS[cls] = tuple(
            FieldSpec(f.name, hints[f.name], f.default is missing and f.default_factory is missing,
                      f.metadata.get("lo"), f.metadata.get("hi"), f.metadata.get("max_len"),
                      f.metadata.get("item_max_len"), f.metadata.get("min_len"))
            for f in dataclasses.fields(cls))
    return specs


def encode(msg: Message, max_bytes: int = DEFAULT_MAX_BYTES) -> bytes:
    """Validate and pack a message; what we send passes the same checks as what we receive."""
    plan = _plan(type(msg))
    values = msg.__dict__
    body: dict[str, Any] = {"v": PROTOCOL_VERSION, "type": msg.TYPE}
    name = ""
    try:
        for name, _, check in plan.checks:
            body[name] = check(values[name])
    except _Bad as bad:
        raise ProtocolError(bad.kind, bad.problem, name + bad.sub) from None
    if plan.cross_checked:
        _check_consistency(msg)
    data = packb(body)
    if len(data) > max_bytes:
        raise ProtocolError("oversize", f"message is {len(data)} bytes, over the cap of {max_bytes}")
    return data


def decode(data: bytes, max_bytes: int = DEFAULT_MAX_BYTES) -> Message:
    """Unpack and validate one message; every problem is one ProtocolError whose reason is a plain
    sentence of bounded length. Nothing here walks an untrusted value deeper than the message type's
    own fields, nor prints one whole (`describe`), so no nesting or size can make decoding fail
    any other way."""
    if type(data) is not bytes and not isinstance(data, bytes | bytearray | memoryview):
        raise ProtocolError("not_msgpack", f"expected bytes, got {type(data).__name__}")
    if len(data) > max_bytes:
        raise ProtocolError("oversize", f"message is {len(data)} bytes, over the cap of {max_bytes}")
    try:
        raw = msgpack.unpackb(data, raw=False, strict_map_key=True, use_list=True, timestamp=0)
    except Exception as exc:  # msgpack raises many types (ExtraData, FormatError, StackError, ...)
        raise ProtocolError("not_msgpack", _unpack_problem(exc)) from None
    if type(raw) is not dict:
        raise ProtocolError("wrong_type", f"the payload must be a msgpack map, got {_type_name(raw)}")
    agent, request_id = _identity(raw)
    version = raw.get("v")
    if type(version) is not int or version != PROTOCOL_VERSION:
        raise ProtocolError("unknown_version", _version_problem(version), "v", agent=agent, request_id=request_id)
    type_name = raw.get("type")
    cls = MESSAGE_TYPES.get(type_name) if type(type_name) is str else None
    if cls is None:
        raise ProtocolError("unknown_type", _type_problem(type_name), "type", agent=agent, request_id=request_id)
    plan = _plan(cls)
    if not plan.names.issuperset(raw):
        extra = sorted(k[:64] if type(k) is str else describe(k, 64) for k in raw if k not in plan.names)
        raise ProtocolError("extra_field", f"not a field of '{cls.TYPE}'", extra[0], agent=agent,
                            request_id=request_id)
    values: dict[str, Any] = {}  # in field order, so the instance reads like one built normally
    defaults = plan.defaults
    name = ""
    try:
        for name, required, check in plan.checks:
            if name in raw:
                values[name] = check(raw[name])
            elif required:
                raise ProtocolError("missing_field", f"required by '{cls.TYPE}' but missing", name)
            elif name in defaults:
                values[name] = defaults[name]
            else:
                values[name] = plan.factories[name]()  # containers: a new one per message
    except _Bad as bad:
        raise ProtocolError(bad.kind, bad.problem, name + bad.sub, agent=agent, request_id=request_id) from None
    except ProtocolError as exc:
        exc.agent, exc.request_id = agent, request_id
        raise
    # Every field is checked above, so the instance is built without re-running the frozen
    # dataclass's __init__ (a large share of the cost of each received message).
    msg = object.__new__(cls)
    msg.__dict__.update(values)
    if plan.cross_checked:
        try:
            _check_consistency(msg)
        except ProtocolError as exc:
            exc.agent, exc.request_id = agent, request_id
            raise
    return msg


def describe(value: Any, limit: int = 80) -> str:
    """A short, bounded description of an untrusted value for an error message: a scalar as itself
    (strings and binary cut to `limit` characters), a container by its kind and size only, so no
    nesting or size of what a peer sent can make an error message large or slow, or fail."""
    kind = type(value)
    if kind is str:
        text = value if len(value) <= limit else value[:limit] + f"... ({len(value)} characters)"
        return repr(text)
    if kind is bytes:
        head = value[:limit // 4]
        return f"binary {head.hex()}{'...' if len(value) > len(head) else ''} ({len(value)} bytes)"
    if kind is bool or value is None:
        return _type_name(value) if value is None else ("true" if value else "false")
    if kind is int or kind is float:
        text = repr(value)
        return text if len(text) <= limit else text[:limit] + "..."
    if kind is list:
        return f"an array of {len(value)} items"
    if kind is dict:
        return f"a map of {len(value)} keys"
    return f"a value of type {_type_name(value)}"


def _identity(raw: dict[Any, Any]) -> tuple[str, str]:
    """The agent and request id a map claims, when they are well-formed (for error reports only)."""
    agent = raw.get("agent")
    request_id = raw.get("request_id")
    return (agent if type(agent) is str and is_agent_id(agent) else "",
            request_id if type(request_id) is str and 0 < len(request_id) <= 64 else "")


def _unpack_problem(exc: Exception) -> str:
    """msgpack's failure as a plain sentence (its own messages name its internals)."""
    if isinstance(exc, msgpack.ExtraData):
        return "the payload holds more than one msgpack value (extra bytes after the first)"
    if isinstance(exc, msgpack.StackError):
        return "the payload is nested too deeply to unpack"
    if isinstance(exc, UnicodeDecodeError):
        return "a string in the payload is not valid UTF-8"
    text = str(exc)
    if "incomplete input" in text:
        return "the payload ends in the middle of a msgpack value"
    if "map key" in text:
        return "a map key in the payload is not a string"
    return "the payload is not valid msgpack"


def _version_problem(version: Any) -> str:
    if version is None:
        return f"the protocol version is missing (this side speaks {PROTOCOL_VERSION})"
    if type(version) is not int:
        return f"the protocol version must be the integer {PROTOCOL_VERSION}, got {_type_name(version)}"
    return f"protocol version {describe(version)} is not supported; this side speaks {PROTOCOL_VERSION}"


def _type_problem(type_name: Any) -> str:
    if type_name is None:
        return "the message type is missing"
    if type(type_name) is not str:
        return f"the message type must be a string, got {_type_name(type_name)}"
    return f"unknown message type {describe(type_name, 64)}; known: {', '.join(sorted(MESSAGE_TYPES))}"


def _check_consistency(msg: Message) -> None:
    problem = msg.consistency_problem()
    if problem is not None:
        raise ProtocolError("inconsistent", problem[1], problem[0])


@dataclasses.dataclass(frozen=True)
class _Plan:
    """What the codec needs to know about one message type, worked out once."""

    checks: tuple[tuple[str, bool, Check], ...]
    names: frozenset[str]  # fields and envelope keys allowed on the wire
    defaults: dict[str, Any]  # plain defaults of optional fields
    factories: dict[str, Any]  # container defaults, made fresh per message
    cross_checked: bool  # the type checks fields against each other


_PLANS: dict[type[Message], _Plan] = {}


def _plan(cls: type[Message]) -> _Plan:
    plan = _PLANS.get(cls)
    if plan is None:
        fields = dataclasses.fields(cls)
        checks = []
        for spec in field_specs(cls):
            check = _compile(spec, spec.kind)
            if spec.name == "agent":
                check = _agent_check(check, cls)
            checks.append((spec.name, spec.required, check))
        plan = _PLANS[cls] = _Plan(
            checks=tuple(checks),
            names=frozenset(spec.name for spec in field_specs(cls)) | frozenset(ENVELOPE_KEYS),
            defaults={f.name: f.default for f in fields if f.default is not dataclasses.MISSING},
            factories={f.name: f.default_factory for f in fields if f.default_factory is not dataclasses.MISSING},
            cross_checked=cls.consistency_problem is not Message.consistency_problem)
    return plan


def _agent_check(check_str: Check, cls: type[Message]) -> Check:
    """The agent id's grammar, and '*' exactly where the type's AGENT_SCOPE allows it."""
    scope, name = cls.AGENT_SCOPE, cls.TYPE

    def check(v: Any) -> Any:
        v = check_str(v)
        if v == ALL_AGENTS:
            if scope == "one":
                raise _Bad("out_of_range", f"agent '*' (no single agent) is not allowed in a '{name}' message: "
                                           "it names one agent")
            return v
        if scope == "all":
            raise _Bad("out_of_range", f"a '{name}' message is about the whole instance: its agent must be '*', "
                                       f"got {describe(v, 40)}")
        if not _AGENT_ID.fullmatch(v):
            raise _Bad("out_of_range", f"agent id {describe(v, 40)} must be 1-32 letters, digits, '_' or '-'")
        return v
    return check


# --- validators, compiled once per message type (the hot path of every bus message) -------------

Check = Callable[[Any], Any]


class _Bad(Exception):
    """A validation failure below the field level; `sub` is the path inside the field."""

    def __init__(self, kind: str, problem: str, sub: str = "") -> None:
        super().__init__(problem)
        self.kind, self.problem, self.sub = kind, problem, sub


def _compile(spec: FieldSpec, kind: Any) -> Check:
    origin = typing.get_origin(kind)
    if origin is types.UnionType or origin is typing.Union:
        inner = _compile(spec, next(a for a in typing.get_args(kind) if a is not type(None)))
        return lambda v: None if v is None else inner(v)
    if origin is Literal:
        return _choice(typing.get_args(kind))
    if origin is list:
        item_spec = dataclasses.replace(spec, max_len=spec.item_max_len, min_len=None)
        return _sequence(spec, _compile(item_spec, typing.get_args(kind)[0]))
    if origin is dict:
        # the field's length limit is on the map; its values are bounded by the message size cap
        return _mapping(spec, _compile(dataclasses.replace(spec, max_len=None), typing.get_args(kind)[1]))
    return _scalar(spec, kind)


def _choice(allowed: tuple[str, ...]) -> Check:
    choices = frozenset(allowed)
    listing = ", ".join(allowed)

    def check(v: Any) -> Any:
        if type(v) is not str:
            raise _Bad("wrong_type", f"expected a string (one of {listing}), got {_type_name(v)}")
        if v not in choices:
            raise _Bad("out_of_range", f"{describe(v, 40)} is not one of {listing}")
        return v
    return check


def _sequence(spec: FieldSpec, item: Check) -> Check:
    max_len = spec.max_len
    min_len = spec.min_len or 0

    def check(v: Any) -> Any:
        if type(v) is not list:
            raise _Bad("wrong_type", f"expected a list, got {_type_name(v)}")
        if max_len is not None and len(v) > max_len:
            raise _Bad("out_of_range", f"length {len(v)} is over the maximum {max_len}")
        if len(v) < min_len:
            exactly = "exactly " if min_len == max_len else "at least "
            raise _Bad("out_of_range", f"length {len(v)} is short: it must have {exactly}{min_len} entries")
        out = []
        for i, x in enumerate(v):
            try:
                out.append(item(x))
            except _Bad as bad:
                raise _Bad(bad.kind, bad.problem, f"[{i}]{bad.sub}") from None
        return out
    return check


def _mapping(spec: FieldSpec, item: Check) -> Check:
    max_len = spec.max_len

    def check(v: Any) -> Any:
        if type(v) is not dict:
            raise _Bad("wrong_type", f"expected a map, got {_type_name(v)}")
        if max_len is not None and len(v) > max_len:
            raise _Bad("out_of_range", f"length {len(v)} is over the maximum {max_len}")
        out = {}
        for key, x in v.items():
            if type(key) is not str or not 0 < len(key) <= 64:
                raise _Bad("wrong_type", f"map keys must be strings of 1-64 characters, got {describe(key, 64)}")
            try:
                out[key] = item(x)
            except _Bad as bad:
                raise _Bad(bad.kind, bad.problem, f".{key}{bad.sub}") from None
        return out
    return check


def _scalar(spec: FieldSpec, kind: Any) -> Check:
    lo, hi, max_len = spec.lo, spec.hi, spec.max_len
    # finite stand-ins for "no limit", so infinities still fail the range test and reach isfinite
    low = -sys.float_info.max if lo is None else lo
    high = sys.float_info.max if hi is None else hi

    def in_range(v: float) -> None:
        if v < low:
            raise _Bad("out_of_range", f"{v} is below the minimum {lo}")
        raise _Bad("out_of_range", f"{v} is above the maximum {hi}")

    if kind is bool:
        def check_bool(v: Any) -> Any:
            if type(v) is not bool:
                raise _Bad("wrong_type", f"expected a boolean, got {_type_name(v)}")
            return v
        return check_bool
    if kind is int:
        def check_int(v: Any) -> Any:
            if type(v) is not int:
                if isinstance(v, bool) or not isinstance(v, int):
                    raise _Bad("wrong_type", f"expected an integer, got {_type_name(v)}")
                v = int(v)
            if not low <= v <= high:
                in_range(v)
            return v
        return check_int
    if kind is float:
        def check_float(v: Any) -> Any:
            if type(v) is not float:
                if isinstance(v, bool) or not isinstance(v, int | float):
                    raise _Bad("wrong_type", f"expected a number, got {_type_name(v)}")
                v = float(v)
            if not low <= v <= high:  # NaN fails this too
                if not math.isfinite(v):
                    raise _Bad("not_finite", f"{v} is not a finite number")
                in_range(v)
            return v
        return check_float
    if kind is str:
        def check_str(v: Any) -> Any:
            if type(v) is not str:
                raise _Bad("wrong_type", f"expected a string, got {_type_name(v)}")
            if max_len is not None and len(v) > max_len:
                raise _Bad("out_of_range", f"length {len(v)} is over the maximum {max_len}")
            return v
        return check_str
    if kind is bytes:
        def check_bytes(v: Any) -> Any:
            if type(v) is not bytes:
                raise _Bad("wrong_type", f"expected binary data, got {_type_name(v)}")
            if max_len is not None and len(v) > max_len:
                raise _Bad("out_of_range", f"{len(v)} bytes is over the maximum {max_len}")
            return v
        return check_bytes
    raise TypeError(f"unsupported annotation {kind!r} in {spec.name}")  # a bug in messages.py, not input


def _type_name(value: Any) -> str:
    if value is None:
        return "nil"
    return {bool: "boolean", int: "integer", float: "float", str: "string", bytes: "binary", list: "array",
            dict: "map"}.get(type(value), type(value).__name__)
