"""The gaze engine's memory layout: per-agent state as rows of an int64 matrix, and the machinery to read it.

The gaze engine keeps the state an event reads or writes as one row per agent (float fields as their bit
patterns), so an event batch gathers its agents' rows once and scatters them back once: with a million
agents, random access to per-agent state, not arithmetic, sets the tick time. Here are the engine's row
columns, cache-line aligned row matrices, whole-row gathers and scatters, the counter-based draws read
from a row's key and counter, the hold tables laid out for one cache line per draw, and the packed sort of
a tick's onsets; the fixational rows (fixation.py) share the machinery.
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np

from eca.agent.counter_rng import splitmix64_inplace, stream_key
from eca.agent.gaze.generator import HOLD_TABLE_INTERVALS, hold_quantiles
from eca.agent.gaze.params import ROLES, GazeParams


def operand(value: float, dtype: type[np.generic] = np.float64) -> np.ndarray:
    """A constant operand of the batches' arithmetic as a 0-d array: numpy converts a Python or numpy scalar
    on every call (about half a microsecond, much of a call on a few thousand agents), an array it takes as
    it is. Of the dtype the scalar would have had, so every result keeps its dtype and value."""
    return np.array(value, dtype=dtype)


_TWO_POW_MINUS_53 = operand(1.0 / float(1 << 53))
_TWO_POW_MINUS_32 = operand(1.0 / float(1 << 32))
_COUNTER_STEPS = np.arange(8, dtype=np.uint64)  # a draw of k uniforms reads counters c .. c + k - 1
_MANTISSA_SHIFT, _HALF_BITS, _LOW_HALF = operand(11, np.uint64), operand(32, np.uint64), operand(0xFFFFFFFF, np.uint64)
CACHE_LINE = 64
# np.rad2deg's own factor: multiplying by it gives rad2deg's results bit for bit, many times faster (numpy
# runs rad2deg through a scalar loop).
DEGREES_PER_RADIAN = 180.0 / math.pi

# Columns of the engine's per-agent row matrix; float fields hold float64 bit patterns. The current saccade
# comes first, so its compact copy for the eyes in flight is one slice of the row. Each cache line of a row
# (eight columns) serves one kind of access: the first holds the saccade, the second the timers and
# everything a blink reads or writes (a blink touches its row nowhere else, and the timers that say which
# event is due sit in the line it then works on), the third what only a decision reads.
(
    ONSET, END, FROM_YAW, FROM_PITCH, TO_YAW, TO_PITCH, KIND, MODE,
    NEXT_SACCADE, NEXT_BLINK, COUNTER_BLINK, KEY_BLINK, BLINK_SPREAD_NS, BLINK_ONSET, COUNTER_SACCADE, KEY_SACCADE,
    ROLE, HOLD_BASE, TARGET_YAW, TARGET_PITCH, P_MUTUAL, MAG_SPAN, MAG_SCALE, INTERVAL_SCALE,
) = range(24)  # fmt: skip
# 24 columns are 192 bytes, three whole cache lines when the matrix starts on a line (aligned_rows): a
# 23-column row straddles four lines at most offsets, and the rows an event batch gathers and scatters
# back are the bulk of a tick's random memory traffic. The latest blink onset rides in the row, written
# with the rest of it, instead of costing a random write of its own per blink.
N_COLUMNS = 24
assert len({c // 8 for c in (NEXT_SACCADE, NEXT_BLINK, COUNTER_BLINK, KEY_BLINK, BLINK_SPREAD_NS, BLINK_ONSET)}) == 1
# The compact copy of a saccade in flight (inflight.Flights): onset, end, from yaw, from pitch, to yaw, to pitch.
FLIGHT = slice(ONSET, TO_PITCH + 1)
# The hold tables (hold_table) have one row per (role, mutual/away); HOLD_BASE is the agent's role's first.
HOLD_ROW = HOLD_TABLE_INTERVALS + 1


def row_uniforms(rows: np.ndarray, key: int, counter: int, count: int) -> np.ndarray:
    """`count` uniforms in [0, 1) per row from the agent's own stream, its key and counter in the given
    columns: shape (count, len(rows)), so each draw is one contiguous row and the broadcasts run along the
    agents, not along a few draws. Bit for bit counter_rng.uniform01(stream seed, agent index, counter); the
    rows' counters advance by `count`."""
    u = uniform_draws(rows[:, counter].view(np.uint64), rows[:, key].view(np.uint64), count)
    rows[:, counter] += count
    return u


def hold_table(params: GazeParams) -> np.ndarray:
    """The quantile tables of the six (role, mutual/away) hold distributions (generator.hold_quantiles), one
    row each, raveled: per quantile a pair (step to the next quantile, quantile), as the interpolation reads
    value + fraction * step. Side by side, a draw reads one cache line of the table instead of one in each of
    two."""
    quantiles = np.concatenate([hold_quantiles(params, role, away) for role in ROLES for away in (False, True)])
    return np.stack([np.append(np.diff(quantiles), 0.0), quantiles], axis=1)


def hashes(counters: np.ndarray, keys: np.ndarray, count: int) -> np.ndarray:
    """The `count` 64-bit hashes per agent of its stream's counters c .. c + count - 1 (int64 or uint64
    counters and keys, usually columns of a row matrix), as uint64 of shape (count, agents): the bits behind
    counter_rng.uniform01, for callers that read them another way than uniform_draws and uniform_halves."""
    z = _streams(counters.view(np.uint64), keys.view(np.uint64), count)
    splitmix64_inplace(z, np.empty_like(z))
    return z


def uniform_draws(counters: np.ndarray, keys: np.ndarray, count: int) -> np.ndarray:
    """`count` uniforms in [0, 1) per agent from its stream's counters c .. c + count - 1 (uint64 counters and
    keys): shape (count, agents), so each draw is one contiguous row. Bit for bit counter_rng.uniform01."""
    z = _streams(counters, keys, count)
    splitmix64_inplace(z, scratch := np.empty_like(z))
    np.right_shift(z, _MANTISSA_SHIFT, out=scratch)
    # As int64 (the same values below 2**53), which numpy converts to float faster than uint64: exactly.
    return np.multiply(scratch.view(np.int64), _TWO_POW_MINUS_53)


def uniform_halves(counters: np.ndarray, keys: np.ndarray, hashes: int) -> np.ndarray:
    """2 * `hashes` uniforms in [0, 1) per agent, two from each 64-bit hash of counters c .. c + hashes - 1:
    row j is the high 32 bits of hash j, row hashes + j its low 32 bits. Half the hashing of uniform_draws,
    for draws that need no more than 32 bits (a choice, a table look-up, an interval's exponential)."""
    z = _streams(counters, keys, hashes)
    splitmix64_inplace(z, scratch := np.empty_like(z))
    out = np.empty((2 * hashes, z.shape[1]))
    np.right_shift(z, _HALF_BITS, out=scratch)
    np.multiply(scratch.view(np.int64), _TWO_POW_MINUS_32, out=out[:hashes])  # int64: see uniform_draws
    z &= _LOW_HALF
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
    """matrix[indices] = rows for C-contiguous row matrices: a put of whole rows (void views), about a
    third faster than the same assignment by index."""
    as_rows(matrix).put(indices, as_rows(rows))


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
    return stream_key(stream_seed, agents).view(np.int64)


def grow_rows(rows: np.ndarray, count: int, added: np.ndarray) -> np.ndarray:
    """`rows` (count rows) with `added` appended, in a fresh aligned matrix."""
    grown = aligned_rows(count + added.shape[0], rows.shape[1])
    grown[:count] = rows[:count]
    grown[count:] = added
    return grown


def write_eyes(eyes: np.ndarray, agents: np.ndarray, yaw: np.ndarray, pitch: np.ndarray) -> None:
    """eyes[agents] = yaw, pitch, for the engine's eye state (C-contiguous rows of yaw and pitch).

    Each agent's yaw and pitch are copied as one 16-byte element into its row: one pass of random writes
    instead of two, with the pair interleaved first (a sequential pass); 2-D fancy indexing would take
    numpy's slow general path."""
    pairs = np.empty((agents.size, 2))
    pairs[:, 0] = yaw
    pairs[:, 1] = pitch
    eyes.view(_PAIR)[:, 0][agents] = pairs.view(_PAIR)[:, 0]


_PAIR = np.dtype((np.void, 16))


def read_only(values: np.ndarray) -> np.ndarray:
    """A read-only view: a tick hands out the state it keeps this way."""
    view = values.view()
    view.flags.writeable = False
    return view


def onset_order(agent: np.ndarray, onset: np.ndarray, n_agents: int) -> np.ndarray:
    """The order that sorts onsets by (onset, agent), ties kept in the order given: np.lexsort((agent, onset))."""
    return sort_onsets(agent, onset, n_agents)[0]


def sort_onsets(agent: np.ndarray, onset: np.ndarray, n_agents: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The order that sorts onsets by (onset, agent), ties kept in the order given (np.lexsort((agent, onset))),
    and the agents and onsets in that order.

    The three keys packed into the bits of one int64, (onset - first, agent, position), so that a sort of
    the values (several times faster than an argsort, and than the two-key stable sort) leaves the order in
    the low bits, and the sorted agents and onsets above them (no gathers); used whenever the three fit in
    63 bits (a tick's onsets span milliseconds). The keys are unique (the position is one of them), so any
    sort gives this one order: see _sort_keys for the one used."""
    if agent.size >= 512:  # below, a few numpy calls cost more than the sort
        # The ufuncs' reductions themselves: ndarray.min and .max go through Python wrappers.
        first = int(np.minimum.reduce(onset))
        span = int(np.maximum.reduce(onset)) - first
        agent_bits = max(n_agents - 1, 1).bit_length()
        position_bits = (agent.size - 1).bit_length()
        key_bits = span.bit_length() + agent_bits + position_bits
        if key_bits <= 63:
            key = onset - first
            key <<= agent_bits
            key |= agent
            key <<= position_bits
            key |= np.arange(agent.size)
            key = _sort_keys(key, key_bits)
            order = key & ((1 << position_bits) - 1)
            key >>= position_bits
            sorted_agent = key & ((1 << agent_bits) - 1)
            key >>= agent_bits
            key += first
            return order, sorted_agent, key
    order = np.lexsort((agent, onset))
    return order, agent.take(order), onset.take(order)


def _sort_keys(key: np.ndarray, key_bits: int) -> np.ndarray:
    """Non-negative int64 keys below 2**key_bits, sorted (`key` may be reused).

    numpy's comparison sort of int64 costs about 40 ns a key here (a tick's 50,000 onsets: 2 ms). Its
    stable sort of 16-bit keys is a radix sort, linear; and its stable sort of int64 is timsort, linear on
    data in long runs. So: order the keys by their top 16 bits (a bucket each), then let timsort finish
    the few keys out of order within a bucket. Several times faster on a tick's onsets, which spread
    over the buckets; on keys that crowd into a few buckets it is timsort's n log n, still exact."""
    if key_bits <= 16:
        key.sort(kind="stable")
        return key
    bucket = (key >> (key_bits - 16)).astype(np.uint16)
    key = key.take(np.argsort(bucket, kind="stable"))
    key.sort(kind="stable")
    return key
