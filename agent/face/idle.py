"""Idle noise: small, smooth, seeded Perlin motion that keeps a resting face alive (Perlin's
ResponsiveFace "noise" button). An action meant for an additive layer on top of the others."""

from __future__ import annotations

import numpy as np

from agent.clock import seconds
from agent.face.flexors import FLEXOR_INDEX, FLEXOR_NAMES, N_FLEXORS
from agent.noise import perlin1d


def _pair_streams() -> np.ndarray:
    """One noise stream per flexor; the left and right of a pair share one, so they move together."""
    streams = np.arange(N_FLEXORS, dtype=np.int64)
    for name in FLEXOR_NAMES:
        if name.endswith("_r") and name[:-2] + "_l" in FLEXOR_INDEX:
            streams[FLEXOR_INDEX[name]] = FLEXOR_INDEX[name[:-2] + "_l"]
    return streams


_STREAMS = _pair_streams()
# Noise is zero at integer lattice points; a per-stream offset keeps flexors from all passing through
# zero at the same instants.
_PHASE = (np.arange(N_FLEXORS) * 0.618034) % 1.0


class IdleNoise:
    """amplitude[i] * perlin1d(rate_hz * t) per flexor; "do not care" where the amplitude is 0."""

    def __init__(self, amplitude: np.ndarray, rate_hz: float, seed: int = 0) -> None:
        amplitude = np.array(amplitude, dtype=np.float64)
        if amplitude.shape != (N_FLEXORS,) or np.any(~np.isfinite(amplitude)) or np.any(amplitude < 0):
            raise ValueError(f"idle-noise amplitudes need shape ({N_FLEXORS},), finite and >= 0")
        if not np.isfinite(rate_hz) or rate_hz < 0:
            raise ValueError(f"idle-noise rate must be a finite number of Hz >= 0, got {rate_hz!r}")
        self.amplitude = amplitude
        self.rate_hz = float(rate_hz)
        self.seed = int(seed)
        self._active = amplitude > 0

    def values_at(self, t_ns: int) -> np.ndarray:
        phase = self.rate_hz * seconds(t_ns) + _PHASE[_STREAMS]
        noise = perlin1d(phase, self.seed, _STREAMS)
        return np.where(self._active, self.amplitude * noise, np.nan)
