"""Per-agent state as rows of an int64 matrix, and the counter-based draws read from them.

The gaze engine keeps the state an event reads or writes as one row per agent (float fields as their bit
patterns), so an event batch gathers its agents' rows once and scatters them back once: with a million
agents, random access to per-agent state, not arithmetic, sets the tick time. These helpers are the
layout's machinery, shared by the engine's Eyes Alive rows and its fixational rows (fixation.py).
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np

_TWO_POW_MINUS_53 = 1.0 / float(1 << 53)
_TWO_POW_MINUS_32 = 1.0 / float(1 << 32)
_COUNTER_STEPS = np.arange(8, dtype=np.uint64)  # a draw of k uniforms reads counters c .. c + k - 1
CACHE_LINE = 64
# np.rad2deg's own factor: multiplying by it gives rad2deg's results bit for bit, many times faster (numpy
# runs rad2deg through a scalar loop).
DEGREES_PER_RADIAN = 180.0 / math.pi


def splitmix64_inplace(z: np.ndarray, scratch: np.ndarray) -> None:
    """counter_rng.splitmix64 on a uint64 array in place (array arithmetic wraps without warnings)."""
    z += np.uint64(0x9E3779B97F4A7C15)
    np.right_shift(z, np.uint64(30), out=scratch)
    z ^= scratch
    z *= np.uint64(0xBF58476D1CE4E5B9)
    np.right_shift(z, np.uint64(27), out=scratch)
    z ^= scratch
    z *= np.uint64(0x94D049BB133111EB)
    np.right_shift(z, np.uint64(31), out=scratch)
    z ^= scratch


def uniform_draws(counters: np.ndarray, keys: np.ndarray, count: int) -> np.ndarray:
    """`count` uniforms in [0, 1) per agent from its stream's counters c .. c + count - 1 (uint64 counters and
    keys): shape (count, agents), so each draw is one contiguous row. Bit for bit counter_rng.uniform01."""
    z = _streams(counters, keys, count)
    splitmix64_inplace(z, scratch := np.empty_like(z))
    np.right_shift(z, np.uint64(11), out=scratch)
    # As int64 (the same values below 2**53), which numpy converts to float faster than uint64: exactly.
    return np.multiply(scratch.view(np.int64), _TWO_POW_MINUS_53)


def uniform_halves(counters: np.ndarray, keys: np.ndarray, hashes: int) -> np.ndarray:
    """2 * `hashes` uniforms in [0, 1) per agent, two from each 64-bit hash of counters c .. c + hashes - 1:
    row j is the high 32 bits of hash j, row hashes + j its low 32 bits. Half the hashing of uniform_draws,
    for draws that need no more than 32 bits (a choice, a table look-up, an interval's exponential)."""
    z = _streams(counters, keys, hashes)
    splitmix64_inplace(z, scratch := np.empty_like(z))
    out = np.empty((2 * hashes, z.shape[1]))
    np.right_shift(z, np.uint64(32), out=scratch)
    np.multiply(scratch.view(np.int64), _TWO_POW_MINUS_32, out=out[:hashes])  # int64: see uniform_draws
    z &= np.uint64(0xFFFFFFFF)
    np.multiply(z.view(np.int64), _TWO_POW_MINUS_32, out=out[hashes:])
    return out


def _streams(counters: np.ndarray, keys: np.ndarray, count: int) -> np.ndarray:
    """The hash inputs (counter + j) ^ key for j < count, shape (count, agents). Counters and keys are
    usually columns of a row matrix: copied to contiguous arrays first, each is read once instead of once
    per row of the result."""
    z = np.ascontiguousarray(counters) + _COUNTER_STEPS[:count, None]
    z ^= np.ascontiguousarray(keys)
    return z


def float_bits(values: np.ndarray | float) -> np.ndarray:
    """Float64 values as the int64 bit patterns a row stores."""
    return np.asarray(values, dtype=np.float64).view(np.int64)


def aligned_rows(count: int, width: int) -> np.ndarray:
    """An uninitialised (count, width) int64 matrix that starts on a cache line boundary."""
    words = CACHE_LINE // 8
    buffer = np.empty(count * width + words, np.int64)
    start = (-buffer.ctypes.data % CACHE_LINE) // 8
    return buffer[start : start + count * width].reshape(count, width)


@cache
def _row_dtype(width: int) -> np.dtype:
    return np.dtype((np.void, width * 8))


def as_rows(matrix: np.ndarray) -> np.ndarray:
    """A C-contiguous row matrix as a 1-D array of whole rows: indexing it copies rows by memcpy, several
    times faster than numpy's general fancy indexing of 2-D arrays (np.take is the fast gather)."""
    return matrix.view(_row_dtype(matrix.shape[1])).reshape(-1)


def scatter_rows(matrix: np.ndarray, indices: np.ndarray, rows: np.ndarray) -> None:
    """matrix[indices] = rows for C-contiguous row matrices: np.put of whole rows (void views), about a
    third faster than the same assignment by index."""
    np.put(as_rows(matrix), indices, as_rows(rows))


def column_pair(matrix: np.ndarray, rows: np.ndarray, first: int, second: int) -> tuple[np.ndarray, np.ndarray]:
    """Two columns of the given rows of a C-contiguous row matrix: np.take on flat offsets, cheaper per
    element than 2-D fancy indexing, and reading only the lines that hold them."""
    flat = matrix.reshape(-1)
    offsets = rows * matrix.shape[1]
    offsets += first
    a = flat.take(offsets)
    offsets += second - first
    return a, flat.take(offsets)


def stream_keys(stream_seed: int, agents: np.ndarray) -> np.ndarray:
    """The per-agent keys counter_rng.hash3 derives for (stream seed, stream = agent index), as int64 bits."""
    from agent.counter_rng import splitmix64

    return splitmix64(splitmix64(np.uint64(stream_seed)) ^ agents.astype(np.uint64)).view(np.int64)


def grow_rows(rows: np.ndarray, count: int, added: np.ndarray) -> np.ndarray:
    """`rows` (count rows) with `added` appended, in a fresh aligned matrix."""
    grown = aligned_rows(count + added.shape[0], rows.shape[1])
    grown[:count] = rows[:count]
    grown[count:] = added
    return grown
