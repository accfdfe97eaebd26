"""Lip-sync constants, read from configs/lipsync.toml (their sources are named there)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from eca.agent.config import ConfigError, load_toml, require

MOUTH_FLEXORS: tuple[str, ...] = ("say_ah", "say_oo", "say_ee", "say_mm", "say_ff")
VISEMES: tuple[str, ...] = ("open", "rounded", "spread", "closed", "fricative")  # plus "rest"


@dataclass(frozen=True)
class LipSyncConfig:
    block_s: float
    window_s: float
    preemphasis: float
    lpc_order: int
    lpc_band_hz: float
    lag_window_hz: float
    max_bandwidth_hz: float
    contour_bandwidth_hz: float
    f1_range_hz: tuple[float, float]
    f2_range_hz: tuple[float, float]
    formant_gap_hz: float
    high_cut_hz: float
    low_cut_hz: float
    floor_dbfs: float
    initial_ref_dbfs: float
    ref_decay_db_per_s: float
    speech_gate_db: float
    fricative_gate_db: float
    gate_width_db: float
    jaw_range_db: float
    fricative_high_ratio: float
    fricative_width: float
    nasal_low_ratio: float
    nasal_width: float
    nasal_max_db: float
    closure_context_s: float
    closure_hold_s: float
    closure_dip_db: float
    open_f1_hz: float
    open_width_hz: float
    rounded_f2_hz: float
    spread_f2_hz: float
    f2_width_hz: float
    formant_tau_s: float
    rest_threshold: float
    jaw_attack_s: float
    jaw_release_s: float
    shape_attack_s: float
    shape_release_s: float
    # viseme -> (jaw share of say_ah, weights of the other mouth flexors), in VISEMES order
    viseme_table: tuple[tuple[float, ...], ...]

    @classmethod
    def load(cls, name: str = "lipsync") -> LipSyncConfig:
        return cls.from_dict(load_toml(name), where=f"configs/{name}.toml")

    @classmethod
    def from_dict(cls, data: dict[str, Any], where: str = "lipsync config") -> LipSyncConfig:
        values: dict[str, Any] = {}
        for section in ("analysis", "level", "classes", "smoothing"):
            table = require(data, section, dict, where)
            for key, value in table.items():
                values[key] = value
        kwargs: dict[str, Any] = {}
        for field_name, field_type in cls.__annotations__.items():
            if field_name == "viseme_table":
                continue
            ctx = f"{where} [{_section_of(data, field_name)}]"
            if field_name.endswith("_range_hz"):
                pair = require(values, field_name, list, ctx)
                if len(pair) != 2 or not all(isinstance(v, int | float) for v in pair) or pair[0] >= pair[1]:
                    raise ConfigError(f"{ctx}: '{field_name}' must be [low, high] with low < high")
                kwargs[field_name] = (float(pair[0]), float(pair[1]))
            elif field_type == "int":
                kwargs[field_name] = require(values, field_name, int, ctx)
            else:
                value = require(values, field_name, float, ctx)
                if field_name.endswith("_s") and value <= 0.0:
                    raise ConfigError(f"{ctx}: '{field_name}' must be > 0, got {value}")
                kwargs[field_name] = value
        visemes = require(data, "visemes", dict, where)
        rows = []
        for viseme in VISEMES:
            row = require(visemes, viseme, dict, f"{where} [visemes]")
            unknown = set(row) - set(MOUTH_FLEXORS)
            if unknown:
                raise ConfigError(f"{where} [visemes.{viseme}]: unknown flexor(s) {sorted(unknown)}")
            weights = []
            for flexor in MOUTH_FLEXORS:
                w = float(row.get(flexor, 0.0))
                if not 0.0 <= w <= 1.0:
                    raise ConfigError(f"{where} [visemes.{viseme}]: '{flexor}' must be in [0, 1], got {w}")
                weights.append(w)
            rows.append(tuple(weights))
        return cls(**kwargs, viseme_table=tuple(rows))


def _section_of(data: dict[str, Any], key: str) -> str:
    for section in ("analysis", "level", "classes", "smoothing"):
        if key in data.get(section, {}):
            return section
    return "analysis|level|classes|smoothing"
