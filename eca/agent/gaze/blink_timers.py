"""The statistical blink model (blink.py) run on the gaze engine's rows: each agent's blink timer.

In modes saccade+blink and saccade+noise+blink every agent has a next spontaneous blink (a renewal process
at its role's rate); a blink that falls due blinks and draws the next one. Large and head-led saccades,
turn boundaries and calls for listener feedback pull a blink due within the pull window forward to their
own instant, so they add no blinks and the rates hold. A blink touches five columns of its agent's row,
all in place (gathering whole rows costs more); the lids of the blinks in progress are written each tick
(inflight.LiveBlinks).
"""

from __future__ import annotations

import numpy as np

from eca.agent.gaze.blink import blink_interval_ns
from eca.agent.gaze.events import BlinkOnsets
from eca.agent.gaze.inflight import LiveBlinks
from eca.agent.gaze.onsets import OnsetLog
from eca.agent.gaze.params import SACCADE_BLINK, BlinkParams
from eca.agent.gaze.rows import (
    BLINK_ONSET,
    BLINK_SPREAD_NS,
    COUNTER_BLINK,
    KEY_BLINK,
    MODE,
    N_COLUMNS,
    NEXT_BLINK,
    hashes,
    operand,
    row_uniforms,
)
from eca.agent.gaze.state import NEVER_NS, GazeState

_NS = 1_000_000_000
# Constant operands (rows.operand).
_MINUS_TWO_POW_MINUS_53, _ZERO = operand(-1.0 / float(1 << 53)), operand(0.0)
_MANTISSA_SHIFT = operand(11, np.uint64)
_ROW, _ONE = operand(N_COLUMNS, np.int64), operand(1, np.int64)
_WITH_MODEL = operand(SACCADE_BLINK, np.int64)
# From a row's NEXT_BLINK cell to its other blink cells (fire works on the flat row matrix).
_NEXT_BLINK, _TO_COUNTER, _TO_KEY, _TO_SPREAD, _COUNTER_TO_ONSET = (operand(v, np.int64) for v in (
    NEXT_BLINK, COUNTER_BLINK - NEXT_BLINK, KEY_BLINK - NEXT_BLINK, BLINK_SPREAD_NS - NEXT_BLINK,
    BLINK_ONSET - COUNTER_BLINK))


class BlinkTimers:
    """Every agent's spontaneous blink timer, and the blinks that saccades and cues pull forward."""

    def __init__(self, blink: BlinkParams, state: GazeState, log: OnsetLog) -> None:
        self._blink = blink
        self._state = state
        self._log = log
        self._refractory_ns = operand(blink.refractory_s * _NS)
        self._pull_window_ns = operand(int(round(blink.pull_window_s * _NS)), np.int64)
        self._evoked_slope = operand(
            blink.evoked_max_probability / max(blink.evoked_full_deg - blink.evoked_min_deg, 1e-9))
        self._evoked_min_deg, self._evoked_max_probability = (
            operand(blink.evoked_min_deg), operand(blink.evoked_max_probability))
        self._head_turn_probability = operand(blink.head_turn_probability)
        self.live = LiveBlinks(blink.lid_curve_s, blink.lid_curve_closure, 0)

    def grow(self, n_agents: int) -> None:
        self.live.grow(n_agents)

    def schedule(self, rows: np.ndarray, t: int) -> None:
        """Draw a fresh next blink from `t` for the rows with the statistical blink model."""
        with_model = np.flatnonzero(rows[:, MODE] >= SACCADE_BLINK)
        if with_model.size:
            sub = rows[with_model]
            u = row_uniforms(sub, KEY_BLINK, COUNTER_BLINK, 1)[0]
            sub[:, NEXT_BLINK] = t + blink_interval_ns(sub.view(np.float64)[:, BLINK_SPREAD_NS], u, self._blink)
            rows[with_model] = sub

    def fire(self, agents: np.ndarray) -> np.ndarray:
        """The blink timers of these agents expired: blink then and draw each one's next spontaneous blink,
        on their columns of the row matrix. Returns the next blink times."""
        flat = self._state.rows.reshape(-1)  # a view: the matrix is C-contiguous (rows.aligned_rows)
        cells = agents * _ROW
        cells += _NEXT_BLINK
        times = flat.take(cells)
        z = hashes(flat.take(cells + _TO_COUNTER), flat.take(cells + _TO_KEY), 1)[0]
        z >>= _MANTISSA_SHIFT
        # blink.blink_interval_ns, in place: the uniform's 53 bits times -2**-53 are -u exactly.
        interval = np.multiply(z.view(np.int64), _MINUS_TWO_POW_MINUS_53)
        np.log1p(interval, out=interval)
        interval *= flat.take(cells + _TO_SPREAD).view(np.float64)
        np.subtract(self._refractory_ns, interval, out=interval)
        next_blink = np.rint(interval, out=interval).astype(np.int64)
        next_blink += times
        flat[cells] = next_blink
        cells += _TO_COUNTER
        flat[cells] += _ONE
        cells += _COUNTER_TO_ONSET
        flat[cells] = times
        self._log.add_blinks(agents, times)
        return next_blink

    def couple(
        self,
        agents: np.ndarray,
        rows: np.ndarray,
        times: np.ndarray,
        amplitude: np.ndarray,
        u_pull: np.ndarray,
        u_follow: np.ndarray,
        head: bool,
        least_pull: np.ndarray | None = None,
    ) -> None:
        """Large saccades and head-led saccades pull the next due blink forward to their onset (blink model
        agents only), when that blink is due within the pull window; so do turn boundaries (`least_pull`)."""
        blink = self._blink
        if head:
            pull = u_pull < self._head_turn_probability
        else:
            # blink.evoked_blink_probability, in place.
            chance = np.subtract(amplitude, self._evoked_min_deg)
            chance *= self._evoked_slope
            np.maximum(chance, _ZERO, out=chance)
            np.minimum(chance, self._evoked_max_probability, out=chance)
            if least_pull is not None:
                np.maximum(chance, least_pull, out=chance)
            pull = u_pull < chance
        next_blink = rows[:, NEXT_BLINK]
        pull &= next_blink - times <= self._pull_window_ns
        pull &= rows[:, MODE] >= _WITH_MODEL
        j = pull.nonzero()[0]
        if j.size:  # through 1-D column views: a (rows, column) fancy index takes the slow general path
            spread = rows.view(np.float64)[:, BLINK_SPREAD_NS]
            next_blink[j] += blink_interval_ns(spread[j], u_follow[j], blink)
            pulled, onset = agents[j], times[j]
            rows[:, BLINK_ONSET][j] = onset
            self._log.add_blinks(pulled, onset)

    def pull(self, idx: np.ndarray, rows: np.ndarray, t: int) -> np.ndarray:
        """Blink at `t` where a blink is due within the pull window (blink_at), on the agents' gathered rows;
        returns the positions of those that blinked."""
        pull = (rows[:, MODE] >= SACCADE_BLINK) & (rows[:, NEXT_BLINK] - t <= self._pull_window_ns)
        j = np.flatnonzero(pull)
        if j.size:
            sub = rows[j]
            u = row_uniforms(sub, KEY_BLINK, COUNTER_BLINK, 1)[0]
            sub[:, NEXT_BLINK] += blink_interval_ns(sub.view(np.float64)[:, BLINK_SPREAD_NS], u, self._blink)
            sub[:, BLINK_ONSET] = t
            rows[j] = sub
            self._log.add_blinks(idx[j], np.full(j.size, t, np.int64))
        return j

    def stop(self, rows: np.ndarray, agents: np.ndarray) -> None:
        """These agents leave the blink model (their gathered rows): no timer, and the lids open."""
        rows[:, NEXT_BLINK] = NEVER_NS
        rows[:, BLINK_ONSET] = -NEVER_NS
        self.live.cancel(agents)

    def write_lids(self, t: int, lid: np.ndarray, new: BlinkOnsets) -> None:
        """Write the lids of the agents whose blink is in progress. Of the blinks started since the last
        tick (`new`) only each agent's latest joins: an earlier one was cut short by it, or by a switch of
        mode (which resets the agent's latest blink onset)."""
        agents, onsets = new.agent, new.onset_ns
        if agents.size:
            latest = self._state.rows.reshape(-1).take(agents * N_COLUMNS + BLINK_ONSET) == onsets
            if not latest.all():
                agents, onsets = agents[latest], onsets[latest]
        self.live.update(t, lid, agents, onsets)
