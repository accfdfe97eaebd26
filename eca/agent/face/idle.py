"""Idle noise: small, smooth, seeded Perlin motion that keeps a resting face alive (Perlin's
ResponsiveFace "noise" button). An action meant for an additive layer on top of the others."""

from __future__ import annotations

import numpy as np

from eca.agent.clock import seconds
from eca.agent.counter_rng import stream_key, uniform01_keyed
from eca.agent.face.flexors import FLEXOR_INDEX, FLEXOR_NAMES, N_FLEXORS


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


class _Gradients:
    """The lattice gradients of noise streams (`keys`: stream_key per flexor, one row per face or a single row),
    kept between evaluations, and the noise at a phase (agent.noise.perlin1d, the same arithmetic step for step).

    The gradients change only when a flexor's phase crosses an integer (every few seconds at idle rates), and hashing
    them is most of perlin1d's cost. Each flexor's phase has its own offset, so one or another crosses an integer
    several times a second: only those get new gradients, and one that stepped to the next cell keeps its old g1 as
    its g0. The hash of (seed, stream) is kept: a gradient is then one splitmix64 of its counter."""

    def __init__(self, keys: np.ndarray) -> None:
        self.keys = keys
        self._lattice: np.ndarray | None = None  # the integer parts the gradients belong to
        self._g0 = self._g1 = np.zeros(keys.shape)

    def noise(self, x: np.ndarray) -> np.ndarray:
        """The noise of every stream at phases `x` (one per flexor): keys' shape."""
        i0 = np.floor(x)
        if self._lattice is None:
            lattice = i0.astype(np.int64).astype(np.uint64)
            self._g0 = uniform01_keyed(self.keys, lattice) * 2.0 - 1.0
            self._g1 = uniform01_keyed(self.keys, lattice + np.uint64(1)) * 2.0 - 1.0
            self._lattice = i0
        elif (moved := np.flatnonzero(i0 != self._lattice)).size:
            lattice = i0[moved].astype(np.int64).astype(np.uint64)
            stepped = i0[moved] == self._lattice[moved] + 1.0
            self._g0[..., moved[stepped]] = self._g1[..., moved[stepped]]
            jumped = moved[~stepped]
            if jumped.size:
                self._g0[..., jumped] = uniform01_keyed(self.keys[..., jumped], lattice[~stepped]) * 2.0 - 1.0
            self._g1[..., moved] = uniform01_keyed(self.keys[..., moved], lattice + np.uint64(1)) * 2.0 - 1.0
            self._lattice = i0
        f = x - i0
        n0 = self._g0 * f
        n1 = self._g1 * (f - 1.0)
        fade = f * f * f * (f * (f * 6.0 - 15.0) + 10.0)
        return 2.0 * (n0 + fade * (n1 - n0))


class IdleNoise:
    """amplitude[i] * perlin1d(rate_hz * t) per flexor; "do not care" where the amplitude is 0.

    The noise is agent.noise.perlin1d, evaluated here with its lattice gradients kept between frames:
    they change only when the phase crosses an integer (every few seconds at idle rates), and hashing
    them is most of perlin1d's cost.
    """

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
        self._active_index = np.flatnonzero(self._active)
        self._active_amplitude = amplitude[self._active_index]
        self._offset = _PHASE[_STREAMS]
        self._keys = stream_key(self.seed, _STREAMS)
        self._gradients = _Gradients(self._keys)

    def values_at(self, t_ns: int) -> np.ndarray:
        phase = self.rate_hz * seconds(t_ns) + self._offset
        noise = self._perlin(phase)
        return np.where(self._active, self.amplitude * noise, np.nan)

    def sparse_at(self, t_ns: int) -> tuple[np.ndarray, np.ndarray] | None:
        if not self._active_index.size:
            return None
        noise = self._perlin(self.rate_hz * seconds(t_ns) + self._offset)
        return self._active_index, self._active_amplitude * noise[self._active_index]

    def _perlin(self, x: np.ndarray) -> np.ndarray:
        """perlin1d(x, self.seed, _STREAMS), the same arithmetic step for step."""
        return self._gradients.noise(x)


class IdleNoiseBatch:
    """The idle noise of many faces at one instant, as one array: IdleNoise.sparse_at of each, element for element
    the same arithmetic. It takes noises of one rate and one set of amplitudes (one face configuration; `fits`):
    their phases are then the same, so their lattice cells change at the same instants and only the gradients,
    hashed from each face's seed, differ by row. It keeps those gradients between calls, as IdleNoise does."""

    def __init__(self) -> None:
        self._noises: list[IdleNoise] = []
        self._fit = True  # whether _noises fit one batch
        self._gradients = _Gradients(np.zeros((0, N_FLEXORS), dtype=np.uint64))

    def fits(self, noises: list[IdleNoise]) -> bool:
        """Whether these noises (at least one) can be evaluated as one batch: one rate, the same amplitudes. Worked
        out again only when they are not the noises of the last call."""
        if len(noises) != len(self._noises) or any(a is not b for a, b in zip(noises, self._noises, strict=True)):
            first = noises[0]
            self._noises = list(noises)
            self._fit = all(n.rate_hz == first.rate_hz and np.array_equal(n.amplitude, first.amplitude)
                            for n in noises[1:])
            self._gradients = _Gradients(np.stack([n._keys for n in noises]))
        return self._fit

    def sparse_at(self, noises: list[IdleNoise], t_ns: int) -> tuple[np.ndarray, np.ndarray] | None:
        """(active flexors (k,), values (N, k)) of `noises` (which `fits`) at t_ns, or None where none is active."""
        if not self.fits(noises):
            raise ValueError("idle noises of different rates or amplitudes cannot be evaluated as one batch")
        first = noises[0]
        if not first._active_index.size:
            return None
        noise = self._gradients.noise(first.rate_hz * seconds(t_ns) + first._offset)
        index = first._active_index
        return index, first._active_amplitude * noise[:, index]
