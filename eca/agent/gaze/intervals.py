"""Inter-saccadic interval distributions (how long the eye holds a fixation), sampled by inverse CDF.

Talking uses the paper's polynomial fits (eq. 4 mutual, eq. 5 away) as densities over their valid
frame ranges; listening uses Eyes Alive's Gaussians with non-positive values redrawn. Redrawing until a
value is positive gives exactly the Gaussian truncated at zero, so both are sampled in one step from a
fine table of their exact CDF: one uniform per interval, whatever the draw.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.polynomial import Polynomial

_TABLE_POINTS = 16_385


class IntervalDistribution:
    """A distribution of hold times in seconds with an exact CDF and a tabulated inverse."""

    grid_s: np.ndarray
    cdf_grid: np.ndarray

    def sample_s(self, u: np.ndarray) -> np.ndarray:
        """Map uniforms in [0, 1) to hold times in seconds (inverse CDF)."""
        return np.interp(u, self.cdf_grid, self.grid_s)

    def cdf_s(self, x_s: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def pdf_s(self, x_s: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    @property
    def mean_s(self) -> float:
        raise NotImplementedError


class PolynomialInterval(IntervalDistribution):
    """Density proportional to a polynomial in frames on [lo, hi] frames (paper eq. 4 and 5)."""

    def __init__(self, coeffs: tuple[float, ...], lo_frames: float, hi_frames: float, frame_rate_hz: float):
        if not 0.0 <= lo_frames < hi_frames:
            raise ValueError(f"range must satisfy 0 <= lo < hi, got [{lo_frames}, {hi_frames}]")
        poly = Polynomial(coeffs)
        frames = np.linspace(lo_frames, hi_frames, _TABLE_POINTS)
        if np.any(poly(frames) <= 0.0):
            raise ValueError(f"the polynomial is not positive everywhere on [{lo_frames}, {hi_frames}] frames")
        antiderivative = poly.integ(lbnd=lo_frames)
        area = float(antiderivative(hi_frames))
        self._poly = poly
        self._antiderivative = antiderivative
        self._area = area
        self._lo = lo_frames
        self._hi = hi_frames
        self._fps = frame_rate_hz
        cdf = antiderivative(frames) / area
        cdf[0], cdf[-1] = 0.0, 1.0
        self.grid_s = frames / frame_rate_hz
        self.cdf_grid = cdf

    def cdf_s(self, x_s: np.ndarray) -> np.ndarray:
        frames = np.clip(np.asarray(x_s, dtype=np.float64) * self._fps, self._lo, self._hi)
        return self._antiderivative(frames) / self._area

    def pdf_s(self, x_s: np.ndarray) -> np.ndarray:
        frames = np.asarray(x_s, dtype=np.float64) * self._fps
        inside = (frames >= self._lo) & (frames <= self._hi)
        return np.where(inside, self._poly(frames) / self._area * self._fps, 0.0)

    @property
    def mean_s(self) -> float:
        first_moment = (self._poly * Polynomial([0.0, 1.0])).integ(lbnd=self._lo)(self._hi)
        return float(first_moment / self._area / self._fps)


class GaussianInterval(IntervalDistribution):
    """A Gaussian (mean, standard deviation, seconds) truncated to positive values."""

    _SPAN_SD = 7.0

    def __init__(self, mean_s: float, sd_s: float):
        if not (sd_s > 0.0 and math.isfinite(mean_s)):
            raise ValueError(f"need a finite mean and a positive sd, got {mean_s}, {sd_s}")
        self._mu = mean_s
        self._sd = sd_s
        self._mass_below_zero = _phi(-mean_s / sd_s)
        grid = np.linspace(0.0, mean_s + self._SPAN_SD * sd_s, _TABLE_POINTS)
        cdf = np.maximum.accumulate(self.cdf_s(grid))
        cdf[0] = 0.0
        self.grid_s = grid
        self.cdf_grid = cdf / cdf[-1]

    def cdf_s(self, x_s: np.ndarray) -> np.ndarray:
        x = np.maximum(np.asarray(x_s, dtype=np.float64), 0.0)
        z = (x - self._mu) / (self._sd * math.sqrt(2.0))
        full = 0.5 * (1.0 + _erf(z))
        return (full - self._mass_below_zero) / (1.0 - self._mass_below_zero)

    def pdf_s(self, x_s: np.ndarray) -> np.ndarray:
        x = np.asarray(x_s, dtype=np.float64)
        density = np.exp(-0.5 * ((x - self._mu) / self._sd) ** 2) / (self._sd * math.sqrt(2.0 * math.pi))
        return np.where(x > 0.0, density / (1.0 - self._mass_below_zero), 0.0)

    @property
    def mean_s(self) -> float:
        z = self._mu / self._sd
        density_at_cut = math.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)
        return self._mu + self._sd * density_at_cut / (1.0 - self._mass_below_zero)


_vector_erf = np.frompyfunc(math.erf, 1, 1)


def _erf(z: np.ndarray) -> np.ndarray:
    # Only used to build tables and for plots, never in the per-tick path, so math.erf is fast enough.
    return np.asarray(_vector_erf(np.asarray(z, dtype=np.float64)), dtype=np.float64)


def _phi(z: float) -> float:
    return 0.5 * (1.0 + math.erf(z / math.sqrt(2.0)))
