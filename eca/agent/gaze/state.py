"""The gaze engine's per-agent state: the row matrix, the dense arrays beside it, and the eye state handed out.

Every part of the engine (engine.py) reads and writes one `GazeState`: the decisions (decide.py), the
launches (launch.py), the blink timers (blink_timers.py) and the eye-mode variants (modes.py). The layout
is chosen for memory traffic (rows.py; with a million agents, random access to per-agent state, not
arithmetic, sets the tick time):

- The state an event reads or writes is one row per agent of an int64 matrix (float fields are stored
  as their bit patterns and read through a float64 view). An event batch gathers its agents' rows
  once, works on that small contiguous copy, and scatters it back once: two random accesses per agent
  instead of two per field.
- What every tick reads for every agent is contiguous 1-D: the next event time (scanned).
- The eye state a tick hands out (yaw, pitch, lid) is kept from tick to tick and rewritten only where it
  changes: yaw and pitch as one 16-byte row per agent (an eye is written as one element, rows.write_eyes),
  the lids apart, as the densest target for the lids of the blinks in progress, which a tick rewrites
  in random order (a tenth of the agents). One scratch entry past the last agent absorbs the lid
  writes of replaced blinks (inflight.LiveBlinks).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from eca.agent.gaze.params import KINDS
from eca.agent.gaze.rows import N_COLUMNS, NEXT_BLINK, NEXT_SACCADE, aligned_rows, scatter_rows

NEVER_NS = 1 << 62
MUTUAL, AWAY, HEAD = (KINDS.index(k) for k in ("mutual", "away", "head"))
assert (MUTUAL, AWAY) == (0, 1)  # a decision's kind is its "away" flag read as int8
# Cues that shape an agent's next decision (a per-agent bit set, cleared by the decision or a new hold).
FORCE_MUTUAL, FORCE_AWAY, TURN_BLINK = 1, 2, 4


class GazeState:
    """Every agent's state, and the counts that let a tick skip what no agent needs."""

    def __init__(self) -> None:
        self.n = 0
        self.rows = np.empty((0, N_COLUMNS), np.int64)
        # Per-agent 1-D arrays outside the rows (initial values in grow). The next event time is scanned
        # every tick; the mode is read by events; the cues by decisions; the rest only by set_head,
        # set_emotion and set_role.
        self.next_event = np.empty(0, np.int64)
        self.mode = np.empty(0, np.int8)
        self.cues = np.empty(0, np.int8)
        self.head_yaw, self.head_pitch = np.empty(0), np.empty(0)
        self.head_ref_yaw, self.head_ref_pitch = np.empty(0), np.empty(0)
        self.magnitude_scale, self.mutual_shift = np.empty(0), np.empty(0)
        self.bias_direction, self.bias_strength = np.empty(0), np.empty(0)
        self.eyes = np.zeros((1, 2))  # yaw, pitch
        self.lid = np.zeros(1)
        self.biased_agents = 0  # how many agents' emotion tilts the direction bins
        self.fixating = 0  # agents in mode saccade+noise+blink
        self.cued = 0  # agents with cues for their next decision (the "cues" column)
        self.flight_stale = False  # set when an eye in flight is relaunched or stopped from outside
        self._due = np.empty(0, bool)  # due()'s mask, kept: a fresh one each tick is a megabyte at 1e6 agents
        self._members: dict[int, np.ndarray] = {}

    def grow(self, rows: np.ndarray, mode_code: int) -> np.ndarray:
        """Append agents with these rows, all in one mode; returns their indices."""
        count = rows.shape[0]
        new = np.arange(self.n, self.n + count, dtype=np.int64)
        grown = aligned_rows(self.n + count, N_COLUMNS)
        grown[: self.n] = self.rows
        grown[self.n :] = rows
        self.rows = grown

        def extended(column: np.ndarray, initial: float) -> np.ndarray:
            return np.concatenate([column, np.full(count, initial, dtype=column.dtype)])

        self.next_event = extended(self.next_event, NEVER_NS)
        self.mode = extended(self.mode, mode_code)
        self.cues = extended(self.cues, 0)
        self.head_yaw, self.head_pitch = extended(self.head_yaw, 0.0), extended(self.head_pitch, 0.0)
        self.head_ref_yaw = extended(self.head_ref_yaw, 0.0)
        self.head_ref_pitch = extended(self.head_ref_pitch, 0.0)
        self.magnitude_scale = extended(self.magnitude_scale, 1.0)  # the emotion "natural"
        self.mutual_shift = extended(self.mutual_shift, 0.0)
        self.bias_direction, self.bias_strength = extended(self.bias_direction, 0.0), extended(self.bias_strength, 0.0)
        self.eyes = np.concatenate([self.eyes[: self.n], np.zeros((count + 1, 2))])
        self.lid = np.concatenate([self.lid[: self.n], np.zeros(count + 1)])
        self.n += count
        self._due = np.empty(self.n, bool)
        self._members.clear()
        return new

    def indices(self, i: int | Sequence[int] | np.ndarray) -> np.ndarray:
        idx = np.atleast_1d(np.asarray(i))
        if idx.dtype.kind not in "iu" or idx.ndim != 1:
            raise ValueError(f"agent index must be an integer or a 1-D integer array, got {i!r}")
        idx = idx.astype(np.int64)
        if idx.size and (idx.min() < 0 or idx.max() >= self.n):
            raise ValueError(f"agent index out of range [0, {self.n}): {i!r}")
        if idx.size > 1 and np.unique(idx).size != idx.size:
            raise ValueError(f"agent indices must be unique: {i!r}")
        return idx

    def due(self, t: int) -> np.ndarray:
        """The agents with a timer event at or before `t` (due_mask holds them as a mask until the next call)."""
        np.less_equal(self.next_event, t, out=self._due)
        return self._due.nonzero()[0]

    @property
    def due_mask(self) -> np.ndarray:
        return self._due

    def store(self, idx: np.ndarray, rows: np.ndarray) -> None:
        """Scatter gathered rows back and refresh the agents' next event times."""
        scatter_rows(self.rows, idx, rows)
        self.next_event[idx] = np.minimum(rows[:, NEXT_SACCADE], rows[:, NEXT_BLINK])

    def members(self, mode: int) -> np.ndarray:
        """The agents in `mode` (cached until a mode changes: see set_modes)."""
        if mode not in self._members:
            self._members[mode] = np.flatnonzero(self.mode == mode)
        return self._members[mode]

    def set_modes(self, idx: np.ndarray, code: int) -> None:
        self.mode[idx] = code
        self._members.clear()

    # ------------------------------------------------------------------ cues for the next decision

    def cue(self, idx: np.ndarray, set_bits: int, clear_bits: int) -> None:
        if idx.size:
            before = np.count_nonzero(self.cues[idx])
            self.cues[idx] = (self.cues[idx] & ~np.int8(clear_bits)) | np.int8(set_bits)
            self.cued += int(np.count_nonzero(self.cues[idx])) - int(before)

    def clear_cues(self, agents: np.ndarray) -> None:
        cued = agents[self.cues.take(agents) != 0]
        self.cues[cued] = 0
        self.cued -= cued.size
