"""Streaming sample-rate conversion with a Kaiser-windowed sinc, numpy only.

Output sample j sits exactly at input time j * in_rate / out_rate (no delay): the converter waits for
`half_width` input samples of look-ahead and `flush` supplies trailing zeros. Chunked input gives the
same output as one call with the whole signal, so streamed and file audio sound the same.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np


class Resampler:
    def __init__(self, in_rate: int, out_rate: int, half_width: int = 16, beta: float = 8.0,
                 max_chunk: int = 8192) -> None:
        if in_rate <= 0 or out_rate <= 0:
            raise ValueError(f"sample rates must be positive, got {in_rate} -> {out_rate}")
        self.in_rate = int(in_rate)
        self.out_rate = int(out_rate)
        self.step = Fraction(self.in_rate, self.out_rate)  # input samples per output sample
        # Downsampling widens the kernel (in input samples) so the cut-off follows the output Nyquist.
        self.scale = min(1.0, self.out_rate / self.in_rate)
        self.half = int(np.ceil(half_width / self.scale))
        self.beta = beta
        self.max_chunk = max_chunk
        self._buf = np.zeros(self.half, dtype=np.float64)  # zeros before the signal
        self._buf_start = -self.half  # input index of _buf[0]
        self._next_out = 0  # index of the next output sample
        self._flushed = False
        # Polyphase table: output positions repeat their fractional part with period `den`, so for the
        # usual rate pairs (22050 -> 48000: 320 phases) every kernel is computed once.
        den = self.step.denominator
        self._table: np.ndarray | None = None
        if den <= 4096 and not self.passthrough:
            self._table = self._kernel(np.arange(den) / den)

    @property
    def passthrough(self) -> bool:
        return self.in_rate == self.out_rate

    def process(self, chunk: np.ndarray) -> np.ndarray:
        x = np.asarray(chunk, dtype=np.float64).reshape(-1)
        if self.passthrough:
            return x.astype(np.float32)
        if self._flushed:
            raise RuntimeError("Resampler already flushed")
        self._buf = np.concatenate((self._buf, x))
        return self._drain()

    def flush(self) -> np.ndarray:
        """End of input: emit the remaining output (up to the last input sample's time)."""
        if self.passthrough or self._flushed:
            return np.zeros(0, dtype=np.float32)
        n_in = self._buf_start + len(self._buf)  # total input samples seen
        self._buf = np.concatenate((self._buf, np.zeros(self.half + 1)))
        out = self._drain(limit_in=n_in)
        self._flushed = True
        return out

    def _drain(self, limit_in: int | None = None) -> np.ndarray:
        pieces = []
        end_in = self._buf_start + len(self._buf)
        while True:
            # Output j needs input up to floor(j * step) + half.
            last_ok = (Fraction(end_in - self.half - 1) / self.step).__floor__()
            if limit_in is not None:
                last_ok = min(last_ok, (Fraction(limit_in - 1) / self.step).__floor__())
            n = min(last_ok - self._next_out + 1, self.max_chunk)
            if n <= 0:
                break
            pieces.append(self._render(self._next_out, n))
            self._next_out += n
        # Keep only the input the next outputs can still reach.
        keep_from = (self._next_out * self.step).__floor__() - self.half
        drop = max(0, keep_from - self._buf_start)
        if drop:
            self._buf = self._buf[drop:]
            self._buf_start += drop
        if not pieces:
            return np.zeros(0, dtype=np.float32)
        return np.concatenate(pieces).astype(np.float32)

    def _render(self, first: int, n: int) -> np.ndarray:
        j = np.arange(first, first + n, dtype=np.int64)
        num, den = self.step.numerator, self.step.denominator
        base = (j * num) // den  # integer part of each output's input position
        phase = j * num - base * den
        taps = np.arange(-self.half + 1, self.half + 1)
        idx = base[:, None] + (taps[None, :] - self._buf_start)
        kernel = self._table[phase] if self._table is not None else self._kernel(phase / den)
        return np.einsum("ij,ij->i", self._buf[idx], kernel)

    def _kernel(self, frac: np.ndarray) -> np.ndarray:
        """Kernel weights for outputs whose input position has fractional part `frac` (one row each)."""
        taps = np.arange(-self.half + 1, self.half + 1)
        dist = taps[None, :] - np.asarray(frac, dtype=np.float64)[:, None]
        return self.scale * np.sinc(self.scale * dist) * _kaiser(dist / (self.half + 1), self.beta)


def _kaiser(x: np.ndarray, beta: float) -> np.ndarray:
    """Kaiser window evaluated at x in [-1, 1] (zero outside)."""
    inside = np.clip(1.0 - x * x, 0.0, None)
    return np.i0(beta * np.sqrt(inside)) / np.i0(beta)


def resample(samples: np.ndarray, in_rate: int, out_rate: int) -> np.ndarray:
    """Whole-signal conversion, identical to streaming the same samples and flushing."""
    r = Resampler(in_rate, out_rate)
    out = r.process(samples)
    return np.concatenate((out, r.flush())) if not r.passthrough else out
