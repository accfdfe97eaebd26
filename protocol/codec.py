"""The versioned msgpack codec. Decoding validates strictly; every problem is one `ProtocolError`.

On the wire a message is a msgpack map: the envelope keys `v`, `type`, `agent`, `seq`, `t_ns`,
`source` and the body fields of its type, nothing else. Nothing from the bus is ever unpickled or
evaluated: msgpack gives plain data, and only the known dataclasses are built from it.
"""

from __future__ import annotations

import dataclasses
import math
import re
import types
import typing
from functools import cache
from typing import Any, Literal

import msgpack

from protocol.messages import ALL_AGENTS, MESSAGE_TYPES, PROTOCOL_VERSION, Message

DEFAULT_MAX_BYTES = 4 * 1024 * 1024
ENVELOPE_KEYS = ("v", "type")
_AGENT_ID = re.compile(r"^[A-Za-z0-9_-]{1,32}$")


class ProtocolError(ValueError):
    """A message that is not valid eca protocol; `field` and `kind` say where and what."""

    def __init__(self, kind: str, problem: str, field: str = "") -> None:
        self.kind = kind
        self.field = field
        self.problem = problem
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


@cache
def field_specs(cls: type[Message]) -> tuple[FieldSpec, ...]:
    hints = typing.get_type_hints(cls)
    specs = []
    for f in dataclasses.fields(cls):
        required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        specs.append(FieldSpec(f.name, hints[f.name], required, f.metadata.get("lo"), f.metadata.get("hi"),
                               f.metadata.get("max_len")))
    return tuple(specs)


def encode(msg: Message, max_bytes: int = DEFAULT_MAX_BYTES) -> bytes:
    """Validate and pack a message; what we send passes the same checks as what we receive."""
    body = {"v": PROTOCOL_VERSION, "type": msg.TYPE}
    for spec in field_specs(type(msg)):
        body[spec.name] = _check(spec, getattr(msg, spec.name), spec.kind, spec.name)
    _check_agent(body["agent"])
    data = msgpack.packb(body, use_bin_type=True)
    if len(data) > max_bytes:
        raise ProtocolError("oversize", f"message is {len(data)} bytes, over the cap of {max_bytes}")
    return data


def decode(data: bytes, max_bytes: int = DEFAULT_MAX_BYTES) -> Message:
    if not isinstance(data, bytes | bytearray | memoryview):
        raise ProtocolError("not_msgpack", f"expected bytes, got {type(data).__name__}")
    if len(data) > max_bytes:
        raise ProtocolError("oversize", f"message is {len(data)} bytes, over the cap of {max_bytes}")
    try:
        raw = msgpack.unpackb(bytes(data), raw=False, strict_map_key=True, use_list=True, timestamp=0)
    except Exception as exc:  # msgpack raises many types (ExtraData, FormatError, StackError, ...)
        problem = f"bytes are not one msgpack value ({type(exc).__name__}: {exc})"
        raise ProtocolError("not_msgpack", problem) from None
    if not isinstance(raw, dict):
        raise ProtocolError("wrong_type", f"message must be a map, got {_type_name(raw)}")
    version = raw.get("v")
    if version != PROTOCOL_VERSION:
        raise ProtocolError("unknown_version", f"unsupported protocol version {version!r}, "
                            f"this side speaks {PROTOCOL_VERSION}", "v")
    type_name = raw.get("type")
    cls = MESSAGE_TYPES.get(type_name) if isinstance(type_name, str) else None
    if cls is None:
        raise ProtocolError("unknown_type", f"unknown message type {type_name!r}; known: "
                            f"{', '.join(sorted(MESSAGE_TYPES))}", "type")
    specs = field_specs(cls)
    known = {spec.name for spec in specs}
    extra = sorted(str(k) for k in raw if k not in known and k not in ENVELOPE_KEYS)
    if extra:
        raise ProtocolError("extra_field", f"not a field of '{cls.TYPE}'", extra[0])
    values: dict[str, Any] = {}
    for spec in specs:
        if spec.name not in raw:
            if spec.required:
                raise ProtocolError("missing_field", f"required by '{cls.TYPE}' but missing", spec.name)
            continue
        values[spec.name] = _check(spec, raw[spec.name], spec.kind, spec.name)
    _check_agent(values["agent"])
    return cls(**values)


def _check_agent(agent: str) -> None:
    if agent != ALL_AGENTS and not _AGENT_ID.match(agent):
        raise ProtocolError("out_of_range", f"agent id {agent!r} must be 1-32 letters, digits, '_' or '-'",
                            "agent")


def _check(spec: FieldSpec, value: Any, kind: Any, path: str) -> Any:
    """Check `value` against the annotation `kind` and the field's limits; return it normalised."""
    origin = typing.get_origin(kind)
    if origin is types.UnionType or origin is typing.Union:
        if value is None and type(None) in typing.get_args(kind):
            return None
        inner = [a for a in typing.get_args(kind) if a is not type(None)]
        return _check(spec, value, inner[0], path)
    if origin is Literal:
        allowed = typing.get_args(kind)
        if value not in allowed or not isinstance(value, str):
            raise ProtocolError("out_of_range", f"{value!r} is not one of {', '.join(allowed)}", path)
        return value
    if origin is list:
        if not isinstance(value, list):
            raise ProtocolError("wrong_type", f"expected a list, got {_type_name(value)}", path)
        _check_len(spec, value, path)
        (item,) = typing.get_args(kind)
        return [_check_scalar(spec, v, item, f"{path}[{i}]") for i, v in enumerate(value)]
    if origin is dict:
        if not isinstance(value, dict):
            raise ProtocolError("wrong_type", f"expected a map, got {_type_name(value)}", path)
        _check_len(spec, value, path)
        _, item = typing.get_args(kind)
        out = {}
        for key, v in value.items():
            if not isinstance(key, str) or not 0 < len(key) <= 64:
                raise ProtocolError("wrong_type", f"map keys must be strings of 1-64 characters, got {key!r}",
                                    path)
            inner_path = f"{path}.{key}"
            if typing.get_origin(item) is list:
                if not isinstance(v, list):
                    raise ProtocolError("wrong_type", f"expected a list, got {_type_name(v)}", inner_path)
                (leaf,) = typing.get_args(item)
                out[key] = [_check_scalar(spec, x, leaf, f"{inner_path}[{i}]") for i, x in enumerate(v)]
            else:
                out[key] = _check_scalar(spec, v, item, inner_path)
        return out
    return _check_scalar(spec, value, kind, path)


def _check_scalar(spec: FieldSpec, value: Any, kind: Any, path: str) -> Any:
    if kind is bool:
        if not isinstance(value, bool):
            raise ProtocolError("wrong_type", f"expected a boolean, got {_type_name(value)}", path)
        return value
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ProtocolError("wrong_type", f"expected an integer, got {_type_name(value)}", path)
        _check_range(spec, value, path)
        return value
    if kind is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ProtocolError("wrong_type", f"expected a number, got {_type_name(value)}", path)
        value = float(value)
        if not math.isfinite(value):
            raise ProtocolError("not_finite", f"{value} is not a finite number", path)
        _check_range(spec, value, path)
        return value
    if kind is str:
        if not isinstance(value, str):
            raise ProtocolError("wrong_type", f"expected a string, got {_type_name(value)}", path)
        _check_len(spec, value, path)
        return value
    if kind is bytes:
        if not isinstance(value, bytes):
            raise ProtocolError("wrong_type", f"expected binary data, got {_type_name(value)}", path)
        return value
    raise TypeError(f"unsupported annotation {kind!r} at {path}")  # a bug in messages.py, not input


def _check_range(spec: FieldSpec, value: float, path: str) -> None:
    if spec.lo is not None and value < spec.lo:
        raise ProtocolError("out_of_range", f"{value} is below the minimum {spec.lo}", path)
    if spec.hi is not None and value > spec.hi:
        raise ProtocolError("out_of_range", f"{value} is above the maximum {spec.hi}", path)


def _check_len(spec: FieldSpec, value: str | list | dict, path: str) -> None:
    if spec.max_len is not None and len(value) > spec.max_len:
        raise ProtocolError("out_of_range", f"length {len(value)} is over the maximum {spec.max_len}", path)


def _type_name(value: Any) -> str:
    if value is None:
        return "nil"
    return {bool: "boolean", int: "integer", float: "float", str: "string", bytes: "binary", list: "array",
            dict: "map"}.get(type(value), type(value).__name__)
