"""The Saccade Synthesizer: the eye's position at any instant of a saccade.

Paper eq. 3 (Vinayagamoorthy et al. 2004) gives the velocity V(X) = 14 exp(-(pi/4)(X - 3)^2) over
X in [0, 6], mapped linearly onto the saccade's duration. The eye's progress is the running integral of
V over its whole area, which has the closed form

    progress(tau) = (erf(k (6 tau - 3)) + erf(3 k)) / (2 erf(3 k)),   k = sqrt(pi) / 2,

so it is 0 at onset, exactly 1 at t0 + D, and its velocity peaks mid-flight. (The area is 27.996, not
quite 28, so dividing by 28 would leave the eye 0.016% short; dividing by the true area lands it.)
The closed form is tabulated once with math.erf as one quadratic per table cell (through the cell's
ends and middle), read back in Horner form: three look-ups and four multiply-adds per eye, accurate to
about 3e-12, so whole crowds are evaluated with few numpy calls. Positions are a pure function of
time: any frame rate samples the same trajectory.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

PAPER_CENTRE = 3.0
PAPER_SPAN = 6.0
_WIDTH = math.pi / 4.0
_TABLE_INTERVALS = 8192
# Constant operands as 0-d arrays: numpy converts a Python float on every call, an array it takes as it is.
_ZERO, _ONE, _CELLS = np.array(0.0), np.array(1.0), np.array(float(_TABLE_INTERVALS))


@lru_cache(maxsize=8)
def _table(centre: float, span: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per cell i the quadratic progress(s) = a + s (b + s c) in its local time s in [0, 1], through the
    exact progress at the cell's start, middle and end. One cell past the last holds the constant 1, so
    tau = 1 needs no clamp of the cell index."""
    k = math.sqrt(_WIDTH)
    lo = math.erf(k * (0.0 - centre))
    hi = math.erf(k * (span - centre))
    tau = np.linspace(0.0, 1.0, 2 * _TABLE_INTERVALS + 1)
    progress = (np.array([math.erf(k * (span * t - centre)) for t in tau]) - lo) / (hi - lo)
    progress[0], progress[-1] = 0.0, 1.0
    start, middle, end = progress[:-1:2], progress[1::2], progress[2::2]
    c = 2.0 * (end - 2.0 * middle + start)
    b = end - start - c
    return np.append(start, 1.0), np.append(b, 0.0), np.append(c, 0.0)


@lru_cache(maxsize=8)
def _cells(centre: float, span: float) -> np.ndarray:
    """_table's cells as one 32-byte element each (a, b, c and a zero): one gather reads a cell, instead of
    three. numpy gathers elements of 32 bytes (not 24) with a copy of its own instead of a call to memmove."""
    a, b, c = _table(centre, span)
    cells = np.stack([a, b, c, np.zeros_like(a)], axis=1)
    return cells.view(np.dtype((np.void, 32))).reshape(-1)


def saccade_progress(tau: np.ndarray | float, centre: float = PAPER_CENTRE, span: float = PAPER_SPAN) -> np.ndarray:
    """Fraction of the saccade covered at normalised time tau = (t - t0) / D; 0 before, 1 after."""
    x = np.minimum(np.maximum(tau, _ZERO), _ONE)  # np.clip's Python wrapper costs more than this on 1000 eyes
    x *= _CELLS
    cell = x.astype(np.int64)
    x -= cell
    if np.ndim(cell):
        a, b, c, _ = _cells(centre, span).take(cell).view(np.float64).reshape(-1, 4).T
    else:
        a, b, c = (column.take(cell) for column in _table(centre, span))
    progress = c * x
    progress += b
    progress *= x
    progress += a  # exact at both ends: 0 + 0 at tau = 0, and 1 + 0 at tau = 1
    return progress


def eye_position_one(
    t_ns: int,
    onset_ns: int,
    from_deg: tuple[float, float],
    to_deg: tuple[float, float],
    duration_s: float,
) -> tuple[float, float]:
    """eye_position_at for one eye, in plain floats, the same arithmetic step for step (so the same values
    bit for bit): a renderer asks once per frame, where numpy's per-call costs are most of the work."""
    elapsed_s = (int(t_ns) - int(onset_ns)) * 1e-9
    duration = float(duration_s)
    if elapsed_s < 0.0:
        tau = 0.0
    elif duration > 0.0:
        tau = elapsed_s / duration
    else:
        tau = 1.0
    a, b, c = _table(PAPER_CENTRE, PAPER_SPAN)
    x = min(max(tau, 0.0), 1.0) * _TABLE_INTERVALS
    cell = int(x)
    x -= cell
    progress = (float(c[cell]) * x + float(b[cell])) * x + float(a[cell])
    remaining = 1.0 - progress
    return (
        float(from_deg[0]) * remaining + float(to_deg[0]) * progress,
        float(from_deg[1]) * remaining + float(to_deg[1]) * progress,
    )


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
