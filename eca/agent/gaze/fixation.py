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
    scatter_rows,
    stream_keys,
    uniform_halves,
)

NEVER_NS = 1 << 62
_NS = 1_000_000_000
SCAN, MICRO = KINDS.index("scan"), KINDS.index("micro")
_N_FEATURES = len(FACE_FEATURES)
AMPLITUDE_TABLE_INTERVALS = 4096  # cells of the microsaccade amplitudes' quantile table

# Columns of the per-agent row (float fields as bit patterns). STATE packs the spread of the exponential
# part of the interval (ns, upper bits) with the fixation's context (low 8 bits): see _state().
COUNTER, KEY, OFF_YAW, OFF_PITCH, BASE_YAW, BASE_PITCH, LAST, STATE = range(8)
_WIDTH = 8  # 64 bytes: one cache line per agent
_STATE_BITS = 8
_STATE_MASK = (1 << _STATE_BITS) - 1
# Each small saccade draws 32-bit uniforms, two per hash (rows.uniform_halves): the interval; scan or
# microsaccade (and the scan's target); the microsaccade's amplitude and its turn off the corrective
# heading; the drift's radius and angle.
_HASHES = 3
_U_INTERVAL, _U_KIND, _U_AMPLITUDE, _U_JITTER, _U_DRIFT_RADIUS, _U_DRIFT_ANGLE = range(6)
ANGLES = 4096  # angle tables: a 32-bit uniform picks one of this many evenly spaced angles


def _state(role: np.ndarray, mutual: np.ndarray, preferred_eye: np.ndarray, feature: np.ndarray) -> np.ndarray:
    """The fixation's context as one small integer: (role, mutual, preferred eye) then the feature fixated
    (0 = the gaze target itself, 1 + index into FACE_FEATURES)."""
    return ((role * 2 + mutual) * 2 + preferred_eye) * 4 + feature


class Fixations:
    """The small saccades of every agent in mode saccade+noise+blink."""

    def __init__(self, params: GazeParams, stream_seed: int) -> None:
        fix = params.fixation
        self._stream_seed = stream_seed
        self._refractory_ns = int(round(fix.refractory_s * _NS))
        self._d0_ns = params.d0_s * _NS
        self._d_ns_per_deg = params.d_s_per_deg * _NS
        self._yaw_limit, self._pitch_limit = params.eye_yaw_limit_deg, params.eye_pitch_limit_deg
        self._drift_two_d = 2.0 * fix.drift_diffusion_deg2_per_s  # per-axis variance per second
        self._correction = math.radians(fix.correction_spread_deg)
        # The points a fixation holds, indexed like the fixated feature: 0 the gaze target, then FACE_FEATURES.
        self._points_yaw = np.append(0.0, fix.features_deg[:, 0])
        self._points_pitch = np.append(0.0, fix.features_deg[:, 1])
        contexts = len(ROLES) * 2 * 2
        # Per (role, mutual, preferred eye): the chance that a small saccade is a scan, its mean interval
        # (s), and the cumulative chances of the scan's target. A scan draws its target by the features'
        # shares of dwell time, the one fixated included (then it re-centres on it), so the shares of time
        # on each feature are exactly those shares.
        self._p_scan = np.zeros(contexts)
        self._mean_s = np.zeros(contexts)
        cumulative = np.zeros((contexts, _N_FEATURES))
        for r, role in enumerate(ROLES):
            for mutual in (0, 1):
                for eye in (0, 1):
                    c = (r * 2 + mutual) * 2 + eye
                    rate = fix.event_rate_hz(role, bool(mutual))
                    self._mean_s[c] = 1.0 / rate
                    self._p_scan[c] = (rate - fix.microsaccade_rate_hz) / rate
                    cumulative[c] = np.cumsum(fix.feature_weights(role, eye))
        # A small saccade is a scan to feature j when its uniform is below p_scan and at or above p_scan times
        # the cumulative chance of the features before j: those products, per context.
        self._scan_edges_0, self._scan_edges_1 = self._p_scan * cumulative[:, 0], self._p_scan * cumulative[:, 1]
        quantiles = microsaccade_quantiles(params)
        self._amplitudes, self._amplitude_steps = quantiles[:-1], np.diff(quantiles)
        angles = (np.arange(ANGLES) + 0.5) * (2.0 * np.pi / ANGLES)
        self._cos, self._sin = np.cos(angles), np.sin(angles)
        jitter = (np.arange(ANGLES) + 0.5) / ANGLES * (2.0 * self._correction) - self._correction
        self._jitter_cos, self._jitter_sin = np.cos(jitter), np.sin(jitter)
        self._n = 0
        self._rows = aligned_rows(0, _WIDTH)
        self.next_ns = np.empty(0, np.int64)  # dense: scanned every tick
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

    def start(
        self,
        agents: np.ndarray,
        landing_ns: np.ndarray,
        base_yaw: np.ndarray,
        base_pitch: np.ndarray,
        mutual: np.ndarray,
        role: np.ndarray,
        interval_scale: np.ndarray,
    ) -> None:
        """A new fixation: the eyes land at `landing_ns` on (base_yaw, base_pitch), the gaze target when
        `mutual`. Pending small saccades of the old fixation are dropped; the first of the new one is drawn."""
        rows = self._rows.take(agents, axis=0)
        floats = rows.view(np.float64)
        preferred_eye = rows[:, KEY] & 1
        context = (role * 2 + mutual) * 2 + preferred_eye
        spread_ns = np.maximum(self._mean_s.take(context) * interval_scale * _NS - self._refractory_ns, 0.0)
        rows[:, STATE] = (np.rint(spread_ns).astype(np.int64) << _STATE_BITS) | _state(
            role, mutual, preferred_eye, np.zeros_like(role))
        floats[:, OFF_YAW] = floats[:, OFF_PITCH] = 0.0
        floats[:, BASE_YAW], floats[:, BASE_PITCH] = base_yaw, base_pitch
        rows[:, LAST] = landing_ns
        u = uniform_halves(rows[:, COUNTER].view(np.uint64), rows[:, KEY].view(np.uint64), 1)[0]
        rows[:, COUNTER] += 1
        self.next_ns[agents] = landing_ns + self._interval_ns(rows[:, STATE], u)
        scatter_rows(self._rows, agents, rows)

    def stop(self, agents: np.ndarray) -> None:
        """These agents left the mode: no more small saccades (their offsets are read first, see offsets)."""
        self.next_ns[agents] = NEVER_NS
        self._rows[agents, OFF_YAW] = self._rows[agents, OFF_PITCH] = 0  # the bits of 0.0

    def offsets(self, agents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """How far each eye sits from its fixation's base point (zero for agents not in the mode)."""
        return column_pair(self._rows.view(np.float64), agents, OFF_YAW, OFF_PITCH)

    # ------------------------------------------------------------------ events

    def due(self, t: int) -> np.ndarray:
        return np.flatnonzero(self.next_ns <= t)

    def advance(self, agents: np.ndarray, before: np.ndarray | int, eyes: np.ndarray | None = None) -> None:
        """Run the agents' small saccades that start before `before` (one time, or one per agent), in time
        order. Each landing goes into `eyes` (rows of yaw, pitch, lid); without it, into the eye state at
        the next write_pending (between ticks the eye state handed out stays as it was)."""
        due = self.next_ns.take(agents) < before
        if np.ndim(before):
            before = before[due]  # type: ignore[index]
        self.run_due(agents[due], before, eyes)

    def run_due(self, agents: np.ndarray, before: np.ndarray | int, eyes: np.ndarray | None = None) -> None:
        """advance() for agents whose next small saccade is known to start before `before` (from due())."""
        while agents.size:
            again = self._step(agents, eyes) < before
            agents = agents[again]
            if np.ndim(before):
                before = before[again]  # type: ignore[index]

    def _step(self, agents: np.ndarray, eyes: np.ndarray | None) -> np.ndarray:
        """One small saccade of each agent, at its next event time; returns the onsets of the next ones.

        Every agent computes both a scan and a microsaccade and keeps one: cheaper than splitting the batch.
        Angles come from tables, not cos/sin. With tens of thousands of agents a tick, the time goes to
        passes over memory, not to arithmetic: the reported columns are computed in place in the onset
        matrix, scratch arrays are reused, and each row's fields are read once."""
        rows = self._rows.take(agents, axis=0)
        floats = rows.view(np.float64)
        onset = self.next_ns.take(agents)
        u = uniform_halves(rows[:, COUNTER].view(np.uint64), rows[:, KEY].view(np.uint64), _HASHES)
        rows[:, COUNTER] += _HASHES
        state = rows[:, STATE]  # a view: the fixated feature is updated in place below
        fixated = state & 3
        context = state & _STATE_MASK
        context >>= 2
        if self._drift_two_d:  # drift since the eye landed: a Brownian displacement (radius and angle)
            radius = u[_U_DRIFT_RADIUS]
            np.negative(radius, out=radius)
            np.log1p(radius, out=radius)
            radius *= (onset - rows[:, LAST]) * (-2e-9 * self._drift_two_d)
            np.sqrt(radius, out=radius)
            turn = u[_U_DRIFT_ANGLE]
            turn *= ANGLES
            turn = turn.astype(np.intp)
            off_yaw = self._cos.take(turn)
            off_yaw *= radius
            off_yaw += floats[:, OFF_YAW]
            off_pitch = self._sin.take(turn)
            off_pitch *= radius
            off_pitch += floats[:, OFF_PITCH]
        else:
            off_yaw, off_pitch = floats[:, OFF_YAW].copy(), floats[:, OFF_PITCH].copy()
        # Scan or microsaccade; a scan's target from the same uniform, rescaled below p_scan.
        u_kind = u[_U_KIND]
        scan = u_kind < self._p_scan.take(context)
        target = (u_kind >= self._scan_edges_0.take(context)).view(np.int8)
        target += (u_kind >= self._scan_edges_1.take(context)).view(np.int8)
        # A microsaccade heads back toward the point fixated, within the correction spread.
        x = u[_U_AMPLITUDE]
        x *= AMPLITUDE_TABLE_INTERVALS
        cell = x.astype(np.intp)
        x -= cell
        amplitude = self._amplitude_steps.take(cell)
        amplitude *= x
        amplitude += self._amplitudes.take(cell)
        toward_yaw = self._points_yaw.take(fixated)
        toward_yaw -= off_yaw
        toward_pitch = self._points_pitch.take(fixated)
        toward_pitch -= off_pitch
        norm = toward_yaw * toward_yaw
        scratch = toward_pitch * toward_pitch
        norm += scratch
        np.sqrt(norm, out=norm)
        on_point = np.flatnonzero(norm < 1e-12)  # heading along the spread alone
        if on_point.size:
            toward_yaw[on_point], norm[on_point] = 1.0, 1.0
        amplitude /= norm
        jitter = u[_U_JITTER]
        jitter *= ANGLES
        jitter = jitter.astype(np.intp)
        cos_j, sin_j = self._jitter_cos.take(jitter), self._jitter_sin.take(jitter)
        to_off_yaw = toward_yaw * cos_j
        np.multiply(toward_pitch, sin_j, out=scratch)
        to_off_yaw -= scratch
        to_off_yaw *= amplitude
        to_off_yaw += off_yaw
        to_off_pitch = np.multiply(toward_yaw, sin_j, out=sin_j)
        np.multiply(toward_pitch, cos_j, out=scratch)
        to_off_pitch += scratch
        to_off_pitch *= amplitude
        to_off_pitch += off_pitch
        hit = np.flatnonzero(scan)
        if hit.size:
            landed_on = target.take(hit)
            landed_on += 1
            to_off_yaw[hit] = self._points_yaw.take(landed_on)
            to_off_pitch[hit] = self._points_pitch.take(landed_on)
            state[hit] += landed_on - fixated.take(hit)  # the feature fixated now, in the low bits
        # The reported columns (events.ONSET_FLOAT_FIELDS), computed where they are reported.
        out = np.empty((9, agents.size))
        from_yaw, from_pitch, to_yaw, to_pitch, magnitude, moved, direction, duration_s, hold_s = out
        for position, base, offset, limit in (
            (from_yaw, BASE_YAW, off_yaw, self._yaw_limit), (from_pitch, BASE_PITCH, off_pitch, self._pitch_limit),
            (to_yaw, BASE_YAW, to_off_yaw, self._yaw_limit), (to_pitch, BASE_PITCH, to_off_pitch, self._pitch_limit),
        ):
            np.add(floats[:, base], offset, out=position)
            np.clip(position, -limit, limit, out=position)
        delta_yaw = np.subtract(to_yaw, from_yaw, out=off_yaw)
        delta_pitch = np.subtract(to_pitch, from_pitch, out=off_pitch)
        np.multiply(delta_yaw, delta_yaw, out=moved)
        np.multiply(delta_pitch, delta_pitch, out=scratch)
        moved += scratch
        np.sqrt(moved, out=moved)
        magnitude[:] = moved
        duration = np.multiply(moved, self._d_ns_per_deg, out=scratch)
        duration += self._d0_ns
        end = np.rint(duration, out=duration).astype(np.int64)
        end += onset
        next_onset = self._interval_ns(state, u[_U_INTERVAL])
        next_onset += onset
        floats[:, OFF_YAW], floats[:, OFF_PITCH] = to_off_yaw, to_off_pitch
        rows[:, LAST] = end
        scatter_rows(self._rows, agents, rows)
        self.next_ns[agents] = next_onset
        if eyes is None:
            self._unwritten.append(agents)
        else:
            _write_eyes(eyes, agents, to_yaw, to_pitch)
        np.arctan2(delta_pitch, delta_yaw, out=direction)
        direction *= DEGREES_PER_RADIAN
        direction += (direction < 0.0) * 360.0
        np.multiply(end - onset, 1e-9, out=duration_s)
        np.multiply(next_onset - end, 1e-9, out=hold_s)
        kind = scan.view(np.int8) * np.int8(SCAN - MICRO)
        kind += np.int8(MICRO)
        self._chunks.append((agents, onset, kind, out))
        return next_onset

    def write_pending(self, eyes: np.ndarray, landed: Callable[[np.ndarray], np.ndarray]) -> None:
        """Write the landings of small saccades run between ticks into the eye state, for the agents still in
        the mode whose Eyes Alive saccade has landed (`landed(agents)`: a mask); an eye in flight shows its
        flight, and one that has left the mode its new mode's position."""
        if self._unwritten:
            agents = np.unique(np.concatenate(self._unwritten))
            self._unwritten.clear()
            agents = agents[self.next_ns.take(agents) != NEVER_NS]  # stop() ends an agent's fixations
            agents = agents[landed(agents)]
            floats = self._rows.view(np.float64)
            rows = floats.take(agents, axis=0)
            _write_eyes(eyes, agents,
                        np.clip(rows[:, BASE_YAW] + rows[:, OFF_YAW], -self._yaw_limit, self._yaw_limit),
                        np.clip(rows[:, BASE_PITCH] + rows[:, OFF_PITCH], -self._pitch_limit, self._pitch_limit))

    def take_onsets(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        """The small saccades since the last call: (agents, onsets, kinds, a (9, k) float matrix in
        events.ONSET_FLOAT_FIELDS order) per batch."""
        chunks, self._chunks = self._chunks, []
        return chunks

    def _interval_ns(self, state: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Onset to next onset: the refractory gap plus an exponential of the fixation's spread. `u` is
        scratch (overwritten)."""
        spread_ns = (state >> _STATE_BITS).astype(np.float64)
        np.negative(spread_ns, out=spread_ns)
        np.negative(u, out=u)
        spread_ns *= np.log1p(u, out=u)
        interval = np.rint(spread_ns, out=spread_ns).astype(np.int64)
        interval += self._refractory_ns
        return interval


def _write_eyes(eyes: np.ndarray, agents: np.ndarray, yaw: np.ndarray, pitch: np.ndarray) -> None:
    flat = eyes.reshape(-1)  # rows of (yaw, pitch, lid), C-contiguous: 1-D writes skip 2-D fancy indexing
    cells = agents * 3
    flat[cells] = yaw
    flat[cells + 1] = pitch


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
