"""Perlin's 1-D gradient noise and his blink pulse, vectorised and seeded.

Perlin's ResponsiveFace drove idle motion and blinks with `noise(t)`; its blink was
`pulse(t/2 + noise(t/1.5) + 0.5*noise(t/3), 0.05)`, as the paper's conditions b and c use it
(docs/gaze.md).
"""

from __future__ import annotations

import numpy as np

from eca.agent.counter_rng import uniform01


def _fade(f: np.ndarray) -> np.ndarray:
    return f * f * f * (f * (f * 6.0 - 15.0) + 10.0)


def perlin1d(x: np.ndarray | float, seed: int = 0, stream: np.ndarray | int = 0) -> np.ndarray:
    """Gradient noise in about [-1, 1], zero at integers, smooth (C2) everywhere.

    `stream` selects an independent noise function (one per agent or per flexor), broadcast with x.
    """
    x = np.asarray(x, dtype=np.float64)
    i0 = np.floor(x)
    f = x - i0
    lattice = i0.astype(np.int64).astype(np.uint64)
    g0 = uniform01(seed, stream, lattice) * 2.0 - 1.0
    g1 = uniform01(seed, stream, lattice + np.uint64(1)) * 2.0 - 1.0
    n0 = g0 * f
    n1 = g1 * (f - 1.0)
    return 2.0 * (n0 + _fade(f) * (n1 - n0))


def pulse(x: np.ndarray | float, width: float) -> np.ndarray:
    """Perlin's pulse: 1 where the fractional part of x is below `width`, else 0, with smooth edges."""
    frac = np.mod(np.asarray(x, dtype=np.float64), 1.0)
    edge = width * 0.25
    rise = np.clip(frac / edge, 0.0, 1.0) if edge > 0 else (frac >= 0).astype(np.float64)
    fall = np.clip((width - frac) / edge, 0.0, 1.0) if edge > 0 else (frac < width).astype(np.float64)
    return np.minimum(rise, fall)


def perlin_blink(t_s: np.ndarray | float, seed: int = 0, stream: np.ndarray | int = 0) -> np.ndarray:
    """Lid closure in [0, 1] from Perlin's blink formula at time t (seconds)."""
    t = np.asarray(t_s, dtype=np.float64)
    phase = t / 2.0 + perlin1d(t / 1.5, seed, stream) + 0.5 * perlin1d(t / 3.0, seed + 1, stream)
    return pulse(phase, 0.05)
