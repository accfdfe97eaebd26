"""The Eyes Alive saccade Parameter Generator: pure maps from uniforms to saccade parameters.

Each function takes uniforms in [0, 1) (from the counter-based streams) and per-saccade settings as
arrays, so a whole crowd's saccades are drawn in one call.
"""

from __future__ import annotations

import numpy as np

from agent.gaze.params import ROLES, GazeParams


def min_uniform_p(params: GazeParams, max_magnitude_deg: np.ndarray | float) -> np.ndarray:
    """The smallest P whose magnitude stays within the limit: A <= max  <=>  P >= p_ref * exp(-max / a)."""
    return params.p_ref * np.exp(-np.asarray(max_magnitude_deg, dtype=np.float64) / params.a_scale_deg)


def magnitude_from_uniform(
    u: np.ndarray,
    params: GazeParams,
    max_magnitude_deg: np.ndarray | float,
    magnitude_scale: np.ndarray | float = 1.0,
) -> np.ndarray:
    """Eyes Alive eq. 1 with its redraw above the role's limit, as one inverse-CDF step.

    Redrawing P uniform on (0, p_max] until A = -a ln(P / p_ref) <= max leaves P uniform on
    [P_min, p_max], so we draw it there directly. An emotion's scale multiplies the result; for scales
    above 1 the unscaled draw is truncated at max / scale so the role limit still holds.
    """
    scale = np.asarray(magnitude_scale, dtype=np.float64)
    limit = np.asarray(max_magnitude_deg, dtype=np.float64) / np.maximum(scale, 1.0)
    p_min = min_uniform_p(params, limit)
    p = params.p_max - np.asarray(u, dtype=np.float64) * (params.p_max - p_min)
    return -params.a_scale_deg * np.log(p / params.p_ref) * scale


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


def direction_from_uniform(
    u: np.ndarray,
    params: GazeParams,
    bias_direction_deg: np.ndarray | float = 0.0,
    bias_strength: np.ndarray | float = 0.0,
) -> np.ndarray:
    """One of the eight bin centres (degrees), chosen by inverse CDF over the (tilted) bin weights."""
    u = np.asarray(u, dtype=np.float64)
    strength = np.asarray(bias_strength, dtype=np.float64)
    if not np.any(strength):
        cumulative = np.cumsum(params.direction_probability)
        index = np.searchsorted(cumulative, u, side="right")
    else:
        weights = direction_weights(
            params, np.broadcast_to(bias_direction_deg, u.shape), np.broadcast_to(strength, u.shape)
        )
        index = (u[..., None] >= np.cumsum(weights, axis=-1)).sum(axis=-1)
    index = np.minimum(index, len(params.direction_bins_deg) - 1)
    return params.direction_bins_deg[index]


def saccade_duration_s(amplitude_deg: np.ndarray | float, params: GazeParams) -> np.ndarray:
    """Eyes Alive eq. 2: D = D0 + d * A."""
    return params.d0_s + params.d_s_per_deg * np.asarray(amplitude_deg, dtype=np.float64)


def mutual_probability(
    params: GazeParams, role_index: np.ndarray, mutual_shift: np.ndarray | float = 0.0
) -> np.ndarray:
    """P(mutual) per saccade for role indices into params.ROLES, shifted by emotion, clipped to [0, 1]."""
    per_role = np.array([params.roles[r].mutual_probability for r in ROLES])
    return np.clip(per_role[role_index] + mutual_shift, 0.0, 1.0)
