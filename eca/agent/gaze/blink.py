"""The statistical blink model of eye mode "saccade+blink": lid curve, blink intervals and gaze-evoked blink chance."""

from __future__ import annotations

import numpy as np

from eca.agent.gaze.params import BlinkParams

_NS = 1_000_000_000


def lid_closure(elapsed_s: np.ndarray | float, blink: BlinkParams) -> np.ndarray:
    """Lid closure (0 open, 1 closed) at `elapsed_s` after a blink's onset; 0 before and after it."""
    elapsed = np.asarray(elapsed_s, dtype=np.float64)
    return np.interp(elapsed, blink.lid_curve_s, blink.lid_curve_closure, left=0.0, right=0.0)


def blink_spread_ns(blink: BlinkParams, rate_per_min: np.ndarray | float) -> np.ndarray:
    """The mean of the exponential part of the interval between spontaneous blinks (ns): the mean interval
    60 / rate less the refractory gap."""
    return (60.0 / np.asarray(rate_per_min, dtype=np.float64) - blink.refractory_s) * _NS


def blink_interval_ns(spread_ns: np.ndarray | float, u: np.ndarray | float, blink: BlinkParams) -> np.ndarray:
    """Onset to the next spontaneous blink (ns) from a uniform in [0, 1): the refractory gap plus an
    exponential of mean `spread_ns` (a renewal process at the role's rate)."""
    return np.rint(blink.refractory_s * _NS - spread_ns * np.log1p(-np.asarray(u))).astype(np.int64)


def evoked_blink_probability(amplitude_deg: np.ndarray | float, blink: BlinkParams) -> np.ndarray:
    """Chance that a saccade of this amplitude carries a blink: 0 below the minimum, rising linearly to the
    maximum chance at evoked_full_deg."""
    slope = blink.evoked_max_probability / max(blink.evoked_full_deg - blink.evoked_min_deg, 1e-9)
    chance = (np.asarray(amplitude_deg, dtype=np.float64) - blink.evoked_min_deg) * slope
    return np.minimum(np.maximum(chance, 0.0), blink.evoked_max_probability)
