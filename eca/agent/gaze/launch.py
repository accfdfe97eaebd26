"""The Saccade Synthesizer on the gaze engine's rows: launching saccades and reading where the eyes are.

A launch starts saccades from where each eye is at its onset (along a saccade still in flight, or where
the last one landed plus, in mode saccade+noise+blink, the fixational offset the small saccades left) to
the point a decision, a head turn or a moved target chose; the duration follows the amplitude (Eyes Alive
eq. 2). It writes the saccade into the agent's row, keeps a compact copy for the eyes in flight
(inflight.Flights), lets the saccade pull a due blink forward (blink_timers.py), starts the fixation at
the landing point, and reports the onset.
"""

from __future__ import annotations

import numpy as np

from eca.agent.gaze.blink_timers import BlinkTimers
from eca.agent.gaze.fixation import OFF_PITCH, OFF_YAW, Fixations
from eca.agent.gaze.inflight import Flights
from eca.agent.gaze.onsets import OnsetLog
from eca.agent.gaze.params import FIXATIONAL, GazeParams
from eca.agent.gaze.rows import (
    DEGREES_PER_RADIAN,
    END,
    FLIGHT,
    FROM_PITCH,
    FROM_YAW,
    INTERVAL_SCALE,
    KIND,
    MODE,
    NEXT_SACCADE,
    ONSET,
    ROLE,
    TO_PITCH,
    TO_YAW,
    operand,
)
from eca.agent.gaze.state import MUTUAL, GazeState
from eca.agent.gaze.synth import saccade_progress

_NS = 1_000_000_000
# Constant operands (rows.operand).
_NS_PER_S, _S_PER_NS, _ZERO, _ONE, _FULL_TURN, _DEGREES_PER_RADIAN = (
    operand(v) for v in (float(_NS), 1e-9, 0.0, 1.0, 360.0, DEGREES_PER_RADIAN))
_ONE_NS = operand(1, np.int64)


class Launcher:
    """Starts saccades for the engine: from its decisions (decide.py), head turns and gaze targets."""

    def __init__(
        self,
        params: GazeParams,
        state: GazeState,
        fixations: Fixations,
        flights: Flights,
        blinks: BlinkTimers,
        log: OnsetLog,
    ) -> None:
        self._state = state
        self._fixations = fixations
        self._flights = flights
        self._blinks = blinks
        self._log = log
        self._d_ns_per_deg = operand(params.d_s_per_deg * _NS)
        self._d0_ns = operand(params.d0_s * _NS)
        self._limits = np.array([[params.eye_yaw_limit_deg], [params.eye_pitch_limit_deg]])
        self._lower_limits = -self._limits

    def launch(
        self,
        agents: np.ndarray,
        rows: np.ndarray,
        times: np.ndarray,
        to: np.ndarray,
        kind: np.ndarray,
        hold_s: np.ndarray | None,
        u_pull: np.ndarray,
        u_follow: np.ndarray,
        magnitude: np.ndarray | None = None,
        drawn: np.ndarray | None = None,
        head: bool = False,
        least_pull: np.ndarray | None = None,
        fixations_run: bool = False,
    ) -> None:
        """Start saccades at `times` from where each eye is then to `to` ((yaw; pitch), (2, agents)), on the
        agents' gathered rows. Without `hold_s` the hold timer is kept; a new hold supersedes the cues for
        the next decision.

        `magnitude` is the drawn Eyes Alive magnitude to report, where `drawn` (default: everywhere); the
        others report the amplitude moved. `least_pull`: the least chance of a coupled blink, per agent.
        `fixations_run`: the small saccades before `times` have run (the tick ran them before its first
        decisions), so the check for them, a random read per agent, is skipped. The reported columns
        (events.ONSET_FLOAT_FIELDS) are computed in place in the onset matrix."""
        state = self._state
        floats = rows.view(np.float64)
        if state.cued and hold_s is not None:
            state.clear_cues(agents)
        fixating = (rows[:, MODE] == FIXATIONAL).nonzero()[0] if state.fixating else agents[:0]
        whole = fixating.size == agents.size  # the whole batch fixates: no gathers
        if fixating.size:  # the small saccades before the launch run first: the eye starts where they left it
            fixating_agents = agents if whole else agents.take(fixating)
            fixating_times = times if whole else times.take(fixating)
            if not fixations_run:
                self._fixations.advance(fixating_agents, fixating_times)
        out = np.empty((9, agents.size))
        start = out[:2]
        self.position(rows, times, start)
        fixation_rows = None
        if fixating.size:
            landed = fixating_times >= rows[:, END].take(fixating)
            if whole and landed.all():  # the usual decision: every eye landed long ago
                # Their fixations' rows, gathered once for the offsets here and the new fixations below.
                fixation_rows = self._fixations.gather(agents)
                offsets = fixation_rows.view(np.float64)
                start[0] += offsets[:, OFF_YAW]
                start[1] += offsets[:, OFF_PITCH]
                np.maximum(start, self._lower_limits, out=start)  # np.clip, without its Python wrapper
                np.minimum(start, self._limits, out=start)
            else:
                at = fixating[landed]
                off_yaw, off_pitch = self._fixations.offsets(agents.take(at))
                limits = self._limits[:, 0]
                start[0, at] = np.clip(start[0, at] + off_yaw, -limits[0], limits[0])
                start[1, at] = np.clip(start[1, at] + off_pitch, -limits[1], limits[1])
        out[2:4] = to
        to = out[2:4]
        delta = np.subtract(to, start)
        amplitude = np.hypot(delta[0], delta[1], out=out[5])
        duration = np.multiply(amplitude, self._d_ns_per_deg, out=out[7])  # the main sequence, Eyes Alive eq. 2
        duration += self._d0_ns
        duration_ns = np.rint(duration, out=duration).astype(np.int64)
        end = times + duration_ns
        if hold_s is not None:
            next_saccade = np.rint(hold_s * _NS_PER_S).astype(np.int64)
            next_saccade += end
            out[8] = hold_s
        else:
            next_saccade = np.maximum(rows[:, NEXT_SACCADE], end)
            np.multiply(next_saccade - end, _S_PER_NS, out=out[8])
        rows[:, ONSET], rows[:, END], rows[:, NEXT_SACCADE] = times, end, next_saccade
        floats[:, FROM_YAW], floats[:, FROM_PITCH] = start
        floats[:, TO_YAW], floats[:, TO_PITCH] = to
        rows[:, KIND] = kind
        self._blinks.couple(agents, rows, times, amplitude, u_pull, u_follow, head, least_pull)
        self._flights.add(agents, rows[:, FLIGHT])
        if fixating.size:
            if fixation_rows is not None:
                self.start_fixations(agents, rows, end, to, fixation_rows)
            elif whole:
                self.start_fixations(agents, rows, end, to)
            else:
                fixating_rows = rows.take(fixating, axis=0)
                self.start_fixations(fixating_agents, fixating_rows, end.take(fixating),
                                     to.take(fixating, axis=1))
        if magnitude is None:
            out[4] = amplitude
        elif drawn is not None:
            out[4] = np.where(drawn, magnitude, amplitude)
        else:
            out[4] = magnitude
        direction = np.arctan2(delta[1], delta[0], out=out[6])
        direction *= _DEGREES_PER_RADIAN
        # np.mod(direction, 360) for angles within one turn, without its slow floating remainder: negative
        # angles go up a turn, the others get 0.0 added, which turns -0.0 into 0.0 as np.mod does.
        direction += (direction < _ZERO) * _FULL_TURN
        duration *= _S_PER_NS
        self._log.add_saccades(agents, times, kind, out)

    def position(self, rows: np.ndarray, times: np.ndarray, out: np.ndarray) -> None:
        """Eye (yaw; pitch) at `times` along each row's current saccade, into `out` (2, rows); landed eyes
        skip the velocity profile.

        A row's columns are read one at a time: a (2, rows) block over two of them (strides of 8 and 192
        bytes) makes numpy iterate the axis of two innermost, several times slower."""
        floats = rows.view(np.float64)
        out[0], out[1] = floats[:, TO_YAW], floats[:, TO_PITCH]
        in_flight = (times < rows[:, END]).nonzero()[0]
        if in_flight.size:
            self._state.flight_stale = True  # these eyes are relaunched or stopped mid-flight
            flying = rows.take(in_flight, axis=0)
            onset = flying[:, ONSET]
            # A mode switch stamped ahead of the last tick leaves a zero-length "saccade" (a fixation)
            # starting in the future: asked before it, the eye is at its start (tau < 0), so dividing by at
            # least 1 ns gives the same position without a division by zero.
            duration = np.maximum(flying[:, END] - onset, _ONE_NS)
            progress = saccade_progress((times.take(in_flight) - onset) / duration)
            remaining = _ONE - progress  # this form is exact at both ends of the saccade
            flying_floats = flying.view(np.float64)
            for axis, start, end in ((0, FROM_YAW, TO_YAW), (1, FROM_PITCH, TO_PITCH)):
                out[axis, in_flight] = flying_floats[:, start] * remaining + flying_floats[:, end] * progress

    def start_fixations(
        self,
        agents: np.ndarray,
        rows: np.ndarray,
        landing_ns: np.ndarray,
        to: np.ndarray,
        fixation_rows: np.ndarray | None = None,
    ) -> None:
        """New fixations where the rows' saccades land (`to`, (yaw; pitch)), in their role, gaze (mutual or
        not) and emotion; `fixation_rows`: the agents' fixation rows, if gathered already."""
        self._fixations.start(agents, landing_ns, to[0], to[1], (rows[:, KIND] == MUTUAL).astype(np.int64),
                              rows[:, ROLE], rows.view(np.float64)[:, INTERVAL_SCALE], fixation_rows)
