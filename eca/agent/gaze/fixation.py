"""Fixational eye movements of mode saccade+noise+blink: microsaccades, drift and face scanning.

Between two Eyes Alive saccades the eye holds a fixation. In this mode the fixation is alive: small
saccades follow one another, each a microsaccade (a fraction of a degree, heading back toward the point
fixated) or, while the gaze is mutual, a scan to one of the partner's eyes or the mouth; between them the
eye drifts. Their intervals are a refractory gap plus an exponential, and each small saccade is a scan
with probability scan rate / (scan rate + microsaccade rate), so both rates hold exactly. The role sets
the scan rate and where scans go (configs/gaze.toml [face_scan]); the emotion's interval scale stretches
the intervals. Every Eyes Alive launch restarts the agent's fixation at the new landing point, so the
Eyes Alive decisions and their statistics are untouched: these movements ride on top of them.

Each agent has its own counter-based stream (the engine's fourth seed), so the fixational draws never
shift the Eyes Alive or blink draws. Per agent the state is one cache line (`_WIDTH` int64 columns); the
next event time is a dense array of its own, scanned each tick (one scan of the union with the engine's
next event times, split afterwards, measured slower: the sparse flatnonzero, not the compare, costs).
A small saccade moves the eye state in one step at its onset: it lasts 26-36 ms (main sequence), about
two frames at 60 Hz, and is reported with its onset, landing and duration, from which a renderer draws
its exact trajectory.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from statistics import NormalDist

import numpy as np

from eca.agent.gaze.params import FACE_FEATURES, KINDS, ROLES, GazeParams
from eca.agent.gaze.rows import (
    DEGREES_PER_RADIAN,
    aligned_rows,
    column_pair,
    grow_rows,
    hashes,
    operand,
    scatter_rows,
    stream_keys,
    write_eyes,
)

NEVER_NS = 1 << 62
_NS = 1_000_000_000
SCAN, MICRO = KINDS.index("scan"), KINDS.index("micro")
_N_FEATURES = len(FACE_FEATURES)
AMPLITUDE_TABLE_INTERVALS = 4096  # cells of the microsaccade amplitudes' quantile table

# Columns of the per-agent row (float fields as bit patterns). STATE packs the spread of the exponential
# part of the interval (ns, negated: see start; upper bits) with the fixation's context (low 8 bits):
# ((role * 2 + mutual) * 2 + preferred eye) * 4 + the feature fixated (0 = the gaze target itself, 1 + index
# into FACE_FEATURES).
COUNTER, KEY, OFF_YAW, OFF_PITCH, BASE_YAW, BASE_PITCH, LAST, STATE = range(8)
OFFSET = slice(OFF_YAW, OFF_PITCH + 1)
_WIDTH = 8  # 64 bytes: one cache line per agent
_STATE_BITS = 8
_STATE_MASK = (1 << _STATE_BITS) - 1
# Each small saccade draws 32-bit uniforms, two per hash, as rows.uniform_halves reads them (row j the high
# half of hash j, row 3 + j its low half): the interval (0); scan or microsaccade, and the scan's target (1);
# the microsaccade's amplitude (2) and its turn off the corrective heading (3); the drift's radius (4) and
# angle (5). A uniform that only picks a table cell is read as the integer it is (see _step).
_HASHES = 3
ANGLES = 4096  # angle tables: a 32-bit uniform picks one of this many evenly spaced angles
# The most agents one _step takes: its few dozen scratch arrays then stay in the core's cache (a million
# agents run some 40,000 small saccades a tick; in batches of this size they take about a tenth less).
_BATCH = 8192
_ANGLE_SHIFT = 32 - 12  # a 32-bit half's top 12 bits pick one of the ANGLES
_CELL_SHIFT = 32 - 12  # and one of the AMPLITUDE_TABLE_INTERVALS cells; the low 20 bits are the fraction
_CELL_FRACTION = (1 << _CELL_SHIFT) - 1
_TWO_POW_MINUS_32 = 1.0 / float(1 << 32)
_TWO_POW_MINUS_20 = 1.0 / float(1 << _CELL_SHIFT)
assert 1 << (32 - _ANGLE_SHIFT) == ANGLES and 1 << (32 - _CELL_SHIFT) == AMPLITUDE_TABLE_INTERVALS
# The constant operands of _step and start (rows.operand).
_HALF_BITS, _LOW_HALF = operand(32, np.uint64), operand(0xFFFFFFFF, np.uint64)
_MINUS_TWO_POW_MINUS_32, _FRACTION_SCALE = operand(-_TWO_POW_MINUS_32), operand(_TWO_POW_MINUS_20)
_ANGLE_SHIFT_BY, _CELL_SHIFT_BY = operand(_ANGLE_SHIFT, np.int64), operand(_CELL_SHIFT, np.int64)
_CELL_FRACTION_MASK, _STATE_MASK_BITS = operand(_CELL_FRACTION, np.int64), operand(_STATE_MASK, np.int64)
_STATE_SHIFT_BY, _HASHES_DRAWN = operand(_STATE_BITS, np.int64), operand(_HASHES, np.int64)
_FEATURE_MASK, _ONE, _TWO = (operand(v, np.int64) for v in (3, 1, 2))
_ON_POINT = operand(1e-12)
_ZERO, _FULL_TURN, _DEGREES_PER_RADIAN, _S_PER_NS = (operand(v) for v in (0.0, 360.0, DEGREES_PER_RADIAN, 1e-9))
_ONE_INT8, _SCAN_MINUS_MICRO, _MICRO = (operand(v, np.int8) for v in (1, SCAN - MICRO, MICRO))
_NS_PER_S = operand(float(_NS))


class Fixations:
    """The small saccades of every agent in mode saccade+noise+blink."""

    def __init__(self, params: GazeParams, stream_seed: int) -> None:
        fix = params.fixation
        self._stream_seed = stream_seed
        self._refractory_ns = int(round(fix.refractory_s * _NS))
        self._refractory = operand(self._refractory_ns, np.int64)
        self._refractory_float = operand(float(self._refractory_ns))
        self._d0_ns = operand(params.d0_s * _NS)
        self._d_ns_per_deg = operand(params.d_s_per_deg * _NS)
        # Per row of a (from yaw, from pitch, to yaw, to pitch) block: the eye's limits, for np.clip as two
        # calls (np.maximum, np.minimum) without its Python wrapper.
        self._limits = np.array([[params.eye_yaw_limit_deg], [params.eye_pitch_limit_deg]] * 2)
        self._lower_limits = -self._limits
        self._drift_two_d = 2.0 * fix.drift_diffusion_deg2_per_s  # per-axis variance per second
        self._drift_scale = operand(-2e-9 * self._drift_two_d)  # times the ns drifted and log1p(-u)
        self._correction = math.radians(fix.correction_spread_deg)
        # The points a fixation holds, indexed like the fixated feature: 0 the gaze target, then FACE_FEATURES.
        self._points_yaw = np.append(0.0, fix.features_deg[:, 0])
        self._points_pitch = np.append(0.0, fix.features_deg[:, 1])
        contexts = len(ROLES) * 2 * 2
        # Per (role, mutual, preferred eye): the chance that a small saccade is a scan, its mean interval
        # (s), and the cumulative chances of the scan's target. A scan draws its target by the features'
        # shares of dwell time, the one fixated included (then it re-centres on it), so the shares of time
        # on each feature are exactly those shares.
        p_scan = np.zeros(contexts)
        self._mean_s = np.zeros(contexts)
        cumulative = np.zeros((contexts, _N_FEATURES))
        for r, role in enumerate(ROLES):
            for mutual in (0, 1):
                for eye in (0, 1):
                    c = (r * 2 + mutual) * 2 + eye
                    rate = fix.event_rate_hz(role, bool(mutual))
                    self._mean_s[c] = 1.0 / rate
                    p_scan[c] = (rate - fix.microsaccade_rate_hz) / rate
                    cumulative[c] = np.cumsum(fix.feature_weights(role, eye))
        # A small saccade is a scan to feature j when its uniform is below p_scan and at or above p_scan times
        # the cumulative chance of the features before j: those products, per context. The uniform is a
        # 32-bit integer h times 2**-32, so u < p is h < ceil(p * 2**32) and u >= e is h >= ceil(e * 2**32),
        # exactly: the draw is compared as the integer, without converting it. Every table of the step is
        # indexed by the state's low bits (context, then the feature fixated), so no shift or mask picks
        # the context out of them.
        def by_state(per_context: np.ndarray) -> np.ndarray:
            return np.repeat(per_context, 4, axis=-1)

        def ceil_bits(chance: np.ndarray) -> np.ndarray:
            return np.array([math.ceil(float(p) * (1 << 32)) for p in chance], dtype=np.int64)

        self._scan_below = by_state(ceil_bits(p_scan))
        self._target_1_from = by_state(ceil_bits(p_scan * cumulative[:, 0]))
        self._target_2_from = by_state(ceil_bits(p_scan * cumulative[:, 1]))
        # The point fixated (yaw; pitch), by the state's low bits.
        self._fixated_point = np.tile(np.stack([self._points_yaw, self._points_pitch]), contexts)
        quantiles = microsaccade_quantiles(params)
        self._amplitudes, self._amplitude_steps = quantiles[:-1], np.diff(quantiles)
        angles = (np.arange(ANGLES) + 0.5) * (2.0 * np.pi / ANGLES)
        self._cos_sin = np.stack([np.cos(angles), np.sin(angles)])  # (yaw; pitch) of a unit step at each angle
        jitter = (np.arange(ANGLES) + 0.5) / ANGLES * (2.0 * self._correction) - self._correction
        self._jitter_cos_sin = np.stack([np.cos(jitter), np.sin(jitter)])
        self._n = 0
        self._rows = aligned_rows(0, _WIDTH)
        self.next_ns = np.empty(0, np.int64)  # dense: scanned every tick
        self._due = np.empty(0, bool)  # due()'s mask, kept: a fresh one per tick is a fresh megabyte at 1e6 agents
        self._chunks: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self._unwritten: list[np.ndarray] = []  # agents whose landing the eye state has yet to show

    # ------------------------------------------------------------------ agents

    def grow(self, count: int) -> None:
        new = np.arange(self._n, self._n + count, dtype=np.int64)
        rows = np.zeros((count, _WIDTH), np.int64)
        rows[:, KEY] = stream_keys(self._stream_seed, new)
        self._rows = grow_rows(self._rows, self._n, rows)
        self.next_ns = np.concatenate([self.next_ns, np.full(count, NEVER_NS, np.int64)])
        self._n += count
        self._due = np.empty(self._n, bool)

    def start(
        self,
        agents: np.ndarray,
        landing_ns: np.ndarray,
        base_yaw: np.ndarray,
        base_pitch: np.ndarray,
        mutual: np.ndarray,
        role: np.ndarray,
        interval_scale: np.ndarray,
        rows: np.ndarray | None = None,
    ) -> None:
        """A new fixation: the eyes land at `landing_ns` on (base_yaw, base_pitch), the gaze target when
        `mutual`. Pending small saccades of the old fixation are dropped; the first of the new one is drawn.
        `rows`: the agents' rows from gather(), if the caller has them (they are overwritten)."""
        if rows is None:
            rows = self._rows.take(agents, axis=0)
        floats = rows.view(np.float64)
        context = role * _TWO
        context += mutual
        context *= _TWO
        context += rows[:, KEY] & _ONE  # the preferred eye
        # The spread negated: -max(x - r, 0) is min(r - x, 0) exactly (a difference changes sign exactly; rint,
        # symmetric, gives the same integer but for the sign of a zero, which the integer drops).
        spread = self._mean_s.take(context)
        spread *= interval_scale
        spread *= _NS_PER_S
        np.subtract(self._refractory_float, spread, out=spread)
        np.minimum(spread, _ZERO, out=spread)
        np.rint(spread, out=spread)
        state = spread.astype(np.int64)
        state <<= _STATE_SHIFT_BY
        context <<= _TWO  # the feature fixated: 0, the gaze target
        state |= context
        rows[:, STATE] = state
        rows[:, OFFSET] = 0  # the bits of 0.0
        floats[:, BASE_YAW], floats[:, BASE_PITCH] = base_yaw, base_pitch
        rows[:, LAST] = landing_ns
        z = hashes(rows[:, COUNTER], rows[:, KEY], 1)[0]
        rows[:, COUNTER] += _ONE
        z >>= _HALF_BITS
        next_ns = self._interval_ns(spread, np.multiply(z.view(np.int64), _MINUS_TWO_POW_MINUS_32))
        next_ns += landing_ns
        self.next_ns[agents] = next_ns
        scatter_rows(self._rows, agents, rows)

    def stop(self, agents: np.ndarray) -> None:
        """These agents left the mode: no more small saccades (their offsets are read first, see offsets)."""
        self.next_ns[agents] = NEVER_NS
        self._rows[agents, OFF_YAW] = self._rows[agents, OFF_PITCH] = 0  # the bits of 0.0

    def offsets(self, agents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """How far each eye sits from its fixation's base point (zero for agents not in the mode)."""
        return column_pair(self._rows.view(np.float64), agents, OFF_YAW, OFF_PITCH)

    def gather(self, agents: np.ndarray) -> np.ndarray:
        """The agents' rows (a copy; float fields as bits: OFF_YAW and OFF_PITCH hold the offsets)."""
        return self._rows.take(agents, axis=0)

    # ------------------------------------------------------------------ events

    def due(self, t: int) -> np.ndarray:
        np.less_equal(self.next_ns, t, out=self._due)
        return self._due.nonzero()[0]

    def advance(self, agents: np.ndarray, before: np.ndarray | int, eyes: np.ndarray | None = None) -> None:
        """Run the agents' small saccades that start before `before` (one time, or one per agent), in time
        order. Each landing goes into `eyes` (rows of yaw and pitch); without it, into the eye state at
        the next write_pending (between ticks the eye state handed out stays as it was)."""
        due = self.next_ns.take(agents) < before
        if np.ndim(before):
            before = before[due]  # type: ignore[index]
        self.run_due(agents[due], before, eyes)

    def mark_unwritten(self, agents: np.ndarray) -> None:
        """Write these agents' landings at the next write_pending too (see advance)."""
        self._unwritten.append(agents)

    def run_due(self, agents: np.ndarray, before: np.ndarray | int, eyes: np.ndarray | None = None) -> None:
        """advance() for agents whose next small saccade is known to start before `before` (from due())."""
        while agents.size:
            if agents.size <= _BATCH:
                next_onsets = self._step(agents, eyes)
            else:
                next_onsets = np.concatenate([self._step(agents[start : start + _BATCH], eyes)
                                              for start in range(0, agents.size, _BATCH)])
            again = next_onsets < before
            agents = agents[again]
            if np.ndim(before):
                before = before[again]  # type: ignore[index]

    def _step(self, agents: np.ndarray, eyes: np.ndarray | None) -> np.ndarray:
        """One small saccade of each agent, at its next event time; returns the onsets of the next ones.

        Every agent computes both a scan and a microsaccade and keeps one: cheaper than splitting the batch.
        Angles come from tables, not cos/sin. With tens of thousands of agents a tick, the time goes to
        passes over memory, not to arithmetic: the reported columns are computed in place in the onset
        matrix, scratch arrays are reused, each row's fields are read once, and the uniforms that only pick
        a table cell stay the integers they are (their float would be converted back). Yaw and pitch go
        through one numpy call as the two rows of a (2, agents) block where both are contiguous: with a
        hundred thousand agents, a few thousand small saccades a tick, a call's fixed cost is much of it."""
        rows = self._rows.take(agents, axis=0)
        floats = rows.view(np.float64)
        onset = self.next_ns.take(agents)
        z = hashes(rows[:, COUNTER], rows[:, KEY], _HASHES)
        rows[:, COUNTER] += _HASHES_DRAWN
        state = rows[:, STATE]  # a view: the fixated feature is updated in place below
        context = state & _STATE_MASK_BITS  # every table's index: see __init__
        high = z >> _HALF_BITS
        z &= _LOW_HALF
        high, low = high.view(np.int64), z.view(np.int64)  # the halves: below 2**32, exact as int64 and float
        if self._drift_two_d:  # drift since the eye landed: a Brownian displacement (radius and angle)
            radius = np.multiply(low[1], _MINUS_TWO_POW_MINUS_32)  # -u: log1p(-u) below
            np.log1p(radius, out=radius)
            radius *= (onset - rows[:, LAST]) * self._drift_scale
            np.sqrt(radius, out=radius)
            off = self._cos_sin.take(low[2] >> _ANGLE_SHIFT_BY, axis=1)  # int(u * ANGLES), exactly
            off *= radius
            off[0] += floats[:, OFF_YAW]
            off[1] += floats[:, OFF_PITCH]
        else:
            off = np.empty((2, agents.size))
            off[0], off[1] = floats[:, OFF_YAW], floats[:, OFF_PITCH]
        # Scan or microsaccade; a scan's target from the same uniform, rescaled below p_scan.
        u_kind = high[1]
        scan = u_kind < self._scan_below.take(context)
        # A microsaccade heads back toward the point fixated, within the correction spread. Its amplitude reads
        # the quantile table at u * AMPLITUDE_TABLE_INTERVALS: the cell and the fraction are the integer's
        # top bits and the rest, exactly.
        cell = high[2] >> _CELL_SHIFT_BY
        fraction = high[2] & _CELL_FRACTION_MASK
        amplitude = self._amplitude_steps.take(cell)
        amplitude *= np.multiply(fraction, _FRACTION_SCALE)
        amplitude += self._amplitudes.take(cell)
        toward = self._fixated_point.take(context, axis=1)
        toward -= off
        square = toward * toward
        norm = np.add(square[0], square[1])
        np.sqrt(norm, out=norm)
        on_point = (norm < _ON_POINT).nonzero()[0]  # heading along the spread alone
        if on_point.size:
            toward[0][on_point], norm[on_point] = 1.0, 1.0
        amplitude /= norm
        # (yaw cos - pitch sin, yaw sin + pitch cos): the heading turned by the jitter.
        turn = self._jitter_cos_sin.take(low[0] >> _ANGLE_SHIFT_BY, axis=1)
        np.multiply(toward, turn, out=square)
        toward *= turn[::-1]  # (sin; cos)
        to_off = np.empty_like(toward)
        np.subtract(square[0], square[1], out=to_off[0])
        np.add(toward[0], toward[1], out=to_off[1])
        to_off *= amplitude
        to_off += off
        hit = scan.nonzero()[0]
        if hit.size:  # through 1-D views: a (row, index) fancy index takes numpy's slow general path
            hit_context, u_hit = context.take(hit), u_kind.take(hit)
            landed_on = (u_hit >= self._target_1_from.take(hit_context)).view(np.int8)
            landed_on += (u_hit >= self._target_2_from.take(hit_context)).view(np.int8)
            landed_on += _ONE_INT8
            to_off[0][hit] = self._points_yaw.take(landed_on)
            to_off[1][hit] = self._points_pitch.take(landed_on)
            hit_context &= _FEATURE_MASK  # the feature fixated
            np.subtract(landed_on, hit_context, out=hit_context)
            state[hit] += hit_context  # the feature fixated now, in the low bits
        # The reported columns (events.ONSET_FLOAT_FIELDS), computed where they are reported. A row's columns
        # are read one at a time: a (2, agents) block over two of them (strides of 8 and 64 bytes) makes
        # numpy iterate the axis of two innermost, several times slower.
        out = np.empty((9, agents.size))
        positions = out[:4]  # from yaw, from pitch, to yaw, to pitch
        base = np.empty_like(off)  # (yaw; pitch) contiguous: read twice
        base[0], base[1] = floats[:, BASE_YAW], floats[:, BASE_PITCH]
        np.add(base, off, out=positions[:2])
        np.add(base, to_off, out=positions[2:])
        np.maximum(positions, self._lower_limits, out=positions)  # np.clip, without its Python wrapper
        np.minimum(positions, self._limits, out=positions)
        delta = np.subtract(positions[2:], positions[:2], out=off)
        moved = out[5]
        np.multiply(delta, delta, out=square)
        np.add(square[0], square[1], out=moved)
        np.sqrt(moved, out=moved)
        out[4] = moved  # the magnitude
        duration = np.multiply(moved, self._d_ns_per_deg, out=norm)
        duration += self._d0_ns
        np.rint(duration, out=duration)
        end = duration.astype(np.int64)
        end += onset
        np.multiply(duration, _S_PER_NS, out=out[7])  # duration_s: the whole nanoseconds, as end - onset
        next_onset = self._interval_ns((state >> _STATE_SHIFT_BY).astype(np.float64),
                                       np.multiply(high[0], _MINUS_TWO_POW_MINUS_32))
        next_onset += onset
        floats[:, OFF_YAW], floats[:, OFF_PITCH] = to_off
        rows[:, LAST] = end
        scatter_rows(self._rows, agents, rows)
        self.next_ns[agents] = next_onset
        if eyes is None:
            self._unwritten.append(agents)
        else:
            write_eyes(eyes, agents, out[2], out[3])
        direction = np.arctan2(delta[1], delta[0], out=out[6])
        direction *= _DEGREES_PER_RADIAN
        direction += (direction < _ZERO) * _FULL_TURN
        np.multiply(next_onset - end, _S_PER_NS, out=out[8])  # hold_s
        kind = scan.view(np.int8) * _SCAN_MINUS_MICRO
        kind += _MICRO
        self._chunks.append((agents, onset, kind, out))
        return next_onset

    def write_pending(self, eyes: np.ndarray, landed: Callable[[np.ndarray], np.ndarray]) -> None:
        """Write the landings of small saccades run between ticks into the eye state, for the agents still in
        the mode whose Eyes Alive saccade has landed (`landed(agents)`: a mask); an eye in flight shows its
        flight, and one that has left the mode its new mode's position."""
        if self._unwritten:
            # One batch (the tick's own, see mark_unwritten) is unique and sorted already.
            batches = self._unwritten
            agents = batches[0] if len(batches) == 1 else np.unique(np.concatenate(batches))
            batches.clear()
            agents = agents[self.next_ns.take(agents) != NEVER_NS]  # stop() ends an agent's fixations
            agents = agents[landed(agents)]
            if not agents.size:  # at video rates the usual case: the agents' new saccades are in flight
                return
            rows = self._rows.view(np.float64).take(agents, axis=0)
            position = rows[:, BASE_YAW : BASE_PITCH + 1] + rows[:, OFF_YAW : OFF_PITCH + 1]
            np.maximum(position, -self._limits[:2, 0], out=position)  # np.clip, without its Python wrapper
            np.minimum(position, self._limits[:2, 0], out=position)
            write_eyes(eyes, agents, position[:, 0], position[:, 1])

    def take_onsets(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        """The small saccades since the last call: (agents, onsets, kinds, a (9, k) float matrix in
        events.ONSET_FLOAT_FIELDS order) per batch."""
        chunks, self._chunks = self._chunks, []
        return chunks

    def _interval_ns(self, negated_spread_ns: np.ndarray, negated_u: np.ndarray) -> np.ndarray:
        """Onset to next onset: the refractory gap plus an exponential of the fixation's spread, from the
        spread and the uniform both negated (STATE holds the spread so; -u is the uniform's integer times
        -2**-32). Both arguments are scratch (overwritten)."""
        negated_spread_ns *= np.log1p(negated_u, out=negated_u)
        interval = np.rint(negated_spread_ns, out=negated_spread_ns).astype(np.int64)
        interval += self._refractory
        return interval


def microsaccade_quantiles(params: GazeParams) -> np.ndarray:
    """The microsaccade amplitudes' quantile table: AMPLITUDE_TABLE_INTERVALS + 1 quantiles of the truncated
    log-normal at evenly spaced probabilities, read between two of them by a uniform."""
    fix = params.fixation
    return _lognormal_quantiles(fix.microsaccade_median_deg, fix.microsaccade_log_sd, fix.microsaccade_max_deg,
                                AMPLITUDE_TABLE_INTERVALS)


def _lognormal_quantiles(median: float, log_sd: float, largest: float, intervals: int) -> np.ndarray:
    """Quantiles of a log-normal truncated at `largest` at the `intervals` + 1 edges of an even grid."""
    normal = NormalDist()
    top = normal.cdf(math.log(largest / median) / log_sd)
    u = np.linspace(0.0, 1.0, intervals + 1) * top
    u[0] = min(max(u[0], 1e-12), top)
    z = np.array([normal.inv_cdf(min(max(v, 1e-12), 1.0 - 1e-12)) for v in u])
    q = median * np.exp(log_sd * z)
    q[-1] = largest
    return q
