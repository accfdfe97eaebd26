"""Acoustic features of 10 ms blocks: level, band balance and LPC formants.

Formants come from *selective* linear prediction (Makhoul 1975): the autocorrelation is the inverse
FFT of the power spectrum restricted to 0..`lpc_band_hz`, which is the autocorrelation the signal
would have if it were low-passed and resampled to 2 x `lpc_band_hz`. So any input rate is analysed
at the same effective rate without a time-domain resampler, and the LPC order stays small.

The resonances are the peaks of the LPC spectrum 1/|A|^2, found on a fixed frequency grid and refined
by a parabola through the three grid values around each minimum of |A|^2; the parabola's depth and
curvature give the resonance's bandwidth. That is the answer the roots of A(z) give, for a fraction of
the cost of a polynomial root finder (an eigenvalue problem), which would dominate the block's time.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

_EPS = 1e-12


@dataclass(frozen=True, slots=True)
class BlockFeatures:
    level_db: float  # block power in dB re full scale (a full-scale sine is -3 dB)
    high_ratio: float  # share of window power above the fricative cut-off
    low_ratio: float  # share of window power below the nasal cut-off


def fast_fft_size(n: int) -> int:
    """The smallest 2^a 3^b 5^c >= n: sizes the FFT computes fastest, and not twice what is needed as
    the next power of two can be."""
    best = 1 << max(0, (n - 1).bit_length())
    p5 = 1
    while p5 < best:
        p35 = p5
        while p35 < best:
            size = p35
            while size < n:
                size *= 2
            best = min(best, size)
            p35 *= 3
        p5 *= 5
    return best


def levinson(r: np.ndarray, order: int) -> tuple[np.ndarray, float]:
    """Levinson-Durbin recursion: LPC polynomial a (a[0] = 1) and the final prediction error."""
    # Plain floats: for order ~10 this is several times faster than per-step numpy calls.
    rr = [float(v) for v in r[: order + 1]]
    a = [1.0] + [0.0] * order
    err = rr[0]
    if err > 0.0:
        for i in range(1, order + 1):
            acc = rr[i]
            for j in range(1, i):
                acc += a[j] * rr[i - j]
            k = -acc / err
            prev = a[:i]
            for j in range(1, i):
                a[j] = prev[j] + k * prev[i - j]
            a[i] = k
            err *= 1.0 - k * k
            if err <= 0.0:
                break
    return np.array(a), max(err, 0.0)


def formants(a: np.ndarray, rate_hz: float, max_bandwidth_hz: float,
             companion: np.ndarray | None = None) -> list[float]:
    """Resonances of the all-pole model 1/A(z): frequencies (Hz, ascending) of roots with narrow bandwidth.

    `companion` may be a preallocated order x order matrix with ones on the subdiagonal (saves time).
    """
    order = len(a) - 1
    if order < 2:
        return []
    if companion is None:
        companion = np.eye(order, k=-1)
    # Eigenvalues of the companion matrix are the polynomial's roots (what np.roots does, minus checks).
    np.divide(a[1:], -a[0], out=companion[0])
    roots = np.linalg.eigvals(companion)
    roots = roots[roots.imag > 0.0]
    # A handful of roots: plain floats from here on.
    to_hz = rate_hz / (2.0 * math.pi)
    min_radius = math.exp(-math.pi * max_bandwidth_hz / rate_hz)  # bandwidth < max <=> |root| > this
    found = [math.atan2(z.imag, z.real) * to_hz for z in roots.tolist() if abs(z) > min_radius]
    return sorted(f for f in found if f > 90.0)


def lpc_solve(r: np.ndarray, toeplitz_index: np.ndarray) -> np.ndarray | None:
    """LPC polynomial (a[0] = 1) from the autocorrelation by solving the Toeplitz normal equations.

    The same solution as `levinson`; one LAPACK call costs less than the recursion in Python at the
    orders used here. None when the system is singular (no usable spectrum).
    """
    order = toeplitz_index.shape[0]
    a = np.empty(order + 1)
    a[0] = 1.0
    try:
        a[1:] = np.linalg.solve(r[toeplitz_index], -r[1 : order + 1])
    except np.linalg.LinAlgError:
        return None
    return a


class SpectrumPeaks:
    """Resonances of 1/A(z) from |A|^2 on a fixed grid of frequencies in [0, max_hz].

    |A(e^jw)|^2 is a cosine series in the autocorrelation of a, so one small matrix-vector product
    evaluates it on the whole grid. Near a pole at radius rho and angle w0, |A|^2 ~ c((1 - rho)^2 +
    rho (w - w0)^2): a parabola through three grid values gives w0, and depth / curvature gives
    (1 - rho)^2 / rho, hence the bandwidth, with no root finding.
    """

    def __init__(self, order: int, rate_hz: float, max_hz: float, step_hz: float, max_bandwidth_hz: float,
                 contour_bandwidth_hz: float = 0.0) -> None:
        self.rate_hz = float(rate_hz)
        if not 0.0 <= contour_bandwidth_hz <= 0.5 * max_bandwidth_hz:
            raise ValueError("contour_bandwidth_hz must lie in [0, max_bandwidth_hz / 2]")
        n = max(8, int(math.ceil(min(max_hz, 0.5 * rate_hz) / step_hz)) + 2)
        self.step_rad = 2.0 * math.pi * step_hz / rate_hz
        w = np.arange(n) * self.step_rad
        k = np.arange(order + 1)
        self._basis = np.where(k == 0, 1.0, 2.0)[None, :] * np.cos(w[:, None] * k[None, :])
        self.order = order
        # A(z) on the circle |z| = rho_c: the poles z_k act as poles at z_k / rho_c, whose bandwidth is
        # |B_k - B_c|, so resonances of typical vowel bandwidth become sharp peaks that do not merge.
        rho_c = math.exp(-math.pi * contour_bandwidth_hz / rate_hz)
        self._scale = rho_c ** -k.astype(float)
        # bandwidth < max  <=>  the apparent radius rho / rho_c > rho_min / rho_c  <=>
        # (1 - rho')^2 / rho' below its value there (for B_c <= max / 2 this also holds for rho' > 1)
        rho_min = math.exp(-math.pi * max_bandwidth_hz / rate_hz) / rho_c
        self._max_depth_ratio = (1.0 - rho_min) ** 2 / rho_min
        self._to_hz = rate_hz / (2.0 * math.pi)

    def __call__(self, a: np.ndarray) -> list[float]:
        """Frequencies (Hz, ascending) of the narrow resonances of 1/A."""
        a = a * self._scale
        c = np.correlate(a, a, "full")[self.order :]
        y = self._basis @ c
        # A minimum of |A|^2 is where the slope turns from falling to rising (NaN input finds none).
        rising = np.diff(y) >= 0.0
        minima = np.flatnonzero(rising[1:] > rising[:-1]).tolist()  # index i - 1 of each minimum i
        if not minima:
            return []
        yl = y.tolist()
        step = self.step_rad
        found = []
        for j in minima:
            i = j + 1
            y0, y1, y2 = yl[j], yl[i], yl[i + 1]
            curv = y0 - 2.0 * y1 + y2  # > 0 at a minimum
            if curv <= 0.0:
                continue
            p = 0.5 * (y0 - y2) / curv  # vertex, in grid steps from i (|p| <= 0.5)
            depth = y1 - 0.25 * (y0 - y2) * p
            gamma = 0.5 * curv / (step * step)  # d2y/dw2 / 2
            if depth / gamma < self._max_depth_ratio:
                found.append((i + p) * step * self._to_hz)
        return found


def pick_f1_f2(freqs: list[float], f1_range: tuple[float, float], f2_range: tuple[float, float],
               min_gap_hz: float) -> tuple[float, float]:
    """F1 = lowest resonance in the F1 range; F2 = the next one at least `min_gap_hz` above it."""
    f1 = math.nan
    for f in freqs:
        if f1_range[0] <= f <= f1_range[1]:
            f1 = float(f)
            break
    floor = f2_range[0] if math.isnan(f1) else max(f2_range[0], f1 + min_gap_hz)
    f2 = math.nan
    for f in freqs:
        if floor <= f <= f2_range[1]:
            f2 = float(f)
            break
    return f1, f2


class FeatureExtractor:
    """Computes `BlockFeatures` for consecutive blocks of one signal; holds the analysis window.

    The blocks that arrive together are analysed together (`blocks`): their windows, spectra and band sums in a
    few array operations instead of a dozen small ones per block, whose fixed cost was most of a block's time.
    Every reduction runs row by row, so a block's features are the same bits however the signal was cut.
    """

    def __init__(self, sample_rate: int, *, window_s: float, preemphasis: float, lpc_order: int,
                 lpc_band_hz: float, high_cut_hz: float, low_cut_hz: float, max_bandwidth_hz: float,
                 f1_range_hz: tuple[float, float], f2_range_hz: tuple[float, float],
                 formant_gap_hz: float, lag_window_hz: float, contour_bandwidth_hz: float = 0.0) -> None:
        self.sample_rate = int(sample_rate)
        self.window_len = max(16, round(window_s * sample_rate))
        # Only the first lpc_order lags of the band-limited autocorrelation are used, so the FFT need
        # only be long enough that those lags do not wrap around (circular correlation).
        decimation = int(np.ceil(sample_rate / (2.0 * min(lpc_band_hz, 0.5 * sample_rate))))
        self.nfft = fast_fft_size(self.window_len + (lpc_order + 1) * decimation)
        self.window = np.hamming(self.window_len)
        self.preemphasis = float(preemphasis)
        self.lpc_order = int(lpc_order)
        self.max_bandwidth_hz = float(max_bandwidth_hz)
        self.f1_range = f1_range_hz
        self.f2_range = f2_range_hz
        self.formant_gap_hz = float(formant_gap_hz)
        bin_hz = sample_rate / self.nfft
        nyquist_bin = self.nfft // 2
        self.lpc_bins = min(nyquist_bin, max(self.lpc_order + 2, int(lpc_band_hz / bin_hz)))
        self.lpc_rate_hz = 2.0 * self.lpc_bins * bin_hz
        self.high_bin = min(nyquist_bin, int(np.ceil(high_cut_hz / bin_hz)))
        self.low_bin = max(1, int(low_cut_hz / bin_hz))
        # A Gaussian lag window widens every resonance by ~lag_window_hz, so a pitch harmonic that falls
        # on a formant cannot pull a root onto the unit circle.
        lags = np.arange(self.lpc_order + 1)
        lag_window = np.exp(-0.5 * (2.0 * np.pi * lag_window_hz * lags / self.lpc_rate_hz) ** 2)
        # The few lags needed are a cosine transform of the band's power spectrum: one small matrix
        # product instead of an inverse FFT (what irfft would compute at those lags, up to a constant).
        k = np.arange(self.lpc_bins + 1)
        edge = np.where((k == 0) | (k == self.lpc_bins), 1.0, 2.0)
        self._lag_basis = (lag_window[:, None] * edge[None, :]
                           * np.cos(np.pi * lags[:, None] * k[None, :] / self.lpc_bins))
        self._psd = np.zeros((1, self.nfft // 2 + 1))  # the power spectra of the blocks last analysed, by row
        # Band balance is judged on the raw spectrum: weights that undo the pre-emphasis filter's gain.
        w = np.linspace(0.0, np.pi, nyquist_bin + 1)
        self._deemphasis = 1.0 / np.maximum(1.0 + preemphasis**2 - 2.0 * preemphasis * np.cos(w), 1e-6)
        self._deemphasis[0] = 0.0
        # All four band sums of a block as one matrix-vector product: total, high band, raw low, raw total.
        bins = np.arange(nyquist_bin + 1)
        self._band_sums = np.stack([
            (bins >= 1).astype(float),
            (bins >= self.high_bin).astype(float),
            np.where(bins <= self.low_bin, self._deemphasis, 0.0),
            self._deemphasis,
        ])
        self._toeplitz = np.abs(lags[:-1, None] - lags[None, :-1])
        # 25 Hz steps: a parabola through three samples then places a peak within a few Hz.
        self._peaks = SpectrumPeaks(self.lpc_order, self.lpc_rate_hz, f2_range_hz[1] + 200.0, 25.0,
                                    max_bandwidth_hz, contour_bandwidth_hz)
        # Raw history: the last window_len samples (plus one for pre-emphasis) end at the block's end.
        self._history = np.zeros(self.window_len + 1)
        self._span = np.arange(self.window_len + 1)
        self._formants: dict[int, tuple[float, float]] = {}  # by row of _psd, once asked for

    def reset(self) -> None:
        self._history[:] = 0.0
        self._formants = {}

    def blocks(self, samples: np.ndarray, starts: Sequence[int]) -> list[BlockFeatures]:
        """The features of the next blocks: block j is samples[starts[j]:starts[j + 1]], the last ending with
        `samples` (starts ascending, the first 0, each block at least one sample). `formants(j)` then gives block
        j's formants."""
        n_blocks = len(starts)
        x = np.asarray(samples, dtype=float)
        if n_blocks == 0 or starts[0] != 0 or len(x) <= starts[-1] or any(
                b <= a for a, b in zip(starts, starts[1:], strict=False)):
            raise ValueError("blocks: starts must begin at 0 and rise, each block a sample at least")
        hist = self._history
        span = len(hist)
        signal = np.concatenate((hist, x))
        ends = [*starts[1:], len(x)]
        # each block's window: the span of samples ending at its end (one more for the pre-emphasis), which in
        # `signal` (the history before x) starts at the block's end in x; a lone block's is the tail, sliced
        windows = signal[None, -span:] if n_blocks == 1 else signal[np.array(ends)[:, None] + self._span]
        hist[:] = signal[-span:]
        power = [float(np.dot(x[a:b], x[a:b])) / (b - a) for a, b in zip(starts, ends, strict=True)]

        emphasised = windows[:, 1:] - self.preemphasis * windows[:, :-1]
        emphasised *= self.window
        spectrum = np.fft.rfft(emphasised, self.nfft, axis=-1)
        psd = spectrum.real * spectrum.real
        psd += spectrum.imag * spectrum.imag
        sums = np.einsum("kb,jb->kj", psd, self._band_sums)  # einsum's loops, not BLAS: row by row, in one order
        self._psd = psd
        self._formants = {}
        return [BlockFeatures(10.0 * math.log10(p + _EPS), high / (total + _EPS), raw_low / (raw_total + _EPS))
                for p, (total, high, raw_low, raw_total) in zip(power, sums.tolist(), strict=True)]

    def formants(self, j: int) -> tuple[float, float]:
        """F1 and F2 (Hz, NaN when absent) of block j of the last `blocks` call.

        Separate from `blocks` because it costs most of the time and only vowel-like and murmur-like
        blocks need it; computed at most once per block, one block at a time (a block's own matrix-vector
        products, so its formants do not depend on the blocks analysed with it).
        """
        found = self._formants.get(j)
        if found is None:
            found = self._formants[j] = self._compute_formants(self._psd[j])
        return found

    def _compute_formants(self, psd: np.ndarray) -> tuple[float, float]:
        r = self._lag_basis @ psd[: self.lpc_bins + 1]
        if r[0] <= _EPS:
            return np.nan, np.nan
        a = lpc_solve(r, self._toeplitz)
        if a is None:
            return np.nan, np.nan
        return pick_f1_f2(self._peaks(a), self.f1_range, self.f2_range, self.formant_gap_hz)
