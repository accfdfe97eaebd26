"""The rig mapping read from configs/rig.toml (its sources are named there, row by row), with errors that name
the file and the key."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from eca.agent.config import ConfigError, config_path, load_toml, require
from eca.agent.rig.lookat import EYE_LOOK_NAMES, EyeLookScale, RangeMap, VrmLookAt
from eca.agent.rig.mapping import FlexorMap, parse_flexor_map
from eca.agent.rig.names import ARKIT_NAMES, VISEME_INDEX, VISEME_NAMES, VRM_EMOTIONS, VRM_VOWELS
from eca.agent.rig.visemes import MAX_SHARPNESS, MOUTH_SHAPES, VisemeTable

DEFAULT_RIG_FILE = "rig"
# The [arkit] table has a row for every shape but the eyeLook ones, which come from the eye angles ([eye_look]).
ARKIT_ROWS: tuple[str, ...] = tuple(n for n in ARKIT_NAMES if n not in EYE_LOOK_NAMES)


@dataclass(frozen=True, eq=False)
class RigConfig:
    arkit: FlexorMap  # outputs: ARKIT_NAMES in order; the eyeLook rows are made from `eye_look`
    vrm_emotions: FlexorMap  # outputs: VRM_EMOTIONS
    eye_look: EyeLookScale
    look_at: VrmLookAt
    visemes: VisemeTable
    source: str = "<memory>"


def load_rig_config(path: str | Path | None = None) -> RigConfig:
    """Read a rig mapping (default configs/rig.toml, or $ECA_CONFIG_DIR/rig.toml where the user has one)."""
    resolved = config_path(str(path if path is not None else DEFAULT_RIG_FILE))
    return parse_rig_config(load_toml(resolved), str(resolved))


def parse_rig_config(document: Mapping[str, Any], source: str) -> RigConfig:
    arkit_table = require(document, "arkit", dict, source)
    misplaced = [n for n in EYE_LOOK_NAMES if n in arkit_table]
    if misplaced:
        raise ConfigError(f"{source}: [arkit] {misplaced[0]}: the eyeLook shapes come from the eye angles "
                          "([eye_look]), not from flexors")
    eye_look = _eye_look(document, source)
    rows = dict(arkit_table)
    rows.update(eye_look_rows(eye_look))
    arkit = parse_flexor_map(rows, ARKIT_NAMES, f"{source}: [arkit]")
    emotions = parse_flexor_map(require(document, "vrm_emotions", dict, source), VRM_EMOTIONS,
                                f"{source}: [vrm_emotions]")
    return RigConfig(arkit, emotions, eye_look, _look_at(document, source),
                     _visemes(document, source), source)


def eye_look_rows(scale: EyeLookScale) -> dict[str, dict[str, float]]:
    """The eight eyeLook rows of a scale, over the eye-angle inputs (mapping.py): a weight is the angle toward its
    direction over the degrees of a full weight. "In" is toward the nose: a look to the agent's right for the
    left eye (eye_l_yaw+), to its left for the right eye (eye_r_yaw-)."""
    rows: dict[str, dict[str, float]] = {}
    for eye, side, inward, outward in (("l", "Left", "+", "-"), ("r", "Right", "-", "+")):
        rows[f"EyeLookIn{side}"] = {f"eye_{eye}_yaw{inward}": 1.0 / scale.in_deg}
        rows[f"EyeLookOut{side}"] = {f"eye_{eye}_yaw{outward}": 1.0 / scale.out_deg}
        rows[f"EyeLookUp{side}"] = {f"eye_{eye}_pitch+": 1.0 / scale.up_deg}
        rows[f"EyeLookDown{side}"] = {f"eye_{eye}_pitch-": 1.0 / scale.down_deg}
    return rows


def _positive(table: Mapping[str, Any], key: str, where: str) -> float:
    value = require(table, key, float, where)
    if not math.isfinite(value) or value <= 0.0:
        raise ConfigError(f"{where}: '{key}' must be a finite number > 0, got {value!r}")
    return float(value)


def _eye_look(document: Mapping[str, Any], source: str) -> EyeLookScale:
    where = f"{source}: [eye_look]"
    table = require(document, "eye_look", dict, source)
    return EyeLookScale(*(_positive(table, key, where) for key in ("in_deg", "out_deg", "up_deg", "down_deg")))


def _look_at(document: Mapping[str, Any], source: str) -> VrmLookAt:
    table = require(document, "vrm_look_at", dict, source)
    maps = []
    for key in ("horizontal_inner", "horizontal_outer", "vertical_down", "vertical_up"):
        where = f"{source}: [vrm_look_at] {key}"
        entry = require(table, key, dict, f"{source}: [vrm_look_at]")
        maps.append(RangeMap(_positive(entry, "input_max_deg", where), _positive(entry, "output_scale", where)))
    return VrmLookAt(*maps)


def _visemes(document: Mapping[str, Any], source: str) -> VisemeTable:
    where = f"{source}: [visemes]"
    table = require(document, "visemes", dict, source)
    prototypes_table = require(table, "prototypes", dict, where)
    expected = VISEME_NAMES[1:]  # sil is the mouth at rest: what activity leaves over, no prototype
    for name in prototypes_table:
        if name not in expected:
            raise ConfigError(f"{where}.prototypes: unknown viseme '{name}'; visemes: {', '.join(expected)}")
    rows = []
    for name in expected:
        row_where = f"{where}.prototypes {name}"
        row = require(prototypes_table, name, dict, f"{where}.prototypes")
        for key in row:
            if key not in MOUTH_SHAPES:
                raise ConfigError(f"{row_where}: unknown mouth shape '{key}'; mouth shapes: {', '.join(MOUTH_SHAPES)}")
        values = []
        for shape in MOUTH_SHAPES:
            value = float(require(row, shape, float, row_where)) if shape in row else 0.0
            if not 0.0 <= value <= 1.0:
                raise ConfigError(f"{row_where}: '{shape}' must lie in [0, 1], got {value!r}")
            values.append(value)
        if max(values) <= 0.0:
            raise ConfigError(f"{row_where}: a prototype needs some mouth shape > 0")
        rows.append(values)

    vowel_table = require(document, "vrm_vowels", dict, source)
    vowels = []
    for vowel in VRM_VOWELS:
        viseme = require(vowel_table, vowel, str, f"{source}: [vrm_vowels]")
        if viseme not in VISEME_INDEX or viseme == "sil":
            raise ConfigError(f"{source}: [vrm_vowels] {vowel}: unknown viseme {viseme!r}; "
                              f"visemes: {', '.join(expected)}")
        vowels.append(viseme)
    extra = sorted(set(vowel_table) - set(VRM_VOWELS))
    if extra:
        raise ConfigError(f"{source}: [vrm_vowels]: unknown VRM vowel '{extra[0]}'; vowels: {', '.join(VRM_VOWELS)}")
    sharpness = _positive(table, "sharpness", where)
    if sharpness > MAX_SHARPNESS:
        raise ConfigError(f"{where}: 'sharpness' must be at most {MAX_SHARPNESS:g}, got {sharpness!r}")
    return VisemeTable(np.array(rows), sharpness, _positive(table, "rest_span", where), tuple(vowels))
