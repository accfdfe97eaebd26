"""Loading eca's TOML configs (shipped in the package's configs/, each replaceable by a file of the same name
in $ECA_CONFIG_DIR), with errors that name the file and the key."""

from __future__ import annotations

import os
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from eca import shipped_configs

SHIPPED_DIR = shipped_configs()


class ConfigError(ValueError):
    """A config file is missing, unreadable, or holds a wrong value; the message says where."""


def user_config_dir() -> Path | None:
    """A folder of the user's own config files ($ECA_CONFIG_DIR): each file in it replaces the shipped one
    of the same name; the files it does not hold come from the package."""
    folder = os.environ.get("ECA_CONFIG_DIR")
    return Path(folder) if folder else None


def config_path(name: str) -> Path:
    """Where the config `name` is read from. A bare name ("emotions") is one of eca's configs: the user's
    own (ECA_CONFIG_DIR) when it has one, else the shipped one. A file name with a folder in it, or a `.toml`
    file that exists, is a path (relative to the working directory)."""
    path = Path(name)
    if path.suffix == ".toml" and (path.is_absolute() or len(path.parts) > 1 or path.exists()):
        return path
    if path.suffix != ".toml":
        path = path.with_suffix(".toml")
    user = user_config_dir()
    if user is not None and (user / path).is_file():
        return user / path
    return SHIPPED_DIR / path


def load_toml(name: str | Path) -> dict[str, Any]:
    path = config_path(str(name))
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{path}: config file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def require(table: Mapping[str, Any], key: str, kind: type | tuple[type, ...], where: str) -> Any:
    """Fetch `key` from `table`, checking its type; `where` names the file and table for the message."""
    if key not in table:
        raise ConfigError(f"{where}: missing key '{key}'")
    value = table[key]
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if not isinstance(value, kind) or (isinstance(value, bool) and kind in (int, float)):
        raise ConfigError(f"{where}: '{key}' must be {_kind_name(kind)}, got {value!r}")
    return value


def _kind_name(kind: type | tuple[type, ...]) -> str:
    if isinstance(kind, tuple):
        return " or ".join(k.__name__ for k in kind)
    return kind.__name__
