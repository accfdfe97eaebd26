"""Emotions as data: a table of flexor poses read from configs/emotions.toml, scaled by intensity.

An emotion names only the flexors it sets; the others are "do not care" (NaN) and fall to the layers
below. Intensity blends from the natural face (0) to the full pose (1). A table entry may instead refer
to another emotion at a fixed intensity (`like = "angry"`, `intensity = 0.5` for the paper's half-angry).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from eca.agent.config import ConfigError, config_path, load_toml
from eca.agent.face.actions import Pose
from eca.agent.face.flexors import FLEXOR_INDEX, FLEXOR_NAMES, N_FLEXORS
from eca.agent.face.frame import DONT_CARE, FLEXOR_MAX, FLEXOR_MIN

DEFAULT_EMOTIONS_FILE = "emotions"
NATURAL = "natural"
# The paper's nine (section 4 and its experiment); a table must define all of them, and may add more.
PAPER_EMOTIONS: tuple[str, ...] = (
    "natural",
    "happy",
    "surprised",
    "arrogant",
    "angry",
    "half-angry",
    "disappointed",
    "annoyed",
    "frightened",
)
_REFERENCE_KEYS = frozenset({"like", "intensity"})


def check_intensity(intensity: float, what: str = "intensity") -> float:
    if isinstance(intensity, bool) or not isinstance(intensity, int | float | np.floating | np.integer):
        raise ValueError(f"{what} must be a number in [0, 1], got {intensity!r}")
    value = float(intensity)
    if not 0.0 <= value <= 1.0:  # also rejects NaN
        raise ValueError(f"{what} must lie in [0, 1], got {intensity!r}")
    return value


def canonical_emotion_name(name: str) -> str:
    """Names are case-insensitive and '_' is accepted for '-' (half_angry is half-angry)."""
    return name.strip().lower().replace("_", "-")


@dataclass(frozen=True)
class EmotionTable:
    """Full poses per emotion (NaN = do not care) and the natural face they blend from."""

    full_poses: Mapping[str, np.ndarray]
    source: str = "<memory>"

    def __post_init__(self) -> None:
        if NATURAL not in self.full_poses:
            raise ValueError(f"{self.source}: an emotion table needs a '{NATURAL}' entry")
        for pose in self.full_poses.values():
            pose.flags.writeable = False

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.full_poses)

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and canonical_emotion_name(name) in self.full_poses

    def pose(self, name: str, intensity: float = 1.0) -> np.ndarray:
        """The flexor vector of `name` at `intensity` in [0, 1]; NaN where the emotion does not care.

        A flexor the emotion sets goes from its natural value (0 if natural leaves it alone) at
        intensity 0 to the full pose at intensity 1, linearly.
        """
        full = self._full_pose(name)
        amount = check_intensity(intensity)
        natural = np.nan_to_num(self.full_poses[NATURAL], nan=0.0)
        return natural + amount * (full - natural)

    def action(self, name: str, intensity: float = 1.0) -> Pose:
        """The emotion as an action: a constant pose, ready for a compositor layer."""
        return Pose(self.pose(name, intensity))

    def _full_pose(self, name: str) -> np.ndarray:
        if not isinstance(name, str) or canonical_emotion_name(name) not in self.full_poses:
            raise ValueError(f"unknown emotion {name!r}; known emotions: {', '.join(self.names)}")
        return self.full_poses[canonical_emotion_name(name)]


def load_emotion_table(path: str | Path | None = None) -> EmotionTable:
    """Read an emotion table (default configs/emotions.toml); errors name the file, emotion and key."""
    resolved = config_path(str(path if path is not None else DEFAULT_EMOTIONS_FILE))
    return parse_emotion_table(load_toml(resolved), str(resolved))


def parse_emotion_table(document: Mapping[str, Any], source: str) -> EmotionTable:
    entries: dict[str, Mapping[str, Any]] = {}
    for raw_name, entry in document.items():
        name = canonical_emotion_name(raw_name)
        if not isinstance(entry, Mapping):
            raise ConfigError(f"{source}: [{raw_name}] must be a table of flexor values, got {entry!r}")
        if name in entries:
            raise ConfigError(f"{source}: emotion [{raw_name}] is defined twice")
        entries[name] = entry
    missing = [name for name in PAPER_EMOTIONS if name not in entries]
    if missing:
        raise ConfigError(f"{source}: missing emotion(s) {', '.join(missing)}")

    direct = {
        name: _parse_pose(name, entry, source) for name, entry in entries.items() if not _REFERENCE_KEYS & entry.keys()
    }
    poses: dict[str, np.ndarray] = {}
    natural = np.nan_to_num(direct[NATURAL], nan=0.0) if NATURAL in direct else None
    if natural is None:
        raise ConfigError(f"{source}: [{NATURAL}] must list flexor values, not refer to another emotion")
    for name in entries:
        poses[name] = _resolve(name, entries, direct, natural, source, chain=())
    return EmotionTable(poses, source)


def _parse_pose(name: str, entry: Mapping[str, Any], source: str) -> np.ndarray:
    pose = np.full(N_FLEXORS, DONT_CARE)
    for flexor, value in entry.items():
        where = f"{source}: [{name}] {flexor}"
        if flexor not in FLEXOR_INDEX:
            raise ConfigError(f"{where}: unknown flexor; known flexors: {', '.join(FLEXOR_NAMES)}")
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where}: must be a number in [-1, 1], got {value!r}")
        if math.isnan(value) or not FLEXOR_MIN <= value <= FLEXOR_MAX:
            raise ConfigError(f"{where}: {value} lies outside [{FLEXOR_MIN}, {FLEXOR_MAX}]")
        pose[FLEXOR_INDEX[flexor]] = float(value)
    return pose


def _resolve(
    name: str,
    entries: Mapping[str, Mapping[str, Any]],
    direct: Mapping[str, np.ndarray],
    natural: np.ndarray,
    source: str,
    chain: tuple[str, ...],
) -> np.ndarray:
    if name in direct:
        return direct[name]
    entry = entries[name]
    where = f"{source}: [{name}]"
    if name in chain:
        raise ConfigError(f"{where}: circular reference {' -> '.join((*chain, name))}")
    extra = sorted(set(entry) - _REFERENCE_KEYS)
    if extra:
        raise ConfigError(f"{where}: a reference ('like') cannot also set flexors ({', '.join(extra)})")
    target = entry.get("like")
    if not isinstance(target, str):
        raise ConfigError(f"{where} like: must name another emotion, got {target!r}")
    target_name = canonical_emotion_name(target)
    if target_name not in entries:
        raise ConfigError(f"{where} like: unknown emotion {target!r}; known emotions: {', '.join(entries)}")
    intensity = entry.get("intensity", 1.0)
    try:
        amount = check_intensity(intensity)
    except ValueError as exc:
        raise ConfigError(f"{where} intensity: {exc}") from None
    full = _resolve(target_name, entries, direct, natural, source, (*chain, name))
    return natural + amount * (full - natural)
