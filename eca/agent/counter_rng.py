"""Counter-based random numbers: a splitmix64 hash of (seed, stream, counter), computed on whole arrays.

Every agent gets its own reproducible stream without one generator object per agent, so adding an
agent never changes another agent's draws (docs/gaze.md: many agents in arrays, each its own stream).
"""

from __future__ import annotations

import numpy as np

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_INV_2_53 = 1.0 / float(1 << 53)
# The same constants and the shifts as 0-d arrays for splitmix64_inplace: numpy converts a scalar operand on
# every call (about half a microsecond), an array it takes as it is; the engine hashes a few batches a tick.
_GOLDEN_0D, _MIX1_0D, _MIX2_0D = (np.array(v, dtype=np.uint64) for v in (_GOLDEN, _MIX1, _MIX2))
_SHIFT_30, _SHIFT_27, _SHIFT_31 = (np.array(v, dtype=np.uint64) for v in (30, 27, 31))


def splitmix64(x: np.ndarray | np.uint64) -> np.ndarray:
    """The splitmix64 finaliser applied elementwise to uint64 values (wrapping arithmetic)."""
    z = np.asarray(x, dtype=np.uint64)
    with np.errstate(over="ignore"):
        z = z + _GOLDEN
        z = (z ^ (z >> np.uint64(30))) * _MIX1
        z = (z ^ (z >> np.uint64(27))) * _MIX2
    return z ^ (z >> np.uint64(31))


def splitmix64_inplace(z: np.ndarray, scratch: np.ndarray) -> None:
    """splitmix64 on a uint64 array in place, with `scratch` (same shape) for the shifts: no temporaries,
    for the engine's batches (array arithmetic wraps without warnings)."""
    z += _GOLDEN_0D
    np.right_shift(z, _SHIFT_30, out=scratch)
    z ^= scratch
    z *= _MIX1_0D
    np.right_shift(z, _SHIFT_27, out=scratch)
    z ^= scratch
    z *= _MIX2_0D
    np.right_shift(z, _SHIFT_31, out=scratch)
    z ^= scratch


def stream_key(seed: int, stream: np.ndarray | int) -> np.ndarray:
    """The per-stream key of hash3: hash3(seed, stream, counter) = splitmix64(stream_key(seed, stream) ^ counter)."""
    s = splitmix64(np.uint64(seed & 0xFFFFFFFFFFFFFFFF))
    return splitmix64(s ^ np.asarray(stream, dtype=np.uint64))


def hash3(seed: int, stream: np.ndarray | int, counter: np.ndarray | int) -> np.ndarray:
    """A 64-bit hash of (seed, stream, counter); broadcasts stream and counter like numpy does."""
    return splitmix64(stream_key(seed, stream) ^ np.asarray(counter, dtype=np.uint64))


def uniform01(seed: int, stream: np.ndarray | int, counter: np.ndarray | int) -> np.ndarray:
    """Uniform doubles in [0, 1) from the top 53 bits of the hash."""
    return uniform01_keyed(stream_key(seed, stream), counter)


def uniform01_keyed(key: np.ndarray, counter: np.ndarray | int) -> np.ndarray:
    """uniform01 from streams' keys kept (stream_key(seed, stream)): one splitmix64 a draw instead of three."""
    return (splitmix64(key ^ np.asarray(counter, dtype=np.uint64)) >> np.uint64(11)).astype(np.float64) * _INV_2_53
