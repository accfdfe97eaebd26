"""The gaze model's constants, read from configs/gaze.toml and configs/gaze_emotions.toml and checked.

Every number here has its source named beside it in the TOML files; this module only validates them and
turns frames into seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np

from eca.agent.config import ConfigError, load_toml, require
from eca.agent.gaze.intervals import GaussianInterval, IntervalDistribution, PolynomialInterval
from eca.agent.vocabulary import EYE_MODES, SACCADE_KINDS
from eca.agent.vocabulary import ROLES as VOCABULARY_ROLES

ROLES: tuple[str, ...] = VOCABULARY_ROLES
MEASURED_ROLES: tuple[str, ...] = ("talking", "listening")
MODES: tuple[str, ...] = EYE_MODES
KINDS: tuple[str, ...] = SACCADE_KINDS
DEFAULT_ROLE = "silence"  # the role agents start in
# The eye modes as codes, in order: the saccades run from SACCADE on, the statistical blink model from
# SACCADE_BLINK on, the fixational movements in FIXATIONAL.
STATIC, NOISE, SACCADE, SACCADE_BLINK, FIXATIONAL = (
    MODES.index(m) for m in ("static", "noise", "saccade", "saccade+blink", "saccade+noise+blink")
)
# What the eyes scan on a partner's face in mutual gaze (the gaze target is between the eyes).
FACE_FEATURES: tuple[str, ...] = ("right eye", "left eye", "mouth")


@dataclass(frozen=True)
class RoleParams:
    """The Eyes Alive statistics of one conversational role."""

    max_magnitude_deg: float
    mutual_probability: float
    mutual_interval: IntervalDistribution
    away_interval: IntervalDistribution
    blink_rate_per_min: float


@dataclass(frozen=True)
class Emotion:
    """How one emotion, at intensity 1, modulates the saccade statistics (natural is the identity)."""

    interval_scale: float = 1.0
    magnitude_scale: float = 1.0
    mutual_shift: float = 0.0
    bias_direction_deg: float = 0.0
    bias_strength: float = 0.0

    def at_intensity(self, intensity: float) -> Emotion:
        """Interpolate linearly from the identity (intensity 0) to this emotion (intensity 1)."""
        k = float(intensity)
        return Emotion(
            interval_scale=1.0 + k * (self.interval_scale - 1.0),
            magnitude_scale=1.0 + k * (self.magnitude_scale - 1.0),
            mutual_shift=k * self.mutual_shift,
            bias_direction_deg=self.bias_direction_deg,
            bias_strength=k * self.bias_strength,
        )


@dataclass(frozen=True)
class BlinkParams:
    refractory_s: float
    pull_window_s: float
    evoked_min_deg: float
    evoked_full_deg: float
    evoked_max_probability: float
    head_turn_probability: float
    turn_probability: float
    lid_curve_s: np.ndarray
    lid_curve_closure: np.ndarray

    @property
    def duration_s(self) -> float:
        return float(self.lid_curve_s[-1])


@dataclass(frozen=True)
class FixationParams:
    """The fixational eye movements and face scanning of mode saccade+noise+blink (configs/gaze.toml)."""

    microsaccade_rate_hz: float
    microsaccade_median_deg: float
    microsaccade_log_sd: float
    microsaccade_max_deg: float
    refractory_s: float
    drift_diffusion_deg2_per_s: float
    correction_spread_deg: float
    scan_rate_hz: dict[str, float]
    mouth_share: dict[str, float]
    preferred_eye_share: float
    features_deg: np.ndarray  # (3, 2): yaw, pitch of FACE_FEATURES from the gaze target

    def event_rate_hz(self, role: str, mutual: bool) -> float:
        """Small saccades per second in a fixation: microsaccades, plus scans on a partner's face."""
        return self.microsaccade_rate_hz + (self.scan_rate_hz[role] if mutual else 0.0)

    def feature_weights(self, role: str, preferred_eye: int) -> np.ndarray:
        """The chance of each face feature as a scan's target, before excluding the one fixated."""
        mouth = self.mouth_share[role]
        eyes = np.full(2, (1.0 - mouth) * (1.0 - self.preferred_eye_share))
        eyes[preferred_eye] = (1.0 - mouth) * self.preferred_eye_share
        return np.array([eyes[0], eyes[1], mouth])


@dataclass(frozen=True)
class GazeParams:
    """Everything the gaze engine needs; build it with `GazeParams.load()`."""

    frame_rate_hz: float
    p_max: float
    p_ref: float
    a_scale_deg: float
    d0_s: float
    d_s_per_deg: float
    velocity_centre: float
    velocity_span: float
    direction_bins_deg: np.ndarray
    direction_probability: np.ndarray
    roles: dict[str, RoleParams]
    silence_like: str
    head_turn_threshold_deg: float
    noise_yaw_amplitude_deg: float
    noise_pitch_amplitude_deg: float
    noise_frequency_hz: float
    blink: BlinkParams
    fixation: FixationParams
    emotions: dict[str, Emotion]
    eye_yaw_limit_deg: float
    eye_pitch_limit_deg: float
    default_mode: str

    @classmethod
    def load(
        cls, gaze: str = "gaze", emotions: str = "gaze_emotions", flexor_units: str = "flexor_units"
    ) -> GazeParams:
        return _parse(load_toml(gaze), load_toml(emotions), load_toml(flexor_units), gaze, emotions)

    def role(self, name: str) -> RoleParams:
        check_name(name, ROLES, "role")
        return self.roles[name]

    def emotion(self, name: str, intensity: float = 1.0) -> Emotion:
        check_name(name, tuple(self.emotions), "emotion")
        if not (math.isfinite(intensity) and 0.0 <= intensity <= 1.0):
            raise ValueError(f"emotion intensity must be in [0, 1], got {intensity!r}")
        return self.emotions[name].at_intensity(intensity)


@cache
def default_eye_mode() -> str:
    """The eye mode agents start in (configs/gaze.toml [modes] default)."""
    return GazeParams.load().default_mode


def check_name(name: str, valid: tuple[str, ...], what: str) -> None:
    if name not in valid:
        raise ValueError(f"unknown {what} {name!r}; valid: {', '.join(valid)}")


def _table(doc: dict[str, Any], key: str, where: str) -> dict[str, Any]:
    return require(doc, key, dict, where)


def _positive(table: dict[str, Any], key: str, where: str, allow_zero: bool = False) -> float:
    value = require(table, key, float, where)
    if not math.isfinite(value) or value < 0.0 or (value == 0.0 and not allow_zero):
        raise ConfigError(f"{where}: '{key}' must be {'>= 0' if allow_zero else '> 0'}, got {value!r}")
    return value


def _probability(table: dict[str, Any], key: str, where: str) -> float:
    value = require(table, key, float, where)
    if not 0.0 <= value <= 1.0:
        raise ConfigError(f"{where}: '{key}' must be in [0, 1], got {value!r}")
    return value


def _floats(table: dict[str, Any], key: str, where: str, length: int | None = None) -> np.ndarray:
    values = require(table, key, list, where)
    if length is not None and len(values) != length:
        raise ConfigError(f"{where}: '{key}' must hold {length} numbers, got {len(values)}")
    if not values or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
        raise ConfigError(f"{where}: '{key}' must be a list of numbers, got {values!r}")
    return np.asarray(values, dtype=np.float64)


def _interval(table: dict[str, Any], gaze_kind: str, frame_rate_hz: float, where: str) -> IntervalDistribution:
    form = require(table, "interval", str, where)
    if form == "polynomial":
        coeffs = _floats(table, f"{gaze_kind}_poly", where)
        lo, hi = _floats(table, f"{gaze_kind}_range_frames", where, length=2)
        try:
            return PolynomialInterval(tuple(coeffs), lo, hi, frame_rate_hz)
        except ValueError as exc:
            raise ConfigError(f"{where}: {gaze_kind} interval: {exc}") from None
    if form == "gaussian":
        mean = _positive(table, f"{gaze_kind}_mean_frames", where)
        sd = _positive(table, f"{gaze_kind}_sd_frames", where)
        return GaussianInterval(mean / frame_rate_hz, sd / frame_rate_hz)
    raise ConfigError(f"{where}: 'interval' must be 'polynomial' or 'gaussian', got {form!r}")


def _parse(
    doc: dict[str, Any], emo_doc: dict[str, Any], units_doc: dict[str, Any], gaze: str, emotions: str
) -> GazeParams:
    w = _where(gaze)
    frame_rate = _positive(_table(doc, "units", w), "frame_rate_hz", f"{w} [units]")
    mag = _table(doc, "magnitude", w)
    dur = _table(doc, "duration", w)
    vel = _table(doc, "velocity", w)
    dirs = _table(doc, "direction", w)
    wd = f"{w} [direction]"
    bins = _floats(dirs, "bins_deg", wd)
    percent = _floats(dirs, "percent", wd, length=len(bins))
    if np.any(percent < 0) or percent.sum() <= 0:
        raise ConfigError(f"{wd}: 'percent' must be non-negative with a positive sum")

    blink_table = _table(doc, "blink", w)
    wb = f"{w} [blink]"
    rates = {role: _positive(blink_table, f"rate_{role}_per_min", wb) for role in ROLES}

    roles: dict[str, RoleParams] = {}
    for role in MEASURED_ROLES:
        t = _table(doc, role, w)
        wr = f"{w} [{role}]"
        roles[role] = RoleParams(
            max_magnitude_deg=_positive(t, "max_magnitude_deg", wr),
            mutual_probability=_probability(t, "mutual_probability", wr),
            mutual_interval=_interval(t, "mutual", frame_rate, wr),
            away_interval=_interval(t, "away", frame_rate, wr),
            blink_rate_per_min=rates[role],
        )
    silence_like = require(_table(doc, "silence", w), "like", str, f"{w} [silence]")
    if silence_like not in MEASURED_ROLES:
        raise ConfigError(f"{w} [silence]: 'like' must be one of {', '.join(MEASURED_ROLES)}")
    base = roles[silence_like]
    roles["silence"] = RoleParams(
        base.max_magnitude_deg,
        base.mutual_probability,
        base.mutual_interval,
        base.away_interval,
        rates["silence"],
    )

    curve_s = _floats(blink_table, "lid_curve_s", wb)
    curve_c = _floats(blink_table, "lid_curve_closure", wb, length=len(curve_s))
    if np.any(np.diff(curve_s) <= 0) or curve_s[0] != 0.0:
        raise ConfigError(f"{wb}: 'lid_curve_s' must start at 0 and increase")
    blink = BlinkParams(
        refractory_s=_positive(blink_table, "refractory_s", wb, allow_zero=True),
        pull_window_s=_positive(blink_table, "pull_window_s", wb, allow_zero=True),
        evoked_min_deg=_positive(blink_table, "evoked_min_deg", wb, allow_zero=True),
        evoked_full_deg=_positive(blink_table, "evoked_full_deg", wb),
        evoked_max_probability=_probability(blink_table, "evoked_max_probability", wb),
        head_turn_probability=_probability(blink_table, "head_turn_probability", wb),
        turn_probability=_probability(blink_table, "turn_probability", wb),
        lid_curve_s=curve_s,
        lid_curve_closure=np.clip(curve_c, 0.0, 1.0),
    )
    for role in ROLES:
        if blink.refractory_s >= 60.0 / rates[role]:
            raise ConfigError(f"{wb}: 'refractory_s' must be shorter than the mean interval of {role}")

    noise = _table(doc, "noise", w)
    wn = f"{w} [noise]"
    units_eyes = _table(units_doc, "eyes", "configs/flexor_units.toml")
    default_mode = require(_table(doc, "modes", w), "default", str, f"{w} [modes]")
    if default_mode not in MODES:
        raise ConfigError(f"{w} [modes]: 'default' must be one of {', '.join(MODES)}")
    d0_s = _positive(dur, "d0_s", f"{w} [duration]")
    d_s_per_deg = _positive(dur, "d_s_per_deg", f"{w} [duration]", allow_zero=True)
    p_max = _positive(mag, "p_max", f"{w} [magnitude]")
    p_ref = _positive(mag, "p_ref", f"{w} [magnitude]")
    if p_ref < p_max:
        raise ConfigError(f"{w} [magnitude]: 'p_ref' must be >= 'p_max' so magnitudes stay positive")
    return GazeParams(
        frame_rate_hz=frame_rate,
        p_max=p_max,
        p_ref=p_ref,
        a_scale_deg=_positive(mag, "a_scale_deg", f"{w} [magnitude]"),
        d0_s=d0_s,
        d_s_per_deg=d_s_per_deg,
        velocity_centre=_positive(vel, "centre", f"{w} [velocity]"),
        velocity_span=_positive(vel, "span", f"{w} [velocity]"),
        direction_bins_deg=bins,
        direction_probability=percent / percent.sum(),
        roles=roles,
        silence_like=silence_like,
        head_turn_threshold_deg=_positive(
            _table(doc, "attention", w), "head_turn_threshold_deg", f"{w} [attention]", allow_zero=True
        ),
        noise_yaw_amplitude_deg=_positive(noise, "yaw_amplitude_deg", wn, allow_zero=True),
        noise_pitch_amplitude_deg=_positive(noise, "pitch_amplitude_deg", wn, allow_zero=True),
        noise_frequency_hz=_positive(noise, "frequency_hz", wn),
        blink=blink,
        fixation=_parse_fixation(doc, w, d0_s, d_s_per_deg),
        emotions=_parse_emotions(emo_doc, _where(emotions)),
        eye_yaw_limit_deg=_positive(units_eyes, "look_x_deg", "configs/flexor_units.toml [eyes]"),
        eye_pitch_limit_deg=_positive(units_eyes, "look_y_deg", "configs/flexor_units.toml [eyes]"),
        default_mode=default_mode,
    )


def _parse_fixation(doc: dict[str, Any], w: str, d0_s: float, d_s_per_deg: float) -> FixationParams:
    wf, ws = f"{w} [fixation]", f"{w} [face_scan]"
    fix, scan = _table(doc, "fixation", w), _table(doc, "face_scan", w)
    median = _positive(fix, "microsaccade_median_deg", wf)
    largest = _positive(fix, "microsaccade_max_deg", wf)
    if largest <= median:
        raise ConfigError(f"{wf}: 'microsaccade_max_deg' must be above 'microsaccade_median_deg'")
    distance = _positive(scan, "partner_distance_m", ws)
    half_eyes = math.degrees(math.atan(0.5 * _positive(scan, "interocular_m", ws) / distance))
    mouth = math.degrees(math.atan(_positive(scan, "eyes_to_mouth_m", ws) / distance))
    features = np.array([[-half_eyes, 0.0], [half_eyes, 0.0], [0.0, -mouth]])
    params = FixationParams(
        microsaccade_rate_hz=_positive(fix, "microsaccade_rate_hz", wf),
        microsaccade_median_deg=median,
        microsaccade_log_sd=_positive(fix, "microsaccade_log_sd", wf),
        microsaccade_max_deg=largest,
        refractory_s=_positive(fix, "refractory_s", wf),
        drift_diffusion_deg2_per_s=_positive(fix, "drift_diffusion_arcmin2_per_s", wf, allow_zero=True) / 3600.0,
        correction_spread_deg=_positive(fix, "correction_spread_deg", wf, allow_zero=True),
        scan_rate_hz={role: _positive(scan, f"scan_rate_{role}_hz", ws, allow_zero=True) for role in ROLES},
        mouth_share={role: _probability(scan, f"mouth_share_{role}", ws) for role in ROLES},
        preferred_eye_share=_probability(scan, "preferred_eye_share", ws),
        features_deg=features,
    )
    # The gap must outlast the longest small saccade (main sequence), so intervals count onset to onset.
    span = float(np.max(np.hypot(*(features[:, None, :] - features[None, :, :]).transpose(2, 0, 1))))
    longest = d0_s + d_s_per_deg * (span + 2.0 * largest)
    if params.refractory_s <= longest:
        raise ConfigError(f"{wf}: 'refractory_s' must exceed the longest small saccade, {longest:.3f} s")
    for role in ROLES:
        if params.refractory_s >= 1.0 / params.event_rate_hz(role, True):
            raise ConfigError(f"{wf}: 'refractory_s' must be shorter than the mean interval of small saccades "
                              f"while {role} (1 / {params.event_rate_hz(role, True):g} Hz)")
    return params


def _where(name: str) -> str:
    """How error messages name a config: as given when it is a path, else under configs/."""
    return name if name.endswith(".toml") else f"configs/{name}.toml"


EMOTION_KEYS = ("interval_scale", "magnitude_scale", "mutual_shift", "bias_direction_deg", "bias_strength")


def _parse_emotions(doc: dict[str, Any], where: str) -> dict[str, Emotion]:
    plain: dict[str, Emotion] = {}
    derived: dict[str, tuple[str, float]] = {}
    for name, table in doc.items():
        wt = f"{where} [{name}]"
        if not isinstance(table, dict):
            raise ConfigError(f"{where}: '{name}' must be a table")
        if "same_as" in table:
            unknown = set(table) - {"same_as", "intensity"}
            if unknown:
                raise ConfigError(f"{wt}: unexpected keys {sorted(unknown)} beside 'same_as'")
            derived[name] = (require(table, "same_as", str, wt), _probability(table, "intensity", wt))
            continue
        unknown = set(table) - set(EMOTION_KEYS)
        if unknown:
            raise ConfigError(f"{wt}: unexpected keys {sorted(unknown)}; expected {', '.join(EMOTION_KEYS)}")
        plain[name] = Emotion(
            interval_scale=_positive(table, "interval_scale", wt),
            magnitude_scale=_positive(table, "magnitude_scale", wt),
            mutual_shift=require(table, "mutual_shift", float, wt),
            bias_direction_deg=require(table, "bias_direction_deg", float, wt),
            bias_strength=_positive(table, "bias_strength", wt, allow_zero=True),
        )
    for name, (base, intensity) in derived.items():
        if base not in plain:
            raise ConfigError(f"{where} [{name}]: 'same_as' names {base!r}, which is not a plain emotion")
        plain[name] = plain[base].at_intensity(intensity)
    if "natural" not in plain or plain["natural"] != Emotion():
        raise ConfigError(f"{where}: 'natural' must exist and be the identity")
    return {name: plain[name] for name in doc}
