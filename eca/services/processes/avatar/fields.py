"""Typed reads of glTF JSON values, each naming where it is (`meshes[0].primitives[2].indices`) when it is wrong.

The document is plain JSON (dicts, lists, str, int, float, bool, None) already checked for depth and non-finite
numbers (container.py). These helpers take one member of one object, check its JSON type and range, and return
it as the Python type the loader uses, or raise AvatarError saying what was expected and what was there. JSON
integers written as floats (`3.0`) are taken as integers; `3.5` is not an index.
"""

from __future__ import annotations

import math
from typing import Any

from eca.services.processes.avatar.errors import AvatarError, kind

JSON = Any  # a value json.loads returned
MAX_SAFE_INT = 2**53  # what a JSON number holds exactly


def join(where: str, key: str) -> str:
    """The path of member `key` of the object at `where` ("" is the document itself)."""
    return f"{where}.{key}" if where else key


def as_int(value: JSON, where: str, lo: int = 0, hi: int = MAX_SAFE_INT) -> int:
    """`value` as an integer in lo..hi."""
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise AvatarError(f"{where} must be an integer, got {kind(value)}")
    if not lo <= value <= hi:
        raise AvatarError(f"{where} is {value}, outside {lo}..{hi}")
    return value


def as_number(value: JSON, where: str) -> float:
    """`value` as a finite float."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise AvatarError(f"{where} must be a number, got {kind(value)}")
    number = float(value)
    if not math.isfinite(number):
        raise AvatarError(f"{where} must be finite, got {value!r}")
    return number


def as_object(value: JSON, where: str) -> dict[str, JSON]:
    if not isinstance(value, dict):
        raise AvatarError(f"{where} must be an object, got {kind(value)}")
    return value


def as_list(value: JSON, where: str, limit: int, what: str = "entries", limit_name: str = "") -> list[JSON]:
    """`value` as a list of at most `limit` items (the count is checked before anything walks it); `limit_name`
    is the AvatarLimits field the limit comes from, for the message."""
    if not isinstance(value, list):
        raise AvatarError(f"{where} must be a list, got {kind(value)}")
    if len(value) > limit:
        named = f" ({limit_name})" if limit_name else ""
        raise AvatarError(f"{where} has {len(value)} {what}, more than the limit of {limit}{named}")
    return value


def get_object(obj: dict[str, JSON], key: str, where: str) -> dict[str, JSON]:
    """Member `key` as an object ({} when absent)."""
    value = obj.get(key)
    return {} if value is None else as_object(value, join(where, key))


def get_list(obj: dict[str, JSON], key: str, where: str, limit: int, what: str = "entries",
             limit_name: str = "") -> list[JSON]:
    """Member `key` as a list of at most `limit` items ([] when absent)."""
    value = obj.get(key)
    return [] if value is None else as_list(value, join(where, key), limit, what, limit_name)


def get_objects(obj: dict[str, JSON], key: str, where: str, limit: int, limit_name: str = "") -> list[dict[str, JSON]]:
    """Member `key` as a list of at most `limit` objects ([] when absent)."""
    items = get_list(obj, key, where, limit, key, limit_name)
    return [as_object(item, f"{join(where, key)}[{i}]") for i, item in enumerate(items)]


def get_int(obj: dict[str, JSON], key: str, where: str, default: int | None = None, lo: int = 0,
            hi: int = MAX_SAFE_INT) -> int | None:
    value = obj.get(key)
    return default if value is None else as_int(value, join(where, key), lo, hi)


def need_int(obj: dict[str, JSON], key: str, where: str, lo: int = 0, hi: int = MAX_SAFE_INT) -> int:
    value = obj.get(key)
    if value is None:
        raise AvatarError(f"{join(where, key)} is missing")
    return as_int(value, join(where, key), lo, hi)


def get_index(obj: dict[str, JSON], key: str, where: str, count: int, what: str) -> int | None:
    """Member `key` as an index into the document's `what` list of `count` items (None when absent)."""
    value = obj.get(key)
    if value is None:
        return None
    return as_index(value, join(where, key), count, what)


def as_index(value: JSON, where: str, count: int, what: str) -> int:
    index = as_int(value, where, 0, MAX_SAFE_INT)
    if index >= count:
        raise AvatarError(f"{where} is {index}, but there are only {count} {what}")
    return index


def get_number(obj: dict[str, JSON], key: str, where: str, default: float) -> float:
    value = obj.get(key)
    return default if value is None else as_number(value, join(where, key))


def get_numbers(obj: dict[str, JSON], key: str, where: str, n: int) -> tuple[float, ...] | None:
    """Member `key` as exactly `n` finite numbers (None when absent)."""
    value = obj.get(key)
    if value is None:
        return None
    items = as_list(value, join(where, key), n, "numbers")
    if len(items) != n:
        raise AvatarError(f"{join(where, key)} must hold {n} numbers, got {len(items)}")
    return tuple(as_number(v, f"{join(where, key)}[{i}]") for i, v in enumerate(items))


def get_str(obj: dict[str, JSON], key: str, where: str, default: str = "") -> str:
    value = obj.get(key)
    if value is None:
        return default
    if not isinstance(value, str):
        raise AvatarError(f"{join(where, key)} must be a string, got {kind(value)}")
    return value


def get_bool(obj: dict[str, JSON], key: str, where: str, default: bool = False) -> bool:
    value = obj.get(key)
    if value is None:
        return default
    if not isinstance(value, bool):
        raise AvatarError(f"{join(where, key)} must be true or false, got {kind(value)}")
    return value
