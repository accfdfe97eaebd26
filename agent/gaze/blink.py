"""The statistical blink model of eye mode "saccade+blink": lid curve and gaze-evoked blink chance."""

from __future__ import annotations

import numpy as np

from agent.gaze.params import BlinkParams


def lid_closure(elapsed_s: np.ndarray | float, blink: BlinkParams) -> np.ndarray:
    """Lid closure (0 open, 1 closed) at `elapsed_s` after a blink's onset; 0 before and after it."""
    elapsed = np.asarray(elapsed_s, dtype=np.float64)
    return np.interp(elapsed, blink.lid_curve_s, blink.lid_curve_closure, left=0.0, right=0.0)


def evoked_blink_probability(amplitude_deg: np.ndarray | float, blink: BlinkParams) -> np.ndarray:
    """Chance that a saccade of this amplitude carries a blink: 0 below the minimum, rising linearly."""
    span = max(blink.evoked_full_deg - blink.evoked_min_deg, 1e-9)
    ramp = (np.asarray(amplitude_deg, dtype=np.float64) - blink.evoked_min_deg) / span
    return np.clip(ramp, 0.0, 1.0) * blink.evoked_max_probability
