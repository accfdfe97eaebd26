"""The Parameter Generator on the gaze engine's rows: when an agent's gaze timer expires, what it does next.

A decision chooses mutual gaze or away (the role's P(mutual), shifted by the emotion, or forced by a cue),
an away saccade's magnitude (Eyes Alive eq. 1) and direction bin (tilted by the emotion), and how long the
eye then holds (the role's mutual or away interval, stretched by the emotion); the launch (launch.py) does
the rest. Role and emotion are folded into per-agent derived columns of the row (P(mutual), the magnitude
map, the hold table row, the blink spread) when they change, so a decision needs no table look-ups by role.
Every draw is one of six uniforms per decision from the agent's own saccade stream.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from eca.agent.counter_rng import uniform01
from eca.agent.gaze.blink import blink_spread_ns
from eca.agent.gaze.generator import (
    HOLD_TABLE_INTERVALS,
    direction_index_from_uniform,
    direction_unit_steps,
    magnitude_map,
    mutual_probability,
)
from eca.agent.gaze.params import ROLES, GazeParams
from eca.agent.gaze.rows import (
    BLINK_SPREAD_NS,
    COUNTER_SACCADE,
    HOLD_BASE,
    HOLD_ROW,
    INTERVAL_SCALE,
    KEY_SACCADE,
    MAG_SCALE,
    MAG_SPAN,
    NEXT_SACCADE,
    P_MUTUAL,
    ROLE,
    TARGET_PITCH,
    TARGET_YAW,
    float_bits,
    hold_table,
    operand,
    row_uniforms,
)
from eca.agent.gaze.state import FORCE_AWAY, FORCE_MUTUAL, TURN_BLINK, GazeState

_HOLD_CELLS = operand(float(HOLD_TABLE_INTERVALS))  # a constant operand (rows.operand)
_AWAY_ROW = operand(HOLD_ROW, np.int64)


def _direction_cells(edges: np.ndarray, last_bin: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The table that reads min(searchsorted(edges, u, "right"), last_bin) in two look-ups by u's cell
    floor(u * cells), for the fewest cells (a power of two) that hold at most one edge each: per cell the
    bin of its start, and the edge inside it where the bin goes up by one (infinity where none does); and
    the number of cells (a 0-d float). None when no table of up to 2**16 cells separates the edges (then a
    binary search it is). A small table stays in the core's cache between a tick's few thousand decisions."""
    for bits in range(4, 17):
        count = 1 << bits
        cells = np.floor(edges * count).astype(np.int64)  # exact: scaling by a power of two
        inside = cells < count  # edges at or past 1 are past every draw
        if np.unique(cells[inside]).size == np.count_nonzero(inside):
            below = np.minimum(np.searchsorted(cells, np.arange(count), side="left"), last_bin)
            edge = np.full(count, np.inf)
            edge[cells[inside]] = edges[inside]
            edge[below == last_bin] = np.inf  # the last bin goes no further
            return below, edge, operand(float(count))
    return None


class Decision(NamedTuple):
    """What a batch of decisions launches (launch.Launcher.launch's arguments)."""

    times: np.ndarray  # when each decides: its gaze timer
    to: np.ndarray  # (yaw; pitch) of the landing point, (2, agents)
    kind: np.ndarray  # mutual (0) or away (1), int8
    hold_s: np.ndarray
    u_pull: np.ndarray  # the uniforms of the gaze-evoked blink's chance and of its follower interval
    u_follow: np.ndarray
    magnitude: np.ndarray  # the drawn magnitude, reported for the away saccades
    away: np.ndarray
    least_pull: np.ndarray | None  # the least chance of a coupled blink (turn boundaries), if any


class Decider:
    """The decisions of every agent, and the choice among several mutual-gaze points (set_targets)."""

    def __init__(self, params: GazeParams, state: GazeState, target_choice_seed: int) -> None:
        self._params = params
        self._state = state
        self._max_magnitude = np.array([params.roles[r].max_magnitude_deg for r in ROLES])
        self._blink_spread_ns = blink_spread_ns(
            params.blink, np.array([params.roles[r].blink_rate_per_min for r in ROLES]))
        self._hold = hold_table(params)
        self._log_ceiling = operand(params.p_max / params.p_ref)
        self._direction_edges = np.cumsum(params.direction_probability)  # generator.direction_index_from_uniform's
        self._last_bin = len(params.direction_bins_deg) - 1
        self._direction_cells = _direction_cells(self._direction_edges, self._last_bin)
        self._steps = np.stack(direction_unit_steps(params))  # (yaw; pitch) of each bin's unit step
        self._limits = np.array([[params.eye_yaw_limit_deg], [params.eye_pitch_limit_deg]])
        self._lower_limits = -self._limits
        # Agents whose mutual gaze chooses among several points (set_targets): points, cumulative weights,
        # and each one's count of draws from the target-choice stream.
        self._target_choice_seed = target_choice_seed
        self.target_sets: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._target_draws: dict[int, int] = {}

    @property
    def max_magnitude(self) -> np.ndarray:
        """The largest away magnitude of each role (ROLES order)."""
        return self._max_magnitude

    def derive(self, idx: np.ndarray) -> None:
        """Fold role and emotion into the columns a decision reads (see decide)."""
        state = self._state
        rows = state.rows
        role = rows[idx, ROLE]
        span, factor = magnitude_map(self._params, self._max_magnitude[role], state.magnitude_scale[idx])
        rows[idx, MAG_SPAN] = float_bits(span)
        rows[idx, MAG_SCALE] = float_bits(factor)
        rows[idx, P_MUTUAL] = float_bits(mutual_probability(self._params, role, state.mutual_shift[idx]))
        rows[idx, HOLD_BASE] = role * (2 * HOLD_ROW)
        rows[idx, BLINK_SPREAD_NS] = float_bits(self._blink_spread_ns[role])

    def decide(self, agents: np.ndarray, rows: np.ndarray) -> Decision:
        """The gaze timer expired (or the regime changed): choose mutual or away, where to and how long.

        Six uniforms per agent in one draw: mutual or away, magnitude, direction, hold, and the gaze-evoked
        blink's chance and follower interval. Yaw and pitch go as the two rows of a (2, agents) block, one
        numpy call for both: numpy broadcasts over a trailing axis of two (yaw, pitch) several times
        slower than it runs along a row. The uniforms are scratch once read."""
        state = self._state
        times = rows[:, NEXT_SACCADE].copy()
        floats = rows.view(np.float64)
        u = row_uniforms(rows, KEY_SACCADE, COUNTER_SACCADE, 6)
        if self.target_sets:
            self._choose_targets(agents, floats)
        away = u[0] >= floats[:, P_MUTUAL]
        least_pull = None
        if state.cued:
            away, least_pull = self._apply_cues(agents, away)
        # generator.magnitude_from_map, in place.
        magnitude = u[1]
        magnitude *= floats[:, MAG_SPAN]
        np.subtract(self._log_ceiling, magnitude, out=magnitude)
        np.log(magnitude, out=magnitude)
        magnitude *= floats[:, MAG_SCALE]
        to = self._steps.take(self._direction(agents, u[2]), axis=1)
        to *= magnitude
        target = np.empty_like(to)  # contiguous: see launch.Launcher.position
        target[0], target[1] = floats[:, TARGET_YAW], floats[:, TARGET_PITCH]
        to += target
        np.maximum(to, self._lower_limits, out=to)  # np.clip, without its Python wrapper
        np.minimum(to, self._limits, out=to)
        to = np.where(away, to, target)
        hold = self.hold_s(rows, u[3], away)
        return Decision(times, to, away.view(np.int8), hold, u[4], u[5], magnitude, away, least_pull)

    def hold_s(self, rows: np.ndarray, u: np.ndarray, away: np.ndarray | None) -> np.ndarray:
        """Inverse-CDF hold times (s) from the quantile table of each agent's (role, mutual/away), scaled by
        its emotion (generator.hold_from_uniform, on the side-by-side table); `away=None` means away for
        every row. `u` is scratch."""
        x = u
        x *= _HOLD_CELLS
        cell = x.astype(np.int64)  # u < 1, so the cell is at most the last one
        x -= cell
        cell += rows[:, HOLD_BASE]
        if away is None:
            cell += _AWAY_ROW
        else:
            cell += away * _AWAY_ROW  # a masked add (where=) is several times slower
        pairs = self._hold.take(cell, axis=0)
        hold = pairs[:, 0] * x
        hold += pairs[:, 1]
        hold *= rows.view(np.float64)[:, INTERVAL_SCALE]
        return hold

    def _direction(self, agents: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The drawn direction bin, tilted by the agents' emotions where they have one."""
        state = self._state
        if state.biased_agents:
            strength = state.bias_strength[agents]
            if strength.any():
                return direction_index_from_uniform(u, self._params, state.bias_direction[agents], strength)
        # generator.direction_index_from_uniform without a tilt: the bin below u's cell of the table, or the next
        # one where u reaches the edge inside that cell (two look-ups, not a binary search per draw).
        if self._direction_cells is None:
            index = np.searchsorted(self._direction_edges, u, side="right")
            return np.minimum(index, self._last_bin, out=index)
        below, edge, count = self._direction_cells
        cell = np.multiply(u, count).astype(np.int64)  # floor(u * 2**k), exactly: u >= 0
        index = below.take(cell)
        index += u >= edge.take(cell)
        return index

    def _apply_cues(self, agents: np.ndarray, away: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Forced outcomes (shift_gaze) and turn-boundary blinks for the deciding agents that have cues; the
        cues are spent. Returns the outcomes and, where a turn boundary asks for it, the least chance of a
        coupled blink."""
        state = self._state
        cues = state.cues.take(agents)
        j = np.flatnonzero(cues)
        if not j.size:
            return away, None
        c = cues[j]
        away = away.copy()
        away[j] = ((c & FORCE_AWAY) != 0) | (away[j] & ((c & FORCE_MUTUAL) == 0))
        state.cues[agents[j]] = 0
        state.cued -= j.size
        turn = j[(c & TURN_BLINK) != 0]
        if not turn.size:
            return away, None
        least = np.zeros(agents.size)
        least[turn] = self._params.blink.turn_probability
        return away, least

    # ------------------------------------------------------------------ several mutual-gaze points

    def set_targets(self, agent: int, yaws: np.ndarray, pitches: np.ndarray, cumulative: np.ndarray) -> None:
        self.target_sets[agent] = (yaws, pitches, cumulative)
        self._target_draws.setdefault(agent, 0)

    def drop_targets(self, agents: np.ndarray) -> None:
        for agent in agents.tolist():
            self.target_sets.pop(agent, None)

    def choose_target(self, agent: int) -> tuple[float, float]:
        yaws, pitches, cumulative = self.target_sets[agent]
        draw = self._target_draws[agent]
        self._target_draws[agent] = draw + 1
        u = float(uniform01(self._target_choice_seed, agent, draw))
        k = int(np.searchsorted(cumulative, u, side="right"))
        return float(yaws[k]), float(pitches[k])

    def _choose_targets(self, agents: np.ndarray, floats: np.ndarray) -> None:
        """Agents with several mutual-gaze points draw the one this decision aims at (and centres on)."""
        for j in np.flatnonzero(np.isin(agents, np.fromiter(self.target_sets, np.int64))).tolist():
            floats[j, TARGET_YAW], floats[j, TARGET_PITCH] = self.choose_target(int(agents[j]))
