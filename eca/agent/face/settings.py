"""The face model's constants from configs/face.toml (settle times, idle noise) and the flexor units
from configs/flexor_units.toml, checked with errors that name the file and key."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from eca.agent.config import ConfigError, config_path, load_toml, require
from eca.agent.face.flexors import FLEXOR_INDEX, FLEXOR_NAMES, N_FLEXORS

DEFAULT_FACE_FILE = "face"
DEFAULT_UNITS_FILE = "flexor_units"


@dataclass(frozen=True)
class FaceSettings:
    settle_s: np.ndarray  # (N_FLEXORS,) seconds to 95% of the way
    idle_amplitude: np.ndarray  # (N_FLEXORS,) flexor units, 0 = no idle noise on that flexor
    idle_rate_hz: float


@dataclass(frozen=True)
class FlexorUnits:
    """Degrees per flexor unit for the eyes and the head."""

    look_x_deg: float
    look_y_deg: float
    turn_deg: float
    nod_deg: float
    tilt_deg: float


def _table(document: Mapping[str, Any], key: str, where: str) -> Mapping[str, Any]:
    table = document.get(key)
    if table is None:
        raise ConfigError(f"{where}: missing table [{key}]")
    if not isinstance(table, Mapping):
        raise ConfigError(f"{where}: [{key}] must be a table, got {table!r}")
    return table


def _positive_or_zero(table: Mapping[str, Any], key: str, where: str) -> float:
    value = require(table, key, float, where)
    if not math.isfinite(value) or value < 0:
        raise ConfigError(f"{where}: '{key}' must be a finite number >= 0, got {value!r}")
    return value


def _flexor_key_check(table: Mapping[str, Any], where: str, also_allowed: frozenset[str] = frozenset()) -> None:
    for key in table:
        if key not in FLEXOR_INDEX and key not in also_allowed:
            raise ConfigError(f"{where}: unknown flexor '{key}'; known flexors: {', '.join(FLEXOR_NAMES)}")


def load_face_settings(path: str | Path | None = None) -> FaceSettings:
    resolved = config_path(str(path if path is not None else DEFAULT_FACE_FILE))
    return parse_face_settings(load_toml(resolved), str(resolved))


def parse_face_settings(document: Mapping[str, Any], source: str) -> FaceSettings:
    settle_table = _table(document, "settle_s", source)
    where = f"{source}: [settle_s]"
    _flexor_key_check(settle_table, where)
    settle = np.array([_positive_or_zero(settle_table, name, where) for name in FLEXOR_NAMES])

    idle_table = _table(document, "idle_noise", source)
    where = f"{source}: [idle_noise]"
    _flexor_key_check(idle_table, where, frozenset({"rate_hz"}))
    rate = _positive_or_zero(idle_table, "rate_hz", where)
    amplitude = np.zeros(N_FLEXORS)
    for name in FLEXOR_NAMES:
        if name in idle_table:
            value = _positive_or_zero(idle_table, name, where)
            if value > 1.0:
                raise ConfigError(f"{where}: '{name}' = {value} exceeds the flexor range (at most 1)")
            amplitude[FLEXOR_INDEX[name]] = value
    settle.flags.writeable = False
    amplitude.flags.writeable = False
    return FaceSettings(settle, amplitude, rate)


def load_flexor_units(path: str | Path | None = None) -> FlexorUnits:
    resolved = config_path(str(path if path is not None else DEFAULT_UNITS_FILE))
    document = load_toml(resolved)
    source = str(resolved)
    eyes = _table(document, "eyes", source)
    head = _table(document, "head", source)
    values: dict[str, float] = {}
    for table, section, keys in (
        (eyes, "eyes", ("look_x_deg", "look_y_deg")),
        (head, "head", ("turn_deg", "nod_deg", "tilt_deg")),
    ):
        for key in keys:
            value = require(table, key, float, f"{source}: [{section}]")
            if not math.isfinite(value) or not 0 < value <= 90:
                raise ConfigError(f"{source}: [{section}] '{key}' must be a number of degrees in (0, 90], "
                                  f"got {value!r}")
            values[key] = value
    return FlexorUnits(**values)
