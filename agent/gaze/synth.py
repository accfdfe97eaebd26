"""The Saccade Synthesizer: the eye's position at any instant of a saccade.

Paper eq. 3 (Vinayagamoorthy et al. 2004) gives the velocity V(X) = 14 exp(-(pi/4)(X - 3)^2) over
X in [0, 6], mapped linearly onto the saccade's duration. The eye's progress is the running integral of
V over its whole area, which has the closed form

    progress(tau) = (erf(k (6 tau - 3)) + erf(3 k)) / (2 erf(3 k)),   k = sqrt(pi) / 2,

so it is 0 at onset, exactly 1 at t0 + D, and its velocity peaks mid-flight. (The area is 27.996, not
quite 28, so dividing by 28 would leave the eye 0.016% short; dividing by the true area lands it.)
The closed form is tabulated once with math.erf and read back by cubic Hermite interpolation with the
exact derivative, accurate to about 1e-12, so whole crowds are evaluated with numpy alone. Positions
are a pure function of time: any frame rate samples the same trajectory.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

PAPER_CENTRE = 3.0
PAPER_SPAN = 6.0
_WIDTH = math.pi / 4.0
_TABLE_INTERVALS = 4096


@lru_cache(maxsize=8)
def _table(centre: float, span: float) -> tuple[np.ndarray, np.ndarray]:
    """Progress and its derivative d progress / d tau at tau = i / _TABLE_INTERVALS."""
    k = math.sqrt(_WIDTH)
    lo = math.erf(k * (0.0 - centre))
    hi = math.erf(k * (span - centre))
    tau = np.linspace(0.0, 1.0, _TABLE_INTERVALS + 1)
    erf_values = np.array([math.erf(k * (span * t - centre)) for t in tau])
    progress = (erf_values - lo) / (hi - lo)
    derivative = span * (2.0 * k / math.sqrt(math.pi)) * np.exp(-_WIDTH * (span * tau - centre) ** 2) / (hi - lo)
    progress[0], progress[-1] = 0.0, 1.0
    return progress, derivative


def saccade_progress(tau: np.ndarray | float, centre: float = PAPER_CENTRE, span: float = PAPER_SPAN) -> np.ndarray:
    """Fraction of the saccade covered at normalised time tau = (t - t0) / D; 0 before, 1 after."""
    progress, derivative = _table(centre, span)
    x = np.clip(np.asarray(tau, dtype=np.float64), 0.0, 1.0) * _TABLE_INTERVALS
    i = np.minimum(x.astype(np.int64), _TABLE_INTERVALS - 1)
    s = x - i
    h = 1.0 / _TABLE_INTERVALS
    p0, p1 = progress[i], progress[i + 1]
    m0, m1 = derivative[i] * h, derivative[i + 1] * h
    s2 = s * s
    s3 = s2 * s
    return (2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * m0 + (-2 * s3 + 3 * s2) * p1 + (s3 - s2) * m1


def saccade_velocity(tau: np.ndarray | float, centre: float = PAPER_CENTRE, span: float = PAPER_SPAN) -> np.ndarray:
    """d progress / d tau: paper eq. 3 normalised to unit area over the saccade; 0 outside it."""
    k = math.sqrt(_WIDTH)
    area = math.erf(k * (span - centre)) - math.erf(-k * centre)
    t = np.asarray(tau, dtype=np.float64)
    value = span * (2.0 * k / math.sqrt(math.pi)) * np.exp(-_WIDTH * (span * t - centre) ** 2) / area
    return np.where((t >= 0.0) & (t <= 1.0), value, 0.0)


def eye_position_at(
    t_ns: np.ndarray | int,
    onset_ns: np.ndarray | int,
    from_deg: np.ndarray | tuple[float, float],
    to_deg: np.ndarray | tuple[float, float],
    duration_s: np.ndarray | float,
) -> np.ndarray:
    """Eye (yaw, pitch) in degrees at t_ns during or after a saccade; broadcasts, last axis is (yaw, pitch).

    Before the onset the eye is at `from_deg`, after onset + duration exactly at `to_deg`.
    """
    elapsed_s = (np.asarray(t_ns, dtype=np.int64) - np.asarray(onset_ns, dtype=np.int64)) * 1e-9
    duration = np.asarray(duration_s, dtype=np.float64)
    tau = np.where(duration > 0.0, elapsed_s / np.where(duration > 0.0, duration, 1.0), 1.0)
    tau = np.where(elapsed_s < 0.0, 0.0, tau)
    progress = saccade_progress(tau)[..., None]
    start = np.asarray(from_deg, dtype=np.float64)
    end = np.asarray(to_deg, dtype=np.float64)
    # This form is exact at both ends: the eye is exactly at `from` at onset and at `to` on landing.
    return start * (1.0 - progress) + end * progress
