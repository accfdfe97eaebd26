"""What a GazeEngine tick rewrites every tick: the eyes in flight and the lids of blinks in progress.

Both live in persistent buffers that a tick appends to and trims, so a tick never gathers them from the
per-agent state or concatenates them anew; with a hundred thousand agents the fixed cost of each numpy
call, not arithmetic, sets the time here, so each tick makes a handful of calls over each buffer.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from eca.agent.gaze.rows import operand, write_eyes
from eca.agent.gaze.synth import saccade_progress

# Fields of a saccade in flight: onset, end, from yaw, from pitch, to yaw, to pitch (float bit patterns), then
# its agent.
FLIGHT_WIDTH = 7
ONSET, END, FROM_YAW, FROM_PITCH, TO_YAW, TO_PITCH, AGENT = range(FLIGHT_WIDTH)
_ONE = operand(1.0)


class Flights:
    """Copies of the saccades of the eyes in flight, in the order they were launched.

    Field by field, each a row of one matrix: a tick reads every field of every copy once (to interpolate)
    and trims them all, and both run along contiguous rows; as one row per copy, numpy reads the fields
    with strides and copies the rows one by one."""

    def __init__(self) -> None:
        self._fields = np.empty((FLIGHT_WIDTH, 256), np.int64)
        self._spare = np.empty_like(self._fields)  # the fields' next state, to trim into without a copy
        self._count = 0
        # The copies before this one were still in flight at _flying_at (land left them): write_positions at
        # that time checks only the saccades launched since.
        self._flying = 0
        self._flying_at: int | None = None

    def add(self, agents: np.ndarray, saccades: np.ndarray) -> None:
        """Append launched saccades: `saccades` holds onset, end, from and to of each (6 int64 columns)."""
        end = self._count + agents.size
        if end > self._fields.shape[1]:
            grown = np.empty((FLIGHT_WIDTH, max(2 * self._fields.shape[1], end)), np.int64)
            grown[:, : self._count] = self._fields[:, : self._count]
            self._fields, self._spare = grown, np.empty_like(grown)
        added = self._fields[:, self._count : end]
        added[:AGENT] = saccades.T
        added[AGENT] = agents
        self._count = end

    def keep_current(self, onset_end: Callable[[np.ndarray], np.ndarray]) -> None:
        """Drop the copies of saccades cut short from outside (relaunched or stopped): those whose onset and
        end are no longer their agent's (`onset_end(agents)`), and all but the last of two launches of one
        agent at one instant (the later one, appended last, is the current one)."""
        live = self._fields[:, : self._count]
        agents = live[AGENT]
        keep = np.all(live[:END + 1].T == onset_end(agents), axis=1)
        _, first_in_reverse = np.unique(agents[::-1], return_index=True)
        latest = np.zeros(agents.size, dtype=bool)
        latest[agents.size - 1 - first_in_reverse] = True
        keep &= latest
        self._trim(keep)

    def land(self, t: int, eyes: np.ndarray) -> None:
        """Write the eyes that landed by `t` into `eyes` (rows of yaw and pitch) and drop their copies; the
        engine lands them before the small saccades that follow a landing, and interpolates the eyes in
        flight (write_positions) once the tick's decisions have launched theirs."""
        live = self._fields[:, : self._count]
        flying = live[END] > t
        if np.count_nonzero(flying) < flying.size:
            live = self._land(live, flying, eyes)
        self._flying, self._flying_at = live.shape[1], t

    def write_positions(self, t: int, eyes: np.ndarray) -> None:
        """Write every eye in flight at `t` into `eyes` (rows of yaw and pitch); eyes that landed since go to
        where their saccade lands and leave (see land)."""
        live = self._fields[:, : self._count]
        checked = self._flying if t == self._flying_at else 0
        flying = live[END, checked:] > t
        if np.count_nonzero(flying) < flying.size:
            flying = np.concatenate([np.ones(checked, dtype=bool), flying]) if checked else flying
            live = self._land(live, flying, eyes)
        if not live.shape[1]:
            return
        onset = live[ONSET]
        elapsed = t - onset
        progress = saccade_progress(elapsed / (live[END] - onset))
        remaining = _ONE - progress  # this form is exact at both ends of the saccade
        floats = live.view(np.float64)
        yaw = floats[FROM_YAW] * remaining
        yaw += floats[TO_YAW] * progress
        pitch = floats[FROM_PITCH] * remaining
        pitch += floats[TO_PITCH] * progress
        write_eyes(eyes, live[AGENT], yaw, pitch)

    def _land(self, live: np.ndarray, flying: np.ndarray, eyes: np.ndarray) -> np.ndarray:
        """Write the landed copies' landing points and keep the others; returns those.

        Each copy is its agent's current saccade (keep_current drops the others), so it lands on the
        agent's resting point, read here from the copy instead of from the agent's row (a random read per
        landing). An agent can have landed twice since the last tick (a saccade, and the one a decision
        launched after it): its copies are in launch order, and the later write is the one that stays."""
        landed = (~flying).nonzero()[0]
        to = live.view(np.float64)
        write_eyes(eyes, live[AGENT].take(landed), to[TO_YAW].take(landed), to[TO_PITCH].take(landed))
        return self._trim(flying)

    def _trim(self, keep: np.ndarray) -> np.ndarray:
        self._flying = 0  # the copies move
        count = int(np.count_nonzero(keep))
        self._spare[:, :count] = np.compress(keep, self._fields[:, : self._count], axis=1)
        self._fields, self._spare = self._spare, self._fields
        self._count = count
        return self._fields[:, :count]


class LiveBlinks:
    """Blinks in progress, at most one per agent (its latest), in the order they started.

    The entries sit in a buffer between a head and a tail; ended blinks leave at the head. An agent's
    earlier blink that a new one replaces stays in place, its agent turned into the sentinel: an index
    one past the last agent, a scratch slot of the lid array, so one assignment writes every lid and no
    agent twice. Entry positions are counted from the first blink ever added, so an agent's entry is in
    the buffer exactly when its position is at or past the head's.
    """

    def __init__(self, curve_s: np.ndarray, closure: np.ndarray, n_agents: int) -> None:
        self._closure = np.asarray(closure, dtype=np.float64)
        self._duration_ns = int(round(float(curve_s[-1]) * 1e9))
        # The curve's pieces as lines closure = slope * elapsed + offset, latest piece first (the window
        # holds onsets in ascending order, so elapsed times descend): (first ns, slope, offset) each.
        knots, values = np.asarray(curve_s, dtype=np.float64) * 1e9, self._closure
        self._pieces: list[tuple[int, np.ndarray, np.ndarray]] = []  # slope and offset as 0-d arrays (operand)
        for j in range(len(knots) - 2, -1, -1):
            if knots[j + 1] > knots[j]:
                slope = float((values[j + 1] - values[j]) / (knots[j + 1] - knots[j]))
                offset = float(values[j] - slope * knots[j])
                self._pieces.append((int(round(knots[j])), operand(slope), operand(offset)))
        self._elapsed = np.empty(1024)  # scratch for the window's elapsed times
        self._agents = np.empty(1024, np.int64)
        self._onsets = np.empty(1024, np.int64)
        self._head = self._tail = 0  # buffer indices
        self._base = 0  # the entry position of buffer index 0
        self._position = np.full(n_agents + 1, -1, np.int64)  # each agent's latest entry
        self._sentinel = n_agents

    def grow(self, n_agents: int) -> None:
        """Make room for agents added up to `n_agents`; the sentinel moves past them."""
        added = n_agents - self._sentinel
        self._position = np.concatenate([self._position, np.full(added, -1, np.int64)])
        window = self._agents[self._head : self._tail]
        window[window == self._sentinel] = n_agents
        self._sentinel = n_agents

    def cancel(self, agents: np.ndarray) -> None:
        """Stop writing the lids of these agents' blinks in progress (their lids are opened elsewhere)."""
        self._retire(agents)

    def update(self, t: int, lid: np.ndarray, agents: np.ndarray, onsets: np.ndarray) -> None:
        """Add the latest blinks of `agents` (onsets sorted, none before an earlier call's) and write the lid
        of every blink in progress at `t`; blinks over by then open their lids and leave."""
        if agents.size:
            self._retire(agents)
            self._append(agents, onsets)
        head, tail = self._head, self._tail
        # A lid reads its curve up to and including the curve's end, so a blink leaves once past it.
        ended = int(np.searchsorted(self._onsets[head:tail], t - self._duration_ns, side="left"))
        if ended:
            lid[self._agents[head : head + ended]] = 0.0
            head = self._head = head + ended
        if head < tail:
            lid[self._agents[head:tail]] = self._closures(t, self._onsets[head:tail])

    def _closures(self, t: int, onsets: np.ndarray) -> np.ndarray:
        """The lid curve at t - onsets (ascending onsets, none before t - the curve's length), piece by
        piece: each piece is a run of the window, so a line per run replaces a search per blink."""
        if self._elapsed.size < onsets.size:
            self._elapsed = np.empty(2 * onsets.size)
        out = self._elapsed[: onsets.size]
        np.subtract(t, onsets, out=out)  # exact: nanosecond counts stay far below 2**53
        # At exactly the curve's end a blink reads the last value, like np.interp.
        stop = int(np.searchsorted(onsets, t - self._duration_ns, side="right"))
        out[:stop] = self._closure[-1]
        for knot_ns, slope, offset in self._pieces:
            start = stop
            stop = int(np.searchsorted(onsets, t - knot_ns, side="right"))
            if stop > start:
                piece = out[start:stop]
                piece *= slope
                piece += offset
        out[stop:] = 0.0  # before the curve starts (np.interp's left)
        return out

    def _retire(self, agents: np.ndarray) -> None:
        position = self._position[agents]
        held = position >= self._base + self._head
        if held.any():
            self._agents[position[held] - self._base] = self._sentinel

    def _append(self, agents: np.ndarray, onsets: np.ndarray) -> None:
        count = self._tail - self._head
        if self._tail + agents.size > self._agents.size:
            capacity = max(self._agents.size, 2 * (count + agents.size))
            for name in ("_agents", "_onsets"):
                old = getattr(self, name)
                new = np.empty(capacity, np.int64) if capacity > old.size else old
                new[:count] = old[self._head : self._tail]
                setattr(self, name, new)
            self._base += self._head
            self._head, self._tail = 0, count
        end = self._tail + agents.size
        self._agents[self._tail : end] = agents
        self._onsets[self._tail : end] = onsets
        self._position[agents] = np.arange(self._base + self._tail, self._base + end)
        self._tail = end
