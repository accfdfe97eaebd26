"""The Eyes Alive saccade Parameter Generator: pure maps from uniforms to saccade parameters.

Each function takes uniforms in [0, 1) (from the counter-based streams) and per-saccade settings as
arrays, so a whole crowd's saccades are drawn in one call; the engine (engine.py) and the one-agent
reference model (reference.py) both draw through them.
"""

from __future__ import annotations

import numpy as np

from eca.agent.counter_rng import splitmix64
from eca.agent.gaze.params import ROLES, GazeParams

# The model's random streams: each kind of draw reads its own, derived from the engine's seed (derive_seed),
# so that one kind of draw never shifts another.
SACCADE_STREAM, BLINK_STREAM, NOISE_STREAM, PERLIN_BLINK_STREAM, FIXATION_STREAM, TARGET_CHOICE_STREAM = range(1, 7)
HOLD_TABLE_INTERVALS = 32_768  # cells of the hold times' quantile tables


def derive_seed(seed: int, stream: int) -> int:
    """The seed of one of the streams above from the engine's seed."""
    return int(splitmix64(np.uint64((seed * 8 + stream) & 0xFFFFFFFFFFFFFFFF)))


def min_uniform_p(params: GazeParams, max_magnitude_deg: np.ndarray | float) -> np.ndarray:
    """The smallest P whose magnitude stays within the limit: A <= max  <=>  P >= p_ref * exp(-max / a)."""
    return params.p_ref * np.exp(-np.asarray(max_magnitude_deg, dtype=np.float64) / params.a_scale_deg)


def magnitude_map(
    params: GazeParams, max_magnitude_deg: np.ndarray | float, magnitude_scale: np.ndarray | float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """Eyes Alive eq. 1 with its redraw above the role's limit, as one inverse-CDF step: the (span, factor)
    of A = factor * ln(p_max / p_ref - u * span) for a uniform u in [0, 1).

    Redrawing P uniform on (0, p_max] until A = -a ln(P / p_ref) <= max leaves P uniform on
    [P_min, p_max], so we draw it there directly: P = p_max - u (p_max - P_min). An emotion's scale
    multiplies the result; for scales above 1 the unscaled draw is truncated at max / scale so the role
    limit still holds. The engine folds (span, factor) into each agent's row when its role or emotion changes.
    """
    scale = np.asarray(magnitude_scale, dtype=np.float64)
    limit = np.asarray(max_magnitude_deg, dtype=np.float64) / np.maximum(scale, 1.0)
    span = (params.p_max - min_uniform_p(params, limit)) / params.p_ref
    return span, -params.a_scale_deg * scale


def magnitude_from_map(
    u: np.ndarray | float, params: GazeParams, span: np.ndarray | float, factor: np.ndarray | float
) -> np.ndarray:
    """The saccade magnitude (degrees) drawn from a uniform by magnitude_map's (span, factor)."""
    return np.log(params.p_max / params.p_ref - np.asarray(u, dtype=np.float64) * span) * factor


def magnitude_from_uniform(
    u: np.ndarray | float,
    params: GazeParams,
    max_magnitude_deg: np.ndarray | float,
    magnitude_scale: np.ndarray | float = 1.0,
) -> np.ndarray:
    """The saccade magnitude (degrees) drawn from a uniform, within the role's limit, scaled by the emotion."""
    span, factor = magnitude_map(params, max_magnitude_deg, magnitude_scale)
    return magnitude_from_map(u, params, span, factor)


def magnitude_cdf(a_deg: np.ndarray, params: GazeParams, max_magnitude_deg: float) -> np.ndarray:
    """The exact CDF of `magnitude_from_uniform` at scale 1 (a truncated shifted exponential)."""
    p_min = float(min_uniform_p(params, max_magnitude_deg))
    a = np.asarray(a_deg, dtype=np.float64)
    p_at_a = params.p_ref * np.exp(-a / params.a_scale_deg)
    return np.clip((params.p_max - p_at_a) / (params.p_max - p_min), 0.0, 1.0)


def direction_weights(
    params: GazeParams, bias_direction_deg: np.ndarray | float, bias_strength: np.ndarray | float
) -> np.ndarray:
    """Per-saccade probabilities of the eight bins, tilted toward an emotion's bias (shape (..., 8))."""
    bins = np.deg2rad(params.direction_bins_deg)
    toward = np.deg2rad(np.asarray(bias_direction_deg, dtype=np.float64))[..., None]
    strength = np.asarray(bias_strength, dtype=np.float64)[..., None]
    weights = params.direction_probability * np.exp(strength * np.cos(bins - toward))
    return weights / weights.sum(axis=-1, keepdims=True)


def direction_index_from_uniform(
    u: np.ndarray | float,
    params: GazeParams,
    bias_direction_deg: np.ndarray | float = 0.0,
    bias_strength: np.ndarray | float = 0.0,
) -> np.ndarray:
    """Which of the eight bins (index into params.direction_bins_deg), by inverse CDF over the (tilted) bin
    weights."""
    u = np.asarray(u, dtype=np.float64)
    strength = np.asarray(bias_strength, dtype=np.float64)
    index = np.searchsorted(np.cumsum(params.direction_probability), u, side="right")
    if np.any(strength):
        strength = np.broadcast_to(strength, u.shape)
        weights = direction_weights(params, np.broadcast_to(bias_direction_deg, u.shape), strength)
        tilted = (u[..., None] >= np.cumsum(weights, axis=-1)).sum(axis=-1)
        # Untilted draws keep the table's own edges (renormalised weights can differ from them in the last
        # bit), so a draw never depends on the other draws it is made with.
        index = np.where(strength != 0.0, tilted, index)
    return np.minimum(index, len(params.direction_bins_deg) - 1)


def direction_from_uniform(
    u: np.ndarray | float,
    params: GazeParams,
    bias_direction_deg: np.ndarray | float = 0.0,
    bias_strength: np.ndarray | float = 0.0,
) -> np.ndarray:
    """One of the eight bin centres (degrees), chosen by inverse CDF over the (tilted) bin weights."""
    return params.direction_bins_deg[direction_index_from_uniform(u, params, bias_direction_deg, bias_strength)]


def direction_unit_steps(params: GazeParams) -> tuple[np.ndarray, np.ndarray]:
    """Per bin the unit step (yaw, pitch) of its direction: an away saccade lands magnitude * step from the
    gaze target."""
    bins = np.deg2rad(params.direction_bins_deg)
    return np.cos(bins), np.sin(bins)


def saccade_duration_s(amplitude_deg: np.ndarray | float, params: GazeParams) -> np.ndarray:
    """Eyes Alive eq. 2: D = D0 + d * A."""
    return params.d0_s + params.d_s_per_deg * np.asarray(amplitude_deg, dtype=np.float64)


def hold_quantiles(params: GazeParams, role: str, away: bool) -> np.ndarray:
    """The hold time distribution (s) of (role, mutual or away) as HOLD_TABLE_INTERVALS + 1 quantiles at
    evenly spaced probabilities: reading between two of them is the inverse CDF to well below a frame."""
    role_params = params.roles[role]
    distribution = role_params.away_interval if away else role_params.mutual_interval
    return distribution.sample_s(np.linspace(0.0, 1.0, HOLD_TABLE_INTERVALS + 1))


def hold_from_uniform(u: float, quantiles: np.ndarray, interval_scale: float) -> float:
    """A hold time (s) drawn from a uniform in [0, 1) by the quantile table, stretched by the emotion."""
    x = u * HOLD_TABLE_INTERVALS
    cell = int(x)  # u < 1, so the cell is at most the last one
    x -= cell
    return float(((quantiles[cell + 1] - quantiles[cell]) * x + quantiles[cell]) * interval_scale)


def mutual_probability(
    params: GazeParams, role_index: np.ndarray, mutual_shift: np.ndarray | float = 0.0
) -> np.ndarray:
    """P(mutual) per saccade for role indices into params.ROLES, shifted by emotion, clipped to [0, 1]."""
    per_role = np.array([params.roles[r].mutual_probability for r in ROLES])
    return np.clip(per_role[role_index] + mutual_shift, 0.0, 1.0)
