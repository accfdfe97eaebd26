"""GazeEngine: the Attention Monitor, Parameter Generator and Saccade Synthesizer for N agents at once.

The model is that of reference.py, one agent written step by step; this is the same model for whole crowds
(tests/test_gaze_reference.py holds the two to identical trajectories). Every agent's state lives in numpy
arrays. A tick compares one next-event-time array against the clock and gathers only the agents whose gaze
timer or blink timer expired; their events are processed at their exact scheduled times (never quantised
to the tick), so the trajectory does not depend on the tick rate. Each agent draws from its own
counter-based stream (seed, agent index, per-agent counter), so adding an agent leaves every other agent's
trajectory unchanged.

The steps, each a section below: events from outside *prepare* their agents (run what was due before, then
apply the cue); the gaze timer expiring makes a *decision* (mutual or away, magnitude, direction, hold);
a decision, a head turn or a moved target *launches* a saccade; in mode saccade+noise+blink the eye
*fixates* between saccades with small saccades and drift (fixation.py); spontaneous and gaze-evoked
*blinks* run on their own timer; and the tick *reports* every eye's state and the onsets.

Layout, chosen for memory traffic (rows.py; with a million agents, random access to per-agent state, not
arithmetic, sets the tick time):

- The state an event reads or writes is one row per agent of an int64 matrix (float fields are stored
  as their bit patterns and read through a float64 view). An event batch gathers its agents' rows
  once, works on that small contiguous copy, and scatters it back once: two random accesses per agent
  instead of two per field.
- Role and emotion are folded into per-agent derived columns (P(mutual), the magnitude map, the hold
  table row, the blink spread) when they change, so a decision needs no table look-ups by role.
- What every tick reads for every agent is contiguous 1-D: the next event time (scanned).
- The eye state a tick hands out (yaw, pitch, lid) is kept from tick to tick and rewritten only where it
  changes: eyes in flight or just landed, lids of blinks in progress or just ended, agents whose mode
  changed, and the static and Perlin-noise modes. The tick hands out read-only views of it.
- Eyes in flight keep a compact copy of their saccade, so a tick interpolates them without touching
  the per-agent rows; they and the blinks in progress live in persistent buffers (inflight.py) that a
  tick appends to and trims instead of rebuilding.
- Timer events run in rounds of every due agent's earliest event: a blink on its agent's columns in place
  (it touches five of them), then the decisions as one batch of whole rows. Onsets are ordered by one
  sort of a packed key.

Events from outside (role, emotion, mode, head, target) take effect at their own timestamp; one stamped
before the last tick is applied at the last tick's time. A decision an event starts (role, mode, a forced
gaze shift) runs once every cue of its instant is in: at the next tick, or the agent's next later event.

In mode saccade+noise+blink the fixational eye movements (fixation.py) run between the Eyes Alive
saccades, on their own timers and stream; a launch first runs the small saccades due before it, starts
from where they left the eye, and starts a new fixation where it lands.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from eca.agent.counter_rng import uniform01
from eca.agent.gaze.blink import blink_interval_ns, blink_spread_ns, evoked_blink_probability
from eca.agent.gaze.events import BlinkOnsets, GazeTick, SaccadeOnsets
from eca.agent.gaze.fixation import Fixations
from eca.agent.gaze.generator import (
    BLINK_STREAM,
    FIXATION_STREAM,
    HOLD_TABLE_INTERVALS,
    NOISE_STREAM,
    PERLIN_BLINK_STREAM,
    SACCADE_STREAM,
    TARGET_CHOICE_STREAM,
    derive_seed,
    direction_index_from_uniform,
    direction_unit_steps,
    magnitude_from_map,
    magnitude_map,
    mutual_probability,
)
from eca.agent.gaze.inflight import Flights, LiveBlinks
from eca.agent.gaze.params import (
    DEFAULT_ROLE,
    FIXATIONAL,
    KINDS,
    MODES,
    NOISE,
    ROLES,
    SACCADE,
    SACCADE_BLINK,
    STATIC,
    GazeParams,
    check_name,
)
from eca.agent.gaze.rows import (
    BLINK_ONSET,
    BLINK_SPREAD_NS,
    COUNTER_BLINK,
    COUNTER_SACCADE,
    DEGREES_PER_RADIAN,
    END,
    FLIGHT,
    FROM_PITCH,
    FROM_YAW,
    HOLD_BASE,
    HOLD_ROW,
    INTERVAL_SCALE,
    KEY_BLINK,
    KEY_SACCADE,
    KIND,
    MAG_SCALE,
    MAG_SPAN,
    MODE,
    N_COLUMNS,
    NEXT_BLINK,
    NEXT_SACCADE,
    ONSET,
    P_MUTUAL,
    ROLE,
    TARGET_PITCH,
    TARGET_YAW,
    TO_PITCH,
    TO_YAW,
    aligned_rows,
    column_pair,
    float_bits,
    hold_table,
    read_only,
    row_uniforms,
    scatter_rows,
    sort_onsets,
    stream_keys,
    uniform_draws,
)
from eca.agent.gaze.synth import saccade_progress
from eca.agent.noise import perlin1d, perlin_blink

__all__ = ["GazeEngine", "GazeTick", "SaccadeOnsets", "BlinkOnsets", "DEFAULT_ROLE", "derive_seed"]

NEVER_NS = 1 << 62
_NS = 1_000_000_000

MUTUAL, AWAY, HEAD = (KINDS.index(k) for k in ("mutual", "away", "head"))
# Cues that shape an agent's next decision (a per-agent bit set, cleared by the decision or a new hold).
FORCE_MUTUAL, FORCE_AWAY, TURN_BLINK = 1, 2, 4
TOWARD: dict[str, int] = {"mutual": FORCE_MUTUAL, "away": FORCE_AWAY}
assert (MUTUAL, AWAY) == (0, 1)  # a decision's kind is its "away" flag read as int8


class GazeEngine:
    """The gaze of `n_agents` agents, advanced by `tick(t_ns)` on any clock (integer nanoseconds)."""

    def __init__(
        self,
        n_agents: int,
        seed: int,
        params: GazeParams | None = None,
        start_ns: int = 0,
        role: str = DEFAULT_ROLE,
        mode: str | None = None,
    ):
        if not isinstance(n_agents, int | np.integer) or n_agents < 0:
            raise ValueError(f"n_agents must be a non-negative integer, got {n_agents!r}")
        if not isinstance(seed, int | np.integer):
            raise ValueError(f"seed must be an integer, got {seed!r}")
        self.params = params if params is not None else GazeParams.load()
        self.seed = int(seed)
        self._seed_saccade = derive_seed(self.seed, SACCADE_STREAM)
        self._seed_blink = derive_seed(self.seed, BLINK_STREAM)
        self._seed_noise = derive_seed(self.seed, NOISE_STREAM)
        self._seed_perlin_blink = derive_seed(self.seed, PERLIN_BLINK_STREAM)
        self._seed_target_choice = derive_seed(self.seed, TARGET_CHOICE_STREAM)
        self._now_ns = int(start_ns)
        p = self.params
        blink = p.blink
        self._max_magnitude = np.array([p.roles[r].max_magnitude_deg for r in ROLES])
        self._blink_spread_ns = blink_spread_ns(blink, np.array([p.roles[r].blink_rate_per_min for r in ROLES]))
        self._pull_window_ns = int(round(blink.pull_window_s * _NS))
        self._d_ns_per_deg = p.d_s_per_deg * _NS
        self._d0_ns = p.d0_s * _NS
        self._hold = hold_table(p)
        self._bin_yaw_steps, self._bin_pitch_steps = direction_unit_steps(p)
        self._biased_agents = 0  # how many agents' emotion tilts the direction bins
        self._n = 0
        self._rows = np.empty((0, N_COLUMNS), np.int64)
        # Per-agent 1-D arrays outside the rows (initial values in _grow_columns). The next event time is
        # scanned every tick; the mode is read by events; the cues by decisions; the rest only by set_head,
        # set_emotion and set_role.
        self._next_event = np.empty(0, np.int64)
        self._mode = np.empty(0, np.int8)
        self._cues = np.empty(0, np.int8)
        self._head_yaw, self._head_pitch = np.empty(0), np.empty(0)
        self._head_ref_yaw, self._head_ref_pitch = np.empty(0), np.empty(0)
        self._magnitude_scale, self._mutual_shift = np.empty(0), np.empty(0)
        self._bias_direction, self._bias_strength = np.empty(0), np.empty(0)
        self._fixations = Fixations(p, derive_seed(self.seed, FIXATION_STREAM))
        self._fixating = 0  # agents in mode saccade+noise+blink
        self._cued = 0  # agents with cues for their next decision (the "cues" column)
        # Agents whose mutual gaze chooses among several points (set_targets): points, cumulative weights,
        # and each one's count of draws from the target-choice stream.
        self._target_sets: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._target_draws: dict[int, int] = {}
        self._flights = Flights()
        self._flight_stale = False  # set when an eye in flight is relaunched or stopped from outside
        self._live_blinks = LiveBlinks(blink.lid_curve_s, blink.lid_curve_closure, 0)
        # The eye state handed out by tick(), kept from tick to tick and rewritten only where it changes:
        # one row per agent (yaw, pitch, lid), so an eye's yaw and pitch writes share a cache line; one
        # scratch row past the last agent absorbs the lid writes of replaced blinks (LiveBlinks).
        self._eyes = np.zeros((1, 3))
        self._dirty: list[np.ndarray] = []  # agents whose mode changed: resting position and open lid again
        self._saccade_chunks: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self._blink_chunks: list[tuple[np.ndarray, np.ndarray]] = []
        self._members_cache: dict[int, np.ndarray] = {}
        if n_agents:
            self.add_agents(int(n_agents), self._now_ns, role, mode)

    # ------------------------------------------------------------------ agents

    def add_agents(self, count: int, t_ns: int, role: str = DEFAULT_ROLE, mode: str | None = None) -> np.ndarray:
        """Append `count` agents that start at `t_ns` looking at the primary position; returns their indices.

        Their first saccade decision is made at `t_ns` in `role`; `mode` defaults to the configured one.
        Existing agents are untouched: the new ones draw from their own streams.
        """
        if count < 0:
            raise ValueError(f"count must be >= 0, got {count}")
        check_name(role, ROLES, "role")
        mode = self.params.default_mode if mode is None else mode
        check_name(mode, MODES, "eye mode")
        mode_code = MODES.index(mode)
        t = max(int(t_ns), self._now_ns)
        new = np.arange(self._n, self._n + count, dtype=np.int64)
        rows = np.zeros((count, N_COLUMNS), np.int64)  # the bits of 0.0 are 0: eyes at the primary position
        rows[:, ONSET] = rows[:, END] = t
        rows[:, NEXT_SACCADE] = t if mode_code >= SACCADE else NEVER_NS  # the first decision, at t
        rows[:, NEXT_BLINK] = NEVER_NS
        rows[:, BLINK_ONSET] = -NEVER_NS
        rows[:, KEY_SACCADE] = stream_keys(self._seed_saccade, new)
        rows[:, KEY_BLINK] = stream_keys(self._seed_blink, new)
        rows[:, ROLE], rows[:, MODE], rows[:, KIND] = ROLES.index(role), mode_code, MUTUAL
        rows[:, INTERVAL_SCALE] = float_bits(1.0)
        grown = aligned_rows(self._n + count, N_COLUMNS)
        grown[: self._n] = self._rows
        grown[self._n :] = rows
        self._rows = grown
        self._grow_columns(count)
        self._mode[new] = mode_code
        self._eyes = np.concatenate([self._eyes[: self._n], np.zeros((count + 1, 3))])
        self._n += count
        self._live_blinks.grow(self._n)
        self._fixations.grow(count)
        if mode_code == FIXATIONAL:
            self._fixating += count
        self._members_cache.clear()
        self._derive(new)
        fresh = self._rows[new]
        self._schedule_blinks(fresh, t)
        self._store(new, fresh)
        return new

    def _grow_columns(self, count: int) -> None:
        """Append `count` agents' initial values to the per-agent 1-D arrays."""

        def grown(column: np.ndarray, initial: float) -> np.ndarray:
            return np.concatenate([column, np.full(count, initial, dtype=column.dtype)])

        self._next_event = grown(self._next_event, NEVER_NS)
        self._mode = grown(self._mode, 0)
        self._cues = grown(self._cues, 0)
        self._head_yaw, self._head_pitch = grown(self._head_yaw, 0.0), grown(self._head_pitch, 0.0)
        self._head_ref_yaw, self._head_ref_pitch = grown(self._head_ref_yaw, 0.0), grown(self._head_ref_pitch, 0.0)
        self._magnitude_scale = grown(self._magnitude_scale, 1.0)  # the emotion "natural"
        self._mutual_shift = grown(self._mutual_shift, 0.0)
        self._bias_direction, self._bias_strength = grown(self._bias_direction, 0.0), grown(self._bias_strength, 0.0)

    @property
    def n_agents(self) -> int:
        return self._n

    @property
    def now_ns(self) -> int:
        return self._now_ns

    def role_of(self, i: int) -> str:
        return ROLES[int(self._rows[self._indices(i)[0], ROLE])]

    def mode_of(self, i: int) -> str:
        return MODES[int(self._mode[self._indices(i)[0]])]

    # ------------------------------------------------------------------ the Attention Monitor's inputs

    def set_role(self, i: int | Sequence[int] | np.ndarray, role: str, t_ns: int) -> None:
        """Switch the conversational role; agents whose role changes decide a new saccade at `t`, once
        every other cue of that instant is in (the decision runs at the next tick or later event). In mode
        saccade+noise+blink the turn boundary may bring a blink ([blink] turn_probability)."""
        check_name(role, ROLES, "role")
        idx, t = self._prepare(i, t_ns)
        code = ROLES.index(role)
        idx = idx[self._rows[idx, ROLE] != code]
        if not idx.size:
            return
        self._rows[idx, ROLE] = code
        self._derive(idx)
        rows = self._rows[idx]
        rows[rows[:, MODE] >= SACCADE, NEXT_SACCADE] = t
        self._schedule_blinks(rows, t)
        self._store(idx, rows)
        self._cue(idx[rows[:, MODE] == FIXATIONAL], TURN_BLINK, 0)

    def shift_gaze(self, i: int | Sequence[int] | np.ndarray, toward: str, t_ns: int) -> None:
        """Make the next decision now, with its outcome fixed: "mutual" (at the gaze target) or "away"
        (magnitude, direction and hold drawn as usual). For turn-taking gaze: a speaker looks away as a
        long turn starts and back at the listener as it ends (Kendon 1967)."""
        check_name(toward, tuple(TOWARD), "gaze shift")
        idx, t = self._prepare(i, t_ns)
        idx = idx[self._mode[idx] >= SACCADE]
        if idx.size:
            self._rows[idx, NEXT_SACCADE] = t
            self._next_event[idx] = np.minimum(self._next_event[idx], t)
            self._cue(idx, TOWARD[toward], FORCE_MUTUAL | FORCE_AWAY)

    def blink_at(self, i: int | Sequence[int] | np.ndarray, t_ns: int) -> np.ndarray:
        """Blink now if a blink is due within the pull window (statistical blink modes only): the due blink
        is pulled forward, as a gaze shift pulls it, so the configured rates still hold. For listener
        feedback at a partner's pause. Returns the agents that blinked."""
        idx, t = self._prepare(i, t_ns)
        rows = self._rows[idx]
        pull = (rows[:, MODE] >= SACCADE_BLINK) & (rows[:, NEXT_BLINK] - t <= self._pull_window_ns)
        j = np.flatnonzero(pull)
        if j.size:
            sub = rows[j]
            u = row_uniforms(sub, KEY_BLINK, COUNTER_BLINK, 1)[0]
            sub[:, NEXT_BLINK] += self._blink_interval_ns(sub.view(np.float64)[:, BLINK_SPREAD_NS], u)
            sub[:, BLINK_ONSET] = t
            rows[j] = sub
            self._store(idx, rows)
            self._blink_chunks.append((idx[j], np.full(j.size, t, np.int64)))
        return idx[j]

    def _cue(self, idx: np.ndarray, set_bits: int, clear_bits: int) -> None:
        if idx.size:
            before = np.count_nonzero(self._cues[idx])
            self._cues[idx] = (self._cues[idx] & ~np.int8(clear_bits)) | np.int8(set_bits)
            self._cued += int(np.count_nonzero(self._cues[idx])) - int(before)

    def set_emotion(self, i: int | Sequence[int] | np.ndarray, name: str, intensity: float, t_ns: int) -> None:
        """Modulate the statistics of every later saccade decision (configs/gaze_emotions.toml)."""
        emotion = self.params.emotion(name, float(intensity))
        idx, _ = self._prepare(i, t_ns)
        self._rows[idx, INTERVAL_SCALE] = float_bits(emotion.interval_scale)
        self._magnitude_scale[idx] = emotion.magnitude_scale
        self._mutual_shift[idx] = emotion.mutual_shift
        self._bias_direction[idx] = emotion.bias_direction_deg
        biased_before = int(np.count_nonzero(self._bias_strength[idx]))
        self._bias_strength[idx] = emotion.bias_strength
        self._biased_agents += int(np.count_nonzero(self._bias_strength[idx])) - biased_before
        self._derive(idx)

    def set_mode(self, i: int | Sequence[int] | np.ndarray, mode: str, t_ns: int) -> None:
        """Switch the eye mode (MODES). Agents that start saccading decide their first saccade at `t`, once
        every other cue of that instant is in."""
        check_name(mode, MODES, "eye mode")
        idx, t = self._prepare(i, t_ns)
        code = MODES.index(mode)
        idx = idx[self._mode[idx] != code]
        if not idx.size:
            return
        yaw, pitch = self._shown_position(idx, t)
        old = self._mode[idx].copy()
        was_saccading = old >= SACCADE
        self._mode[idx] = code
        self._members_cache.clear()
        self._flight_stale = True  # eyes stopped mid-flight fixate where they are
        self._dirty.append(idx)
        rows = self._rows[idx]
        rows[:, MODE] = code
        fixate = ~was_saccading if code >= SACCADE else np.ones(idx.size, dtype=bool)
        # Eyes that leave the fixational movements keep the point they hold (the offset becomes the rest).
        fixate |= (old == FIXATIONAL) & (rows[:, END] <= t)
        rows[fixate, ONSET] = rows[fixate, END] = t
        floats = rows.view(np.float64)
        floats[fixate, FROM_YAW] = floats[fixate, TO_YAW] = yaw[fixate]
        floats[fixate, FROM_PITCH] = floats[fixate, TO_PITCH] = pitch[fixate]
        rows[fixate & ~was_saccading, NEXT_SACCADE] = t if code >= SACCADE else NEVER_NS
        if code < SACCADE:
            rows[:, NEXT_SACCADE] = NEVER_NS
        if code >= SACCADE_BLINK:
            self._schedule_blinks(rows, t)
        else:
            rows[:, NEXT_BLINK] = NEVER_NS
            rows[:, BLINK_ONSET] = -NEVER_NS
            self._live_blinks.cancel(idx)
        self._store(idx, rows)
        leaving = idx[old == FIXATIONAL]
        self._fixations.stop(leaving)
        self._fixating -= leaving.size
        if code == FIXATIONAL:
            self._fixating += idx.size
            self._start_fixations(idx, rows, np.maximum(rows[:, END], t))

    def set_head(
        self,
        i: int | Sequence[int] | np.ndarray,
        yaw_deg: float | np.ndarray,
        pitch_deg: float | np.ndarray,
        t_ns: int,
    ) -> None:
        """Report the head direction. A turn beyond the threshold since the last head-led saccade starts a
        saccade in the direction of the turn (the eyes lead the head)."""
        yaw, pitch = _finite_pair(yaw_deg, pitch_deg, "head")
        idx, t = self._prepare(i, t_ns)
        self._head_yaw[idx] = np.broadcast_to(yaw, idx.shape)
        self._head_pitch[idx] = np.broadcast_to(pitch, idx.shape)
        d_yaw = self._head_yaw[idx] - self._head_ref_yaw[idx]
        d_pitch = self._head_pitch[idx] - self._head_ref_pitch[idx]
        turn = np.hypot(d_yaw, d_pitch)
        turned = turn > self.params.head_turn_threshold_deg
        idx, d_yaw, d_pitch, turn = idx[turned], d_yaw[turned], d_pitch[turned], turn[turned]
        self._head_ref_yaw[idx] = self._head_yaw[idx]
        self._head_ref_pitch[idx] = self._head_pitch[idx]
        saccading = self._mode[idx] >= SACCADE
        idx, d_yaw, d_pitch, turn = idx[saccading], d_yaw[saccading], d_pitch[saccading], turn[saccading]
        if not idx.size:
            return
        rows = self._rows[idx]
        floats = rows.view(np.float64)
        amplitude = np.minimum(turn, self._max_magnitude[rows[:, ROLE]])
        to_yaw = self._clip_yaw(floats[:, TARGET_YAW] + amplitude * d_yaw / turn)
        to_pitch = self._clip_pitch(floats[:, TARGET_PITCH] + amplitude * d_pitch / turn)
        u = row_uniforms(rows, KEY_SACCADE, COUNTER_SACCADE, 3)  # hold, blink pull, blink follower
        hold = self._hold_s(rows, u[0], None)
        kind = np.full(idx.size, HEAD, np.int8)
        times = np.full(idx.size, t, dtype=np.int64)
        self._launch(idx, rows, times, to_yaw, to_pitch, kind, hold, u[1], u[2], magnitude=amplitude, head=True)
        self._store(idx, rows)

    def set_target(
        self,
        i: int | Sequence[int] | np.ndarray,
        yaw_deg: float | np.ndarray,
        pitch_deg: float | np.ndarray,
        t_ns: int,
    ) -> None:
        """Set where mutual gaze looks (head frame, degrees); away saccades centre on it too.

        An agent holding mutual gaze follows the target with a saccade at once, keeping its hold timer.
        """
        yaw, pitch = _finite_pair(yaw_deg, pitch_deg, "target")
        idx, t = self._prepare(i, t_ns)
        for agent in idx.tolist():
            self._target_sets.pop(agent, None)
        self._point_at(idx, yaw, pitch, t)

    def set_targets(
        self, i: int, yaw_deg: Sequence[float], pitch_deg: Sequence[float], weights: Sequence[float], t_ns: int
    ) -> None:
        """Let mutual gaze choose among several points (head frame, degrees): each decision draws one, with
        the given weights (for the people of a multi-party conversation). The choice is drawn at once too:
        an agent holding mutual gaze moves to it when it differs, keeping its hold timer."""
        yaws, pitches = _finite_pair(yaw_deg, pitch_deg, "target")
        w = np.asarray(weights, dtype=np.float64)
        if yaws.ndim != 1 or not (yaws.size == pitches.size == w.size) or yaws.size == 0:
            raise ValueError(f"targets need matching non-empty lists of yaw, pitch and weight, got "
                             f"{yaws.size}, {pitches.size}, {w.size}")
        if not (np.all(np.isfinite(w)) and np.all(w >= 0) and w.sum() > 0):
            raise ValueError(f"target weights must be non-negative with a positive sum, got {list(w)}")
        idx, t = self._prepare(i, t_ns)
        if idx.size != 1:
            raise ValueError(f"set_targets takes one agent index, got {i!r}")
        agent = int(idx[0])
        self._target_sets[agent] = (self._clip_yaw(yaws), self._clip_pitch(pitches), np.cumsum(w / w.sum())[:-1])
        self._target_draws.setdefault(agent, 0)
        chosen_yaw, chosen_pitch = self._choose_target(agent)
        self._point_at(idx, np.array([chosen_yaw]), np.array([chosen_pitch]), t)

    def _choose_target(self, agent: int) -> tuple[float, float]:
        yaws, pitches, cumulative = self._target_sets[agent]
        draw = self._target_draws[agent]
        self._target_draws[agent] = draw + 1
        u = float(uniform01(self._seed_target_choice, agent, draw))
        k = int(np.searchsorted(cumulative, u, side="right"))
        return float(yaws[k]), float(pitches[k])

    def _point_at(self, idx: np.ndarray, yaw: np.ndarray, pitch: np.ndarray, t: int) -> None:
        rows = self._rows[idx]
        floats = rows.view(np.float64)
        floats[:, TARGET_YAW] = self._clip_yaw(np.broadcast_to(yaw, idx.shape))
        floats[:, TARGET_PITCH] = self._clip_pitch(np.broadcast_to(pitch, idx.shape))
        follow = (rows[:, MODE] >= SACCADE) & (rows[:, KIND] == MUTUAL)
        follow &= (floats[:, TO_YAW] != floats[:, TARGET_YAW]) | (floats[:, TO_PITCH] != floats[:, TARGET_PITCH])
        j = np.flatnonzero(follow)
        if j.size:
            moving = rows[j]
            to_yaw, to_pitch = moving.view(np.float64)[:, TARGET_YAW], moving.view(np.float64)[:, TARGET_PITCH]
            u = row_uniforms(moving, KEY_SACCADE, COUNTER_SACCADE, 2)  # blink pull, blink follower
            times = np.full(j.size, t, dtype=np.int64)
            kind = np.full(j.size, MUTUAL, np.int8)
            self._launch(idx[j], moving, times, to_yaw, to_pitch, kind, None, u[0], u[1])
            rows[j] = moving
        self._store(idx, rows)

    # ------------------------------------------------------------------ the tick

    def tick(self, t_ns: int) -> GazeTick:
        """Advance every agent to `t_ns`; return the eye state there and the onsets since the last tick."""
        t = int(t_ns)
        if t < self._now_ns:
            raise ValueError(f"tick time {t} ns is before the previous tick at {self._now_ns} ns")
        due = np.flatnonzero(self._next_event <= t)
        if due.size:
            self._advance_due(due, t)
        self._now_ns = t
        yaw, pitch, lid = self._eyes[:, 0], self._eyes[:, 1], self._eyes[:, 2]
        n = self._n
        if self._dirty:
            changed = np.concatenate(self._dirty)
            self._dirty.clear()
            yaw[changed], pitch[changed] = self._resting(changed)
            lid[changed] = 0.0
        if self._flight_stale:
            self._flight_stale = False
            self._flights.keep_current(lambda agents: self._rows.take(agents, axis=0)[:, [ONSET, END]])
        self._flights.write_positions(t, yaw, pitch, self._resting)
        # After the flights (a landing writes the landing point): where the small saccades run between ticks
        # left the eyes that have landed; then the small saccades due now.
        self._fixations.write_pending(self._eyes, lambda agents: self._rows.reshape(-1).take(
            agents * N_COLUMNS + END) <= t)
        if self._fixating:
            self._fixations.run_due(self._fixations.due(t), t + 1, self._eyes)
        blinks = self._take_blinks()
        self._blink_lids(t, lid, blinks)
        self._apply_non_saccade_modes(t, yaw, pitch, lid)
        saccades = self._take_saccades()
        return GazeTick(t, read_only(yaw[:n]), read_only(pitch[:n]), read_only(lid[:n]), saccades, blinks)

    def _advance(self, idx: np.ndarray, t: int) -> None:
        """Process every timer event at or before `t` of the given agents, in time order per agent."""
        if idx.size:
            idx = idx[self._next_event[idx] <= t]
            if idx.size:
                self._advance_due(idx, t)

    def _advance_due(self, idx: np.ndarray, t: int) -> None:
        """Process the due agents' timer events in rounds until none is left at or before `t`: each round
        takes every agent's earliest event, a blink (a tie goes to the saccade, which may carry the blink)
        and, if that leaves its saccade the earliest and due, the saccade decision. At video rates one
        round does nearly everything; the next has the few blinks due after a decision.

        A blink works on its five columns of the row matrix in place: gathering whole rows and storing
        them back costs more. Decisions read and write most of a row, so they gather their rows as one
        batch. Which is which is read from the rows' timers, lines both then find in cache."""
        while idx.size:
            next_saccade, next_blink = column_pair(self._rows, idx, NEXT_SACCADE, NEXT_BLINK)
            blink_first = next_blink < next_saccade
            deciding = idx
            due: list[np.ndarray] = []
            if np.count_nonzero(blink_first):
                blinking = idx[blink_first]
                saccade_at = next_saccade[blink_first]
                blink_at = self._blink_in_place(blinking)
                self._next_event[blinking] = np.minimum(saccade_at, blink_at)
                decides = (saccade_at <= t) & (saccade_at <= blink_at)
                due.append(blinking[(blink_at <= t) & (blink_at < saccade_at)])  # another blink first
                deciding = np.concatenate([idx[~blink_first], blinking[decides]])
            if deciding.size:
                rows = self._rows.take(deciding, axis=0)
                self._decide(deciding, rows)
                self._store(deciding, rows)
                due.append(deciding[self._next_event.take(deciding) <= t])
            idx = np.concatenate(due) if due else deciding[:0]

    # ------------------------------------------------------------------ prepare

    def _prepare(self, i: int | Sequence[int] | np.ndarray, t_ns: int) -> tuple[np.ndarray, int]:
        """The agents' indices and the event's time, with their events before that time run: those at the
        time itself wait, so every cue of one instant is in before any decision of that instant."""
        idx = self._indices(i)
        t = max(int(t_ns), self._now_ns)
        self._advance(idx, t - 1)
        if self._fixating:
            self._fixations.advance(idx, t)
        return idx, t

    def _indices(self, i: int | Sequence[int] | np.ndarray) -> np.ndarray:
        idx = np.atleast_1d(np.asarray(i))
        if idx.dtype.kind not in "iu" or idx.ndim != 1:
            raise ValueError(f"agent index must be an integer or a 1-D integer array, got {i!r}")
        idx = idx.astype(np.int64)
        if idx.size and (idx.min() < 0 or idx.max() >= self._n):
            raise ValueError(f"agent index out of range [0, {self._n}): {i!r}")
        if idx.size > 1 and np.unique(idx).size != idx.size:
            raise ValueError(f"agent indices must be unique: {i!r}")
        return idx

    def _store(self, idx: np.ndarray, rows: np.ndarray) -> None:
        """Scatter gathered rows back and refresh the agents' next event times."""
        scatter_rows(self._rows, idx, rows)
        next_saccade, next_blink = rows[:, NEXT_SACCADE], rows[:, NEXT_BLINK]
        self._next_event[idx] = np.minimum(next_saccade, next_blink)

    def _derive(self, idx: np.ndarray) -> None:
        """Fold role and emotion into the columns a decision reads (see _decide)."""
        p = self.params
        rows = self._rows
        role = rows[idx, ROLE]
        span, factor = magnitude_map(p, self._max_magnitude[role], self._magnitude_scale[idx])
        rows[idx, MAG_SPAN] = float_bits(span)
        rows[idx, MAG_SCALE] = float_bits(factor)
        rows[idx, P_MUTUAL] = float_bits(mutual_probability(p, role, self._mutual_shift[idx]))
        rows[idx, HOLD_BASE] = role * (2 * HOLD_ROW)
        rows[idx, BLINK_SPREAD_NS] = float_bits(self._blink_spread_ns[role])

    # ------------------------------------------------------------------ decide

    def _decide(self, agents: np.ndarray, rows: np.ndarray) -> None:
        """The gaze timer expired (or the regime changed): choose mutual or away and launch the saccade.

        Six uniforms per agent in one draw: mutual or away, magnitude, direction, hold, and the gaze-evoked
        blink's chance and follower interval. Yaw and pitch go as separate 1-D arrays: numpy broadcasts
        over a trailing axis of two (yaw, pitch) several times slower than it runs along one column."""
        times = rows[:, NEXT_SACCADE].copy()
        floats = rows.view(np.float64)
        u = row_uniforms(rows, KEY_SACCADE, COUNTER_SACCADE, 6)
        if self._target_sets:
            self._choose_targets(agents, floats)
        away = u[0] >= floats[:, P_MUTUAL]
        least_pull = None
        if self._cued:
            away, least_pull = self._apply_cues(agents, away)
        magnitude = magnitude_from_map(u[1], self.params, floats[:, MAG_SPAN], floats[:, MAG_SCALE])
        step_yaw, step_pitch = self._direction(agents, u[2])
        to = []
        for step, target, limit in (
            (step_yaw, floats[:, TARGET_YAW], self.params.eye_yaw_limit_deg),
            (step_pitch, floats[:, TARGET_PITCH], self.params.eye_pitch_limit_deg),
        ):
            step *= magnitude
            step += target
            np.maximum(step, -limit, out=step)
            np.minimum(step, limit, out=step)
            to.append(np.where(away, step, target))
        hold = self._hold_s(rows, u[3], away)
        kind = away.view(np.int8)
        self._launch(agents, rows, times, to[0], to[1], kind, hold, u[4], u[5], magnitude, away, least_pull=least_pull)

    def _choose_targets(self, agents: np.ndarray, floats: np.ndarray) -> None:
        """Agents with several mutual-gaze points draw the one this decision aims at (and centres on)."""
        for j in np.flatnonzero(np.isin(agents, np.fromiter(self._target_sets, np.int64))).tolist():
            floats[j, TARGET_YAW], floats[j, TARGET_PITCH] = self._choose_target(int(agents[j]))

    def _apply_cues(self, agents: np.ndarray, away: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Forced outcomes (shift_gaze) and turn-boundary blinks for the deciding agents that have cues; the
        cues are spent. Returns the outcomes and, where a turn boundary asks for it, the least chance of a
        coupled blink."""
        cues = self._cues.take(agents)
        j = np.flatnonzero(cues)
        if not j.size:
            return away, None
        c = cues[j]
        away = away.copy()
        away[j] = ((c & FORCE_AWAY) != 0) | (away[j] & ((c & FORCE_MUTUAL) == 0))
        self._cues[agents[j]] = 0
        self._cued -= j.size
        turn = j[(c & TURN_BLINK) != 0]
        if not turn.size:
            return away, None
        least = np.zeros(agents.size)
        least[turn] = self.params.blink.turn_probability
        return away, least

    def _clear_cues(self, agents: np.ndarray) -> None:
        cued = agents[self._cues.take(agents) != 0]
        self._cues[cued] = 0
        self._cued -= cued.size

    def _direction(self, agents: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The unit step (yaw, pitch) of the drawn direction bin, tilted by the agents' emotions where they
        have one."""
        if self._biased_agents:
            strength = self._bias_strength[agents]
            if strength.any():
                index = direction_index_from_uniform(u, self.params, self._bias_direction[agents], strength)
                return self._bin_yaw_steps.take(index), self._bin_pitch_steps.take(index)
        index = direction_index_from_uniform(u, self.params)
        return self._bin_yaw_steps.take(index), self._bin_pitch_steps.take(index)

    def _hold_s(self, rows: np.ndarray, u: np.ndarray, away: np.ndarray | None) -> np.ndarray:
        """Inverse-CDF hold times (s) from the quantile table of each agent's (role, mutual/away), scaled by
        its emotion (generator.hold_from_uniform, on the side-by-side table); `away=None` means away for
        every row."""
        x = u * HOLD_TABLE_INTERVALS
        cell = x.astype(np.int64)  # u < 1, so the cell is at most the last one
        x -= cell
        cell += rows[:, HOLD_BASE]
        if away is None:
            cell += HOLD_ROW
        else:
            cell += away * HOLD_ROW  # a masked add (where=) is several times slower
        pairs = self._hold.take(cell, axis=0)
        hold = pairs[:, 0] * x
        hold += pairs[:, 1]
        hold *= rows.view(np.float64)[:, INTERVAL_SCALE]
        return hold

    # ------------------------------------------------------------------ launch

    def _launch(
        self,
        agents: np.ndarray,
        rows: np.ndarray,
        times: np.ndarray,
        to_yaw: np.ndarray,
        to_pitch: np.ndarray,
        kind: np.ndarray,
        hold_s: np.ndarray | None,
        u_pull: np.ndarray,
        u_follow: np.ndarray,
        magnitude: np.ndarray | None = None,
        drawn: np.ndarray | None = None,
        head: bool = False,
        least_pull: np.ndarray | None = None,
    ) -> None:
        """Start saccades at `times` from where each eye is then to (`to_yaw`, `to_pitch`). Without
        `hold_s` the hold timer is kept; a new hold supersedes the cues for the next decision.

        `magnitude` is the drawn Eyes Alive magnitude to report, where `drawn` (default: everywhere); the
        others report the amplitude moved. `least_pull`: the least chance of a coupled blink, per agent."""
        floats = rows.view(np.float64)
        if self._cued and hold_s is not None:
            self._clear_cues(agents)
        fixating = np.flatnonzero(rows[:, MODE] == FIXATIONAL) if self._fixating else agents[:0]
        whole = fixating.size == agents.size  # the whole batch fixates: no gathers
        if fixating.size:  # the small saccades before the launch run first: the eye starts where they left it
            fixating_agents = agents if whole else agents.take(fixating)
            fixating_times = times if whole else times.take(fixating)
            self._fixations.advance(fixating_agents, fixating_times)
        start_yaw, start_pitch = self._position(rows, times)
        if fixating.size:
            landed = fixating[fixating_times >= rows[:, END].take(fixating)]
            off_yaw, off_pitch = self._fixations.offsets(agents.take(landed))
            start_yaw[landed] = self._clip_yaw(start_yaw[landed] + off_yaw)
            start_pitch[landed] = self._clip_pitch(start_pitch[landed] + off_pitch)
        delta_yaw, delta_pitch = to_yaw - start_yaw, to_pitch - start_pitch
        amplitude = np.hypot(delta_yaw, delta_pitch)
        duration = amplitude * self._d_ns_per_deg  # the main sequence, Eyes Alive eq. 2
        duration += self._d0_ns
        duration_ns = np.rint(duration, out=duration).astype(np.int64)
        end = times + duration_ns
        if hold_s is not None:
            next_saccade = np.rint(hold_s * _NS).astype(np.int64)
            next_saccade += end
        else:
            next_saccade = np.maximum(rows[:, NEXT_SACCADE], end)
            hold_s = (next_saccade - end) * 1e-9
        rows[:, ONSET], rows[:, END], rows[:, NEXT_SACCADE] = times, end, next_saccade
        floats[:, FROM_YAW], floats[:, FROM_PITCH] = start_yaw, start_pitch
        floats[:, TO_YAW], floats[:, TO_PITCH] = to_yaw, to_pitch
        rows[:, KIND] = kind
        self._couple_blinks(agents, rows, times, amplitude, u_pull, u_follow, head, least_pull)
        self._flights.add(agents, rows[:, FLIGHT])
        if fixating.size:
            self._start_fixations(fixating_agents, rows if whole else rows.take(fixating, axis=0),
                                  end if whole else end.take(fixating))
        if magnitude is None:
            magnitude = amplitude
        elif drawn is not None:
            magnitude = np.where(drawn, magnitude, amplitude)
        direction = np.arctan2(delta_pitch, delta_yaw)
        direction *= DEGREES_PER_RADIAN
        # np.mod(direction, 360) for angles within one turn, without its slow floating remainder: negative
        # angles go up a turn, the others get 0.0 added, which turns -0.0 into 0.0 as np.mod does.
        direction += (direction < 0.0) * 360.0
        duration *= 1e-9
        floats_out = np.array(
            (start_yaw, start_pitch, to_yaw, to_pitch, magnitude, amplitude, direction, duration, hold_s)
        )
        self._saccade_chunks.append((agents, times, kind, floats_out))

    def _position(self, rows: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Eye yaw and pitch at `times` along each row's current saccade; landed eyes skip the velocity
        profile."""
        floats = rows.view(np.float64)
        yaw, pitch = floats[:, TO_YAW].copy(), floats[:, TO_PITCH].copy()
        in_flight = np.flatnonzero(times < rows[:, END])
        if in_flight.size:
            self._flight_stale = True  # these eyes are relaunched or stopped mid-flight
            flying = rows.take(in_flight, axis=0)
            onset = flying[:, ONSET]
            # A mode switch stamped ahead of the last tick leaves a zero-length "saccade" (a fixation)
            # starting in the future: asked before it, the eye is at its start (tau < 0), so dividing by at
            # least 1 ns gives the same position without a division by zero.
            duration = np.maximum(flying[:, END] - onset, 1)
            progress = saccade_progress((times.take(in_flight) - onset) / duration)
            remaining = 1.0 - progress  # this form is exact at both ends of the saccade
            flying_floats = flying.view(np.float64)
            for position, start, end in ((yaw, FROM_YAW, TO_YAW), (pitch, FROM_PITCH, TO_PITCH)):
                position[in_flight] = flying_floats[:, start] * remaining + flying_floats[:, end] * progress
        return yaw, pitch

    # ------------------------------------------------------------------ fixate

    def _start_fixations(self, agents: np.ndarray, rows: np.ndarray, landing_ns: np.ndarray) -> None:
        """New fixations where the rows' saccades land, in their role, gaze (mutual or not) and emotion."""
        floats = rows.view(np.float64)
        self._fixations.start(agents, landing_ns, floats[:, TO_YAW], floats[:, TO_PITCH],
                              (rows[:, KIND] == MUTUAL).astype(np.int64), rows[:, ROLE], floats[:, INTERVAL_SCALE])

    # ------------------------------------------------------------------ blink

    def _schedule_blinks(self, rows: np.ndarray, t: int) -> None:
        """Draw a fresh next blink from `t` for the rows with the statistical blink model."""
        with_model = np.flatnonzero(rows[:, MODE] >= SACCADE_BLINK)
        if with_model.size:
            sub = rows[with_model]
            u = row_uniforms(sub, KEY_BLINK, COUNTER_BLINK, 1)[0]
            sub[:, NEXT_BLINK] = t + self._blink_interval_ns(sub.view(np.float64)[:, BLINK_SPREAD_NS], u)
            rows[with_model] = sub

    def _blink_in_place(self, agents: np.ndarray) -> np.ndarray:
        """The blink timers of these agents expired: blink then and draw each one's next spontaneous blink, on
        their columns of the row matrix. Returns the next blink times."""
        flat = self._rows.reshape(-1)
        cells = agents * N_COLUMNS
        cells += NEXT_BLINK
        times = flat.take(cells)
        next_blink = times + self._blink_interval_ns(
            flat.take(cells + (BLINK_SPREAD_NS - NEXT_BLINK)).view(np.float64),
            uniform_draws(
                flat.take(cells + (COUNTER_BLINK - NEXT_BLINK)).view(np.uint64),
                flat.take(cells + (KEY_BLINK - NEXT_BLINK)).view(np.uint64),
                1,
            )[0],
        )
        flat[cells] = next_blink  # flat is a view: the matrix is C-contiguous (aligned_rows)
        cells += COUNTER_BLINK - NEXT_BLINK
        flat[cells] += 1
        cells += BLINK_ONSET - COUNTER_BLINK
        flat[cells] = times
        self._blink_chunks.append((agents, times))
        return next_blink

    def _couple_blinks(
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
        blink = self.params.blink
        if head:
            pull = u_pull < blink.head_turn_probability
        else:
            chance = evoked_blink_probability(amplitude, blink)
            if least_pull is not None:
                np.maximum(chance, least_pull, out=chance)
            pull = u_pull < chance
        next_blink = rows[:, NEXT_BLINK]
        pull &= next_blink - times <= self._pull_window_ns
        pull &= rows[:, MODE] >= SACCADE_BLINK
        j = np.flatnonzero(pull)
        if j.size:  # through 1-D column views: a (rows, column) fancy index takes the slow general path
            interval = self._blink_interval_ns(rows.view(np.float64)[:, BLINK_SPREAD_NS][j], u_follow[j])
            next_blink[j] += interval
            pulled, onset = agents[j], times[j]
            rows[:, BLINK_ONSET][j] = onset
            self._blink_chunks.append((pulled, onset))

    def _blink_interval_ns(self, spread_ns: np.ndarray, u: np.ndarray) -> np.ndarray:
        return blink_interval_ns(spread_ns, u, self.params.blink)

    def _blink_lids(self, t: int, lid: np.ndarray, new: BlinkOnsets) -> None:
        """Write the lids of the agents whose blink is in progress. Of the blinks started since the last
        tick (`new`) only each agent's latest joins: an earlier one was cut short by it, or by a switch of
        mode (which resets the agent's latest blink onset)."""
        agents, onsets = new.agent, new.onset_ns
        if agents.size:
            latest = self._rows.reshape(-1).take(agents * N_COLUMNS + BLINK_ONSET) == onsets
            if not latest.all():
                agents, onsets = agents[latest], onsets[latest]
        self._live_blinks.update(t, lid, agents, onsets)

    # ------------------------------------------------------------------ report

    def _resting(self, agents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where the agents' eyes rest once their current saccade has landed (both in one cache line; a
        whole-row gather would read three)."""
        return column_pair(self._rows.view(np.float64), agents, TO_YAW, TO_PITCH)

    def _noise_position(self, idx: np.ndarray, t: int) -> tuple[np.ndarray, np.ndarray]:
        p = self.params
        floats = self._rows.view(np.float64)
        x = t * 1e-9 * p.noise_frequency_hz
        stream = idx.astype(np.uint64) * np.uint64(2)
        yaw = floats[idx, TARGET_YAW] + p.noise_yaw_amplitude_deg * perlin1d(x, self._seed_noise, stream)
        pitch = floats[idx, TARGET_PITCH] + p.noise_pitch_amplitude_deg * perlin1d(
            x, self._seed_noise, stream + np.uint64(1)
        )
        return self._clip_yaw(yaw), self._clip_pitch(pitch)

    def _shown_position(self, idx: np.ndarray, t: int) -> tuple[np.ndarray, np.ndarray]:
        """Where each eye is at `t` in its current mode."""
        rows = self._rows[idx]
        stale = self._flight_stale  # only looking: nothing is relaunched here
        yaw, pitch = self._position(rows, np.full(idx.size, t, dtype=np.int64))
        self._flight_stale = stale
        mode = self._mode[idx]
        static = mode == STATIC
        floats = rows.view(np.float64)
        yaw[static], pitch[static] = floats[static, TARGET_YAW], floats[static, TARGET_PITCH]
        noisy = mode == NOISE
        if noisy.any():
            yaw[noisy], pitch[noisy] = self._noise_position(idx[noisy], t)
        held = np.flatnonzero((mode == FIXATIONAL) & (rows[:, END] <= t))
        if held.size:
            off_yaw, off_pitch = self._fixations.offsets(idx[held])
            yaw[held] = self._clip_yaw(yaw[held] + off_yaw)
            pitch[held] = self._clip_pitch(pitch[held] + off_pitch)
        return yaw, pitch

    def _members(self, mode: int) -> np.ndarray:
        if mode not in self._members_cache:
            self._members_cache[mode] = np.flatnonzero(self._mode == mode)
        return self._members_cache[mode]

    def _apply_non_saccade_modes(self, t: int, yaw: np.ndarray, pitch: np.ndarray, lid: np.ndarray) -> None:
        static = self._members(STATIC)
        if static.size:
            floats = self._rows.view(np.float64)
            yaw[static], pitch[static] = floats[static, TARGET_YAW], floats[static, TARGET_PITCH]
        noisy = self._members(NOISE)
        if noisy.size:
            yaw[noisy], pitch[noisy] = self._noise_position(noisy, t)
        for mode in (NOISE, SACCADE):
            members = self._members(mode)
            if members.size:
                lid[members] = perlin_blink(t * 1e-9, self._seed_perlin_blink, members.astype(np.uint64))

    def _take_saccades(self) -> SaccadeOnsets:
        chunks = self._saccade_chunks
        chunks.extend(self._fixations.take_onsets())  # those run before a switch out of the mode too
        if not chunks:
            return SaccadeOnsets.empty()
        if len(chunks) == 1:
            agent, onset, kind, floats = chunks[0]
        else:
            agent = np.concatenate([chunk[0] for chunk in chunks])
            onset = np.concatenate([chunk[1] for chunk in chunks])
            kind = np.concatenate([chunk[2] for chunk in chunks])
            floats = np.concatenate([chunk[3] for chunk in chunks], axis=1)
        chunks.clear()
        order, agent, onset = sort_onsets(agent, onset, self._n)
        return SaccadeOnsets.from_columns(
            agent, onset, kind.take(order), floats.take(order, axis=1)
        )  # take: several times faster than fancy indexing, most of all on the 2-D floats

    def _take_blinks(self) -> BlinkOnsets:
        chunks = self._blink_chunks
        if not chunks:
            return BlinkOnsets.empty()
        if len(chunks) == 1:
            agent, onset = chunks[0]
        else:
            agent = np.concatenate([c[0] for c in chunks])
            onset = np.concatenate([c[1] for c in chunks])
        chunks.clear()
        _, agent, onset = sort_onsets(agent, onset, self._n)
        return BlinkOnsets(agent, onset)

    def _clip_yaw(self, yaw: np.ndarray) -> np.ndarray:
        limit = self.params.eye_yaw_limit_deg
        return np.clip(np.asarray(yaw, dtype=np.float64), -limit, limit)

    def _clip_pitch(self, pitch: np.ndarray) -> np.ndarray:
        limit = self.params.eye_pitch_limit_deg
        return np.clip(np.asarray(pitch, dtype=np.float64), -limit, limit)


def _finite_pair(
    yaw: float | Sequence[float] | np.ndarray, pitch: float | Sequence[float] | np.ndarray, what: str
) -> tuple[np.ndarray, np.ndarray]:
    yaw_a = np.asarray(yaw, dtype=np.float64)
    pitch_a = np.asarray(pitch, dtype=np.float64)
    if not (np.all(np.isfinite(yaw_a)) and np.all(np.isfinite(pitch_a))):
        raise ValueError(f"{what} yaw/pitch must be finite numbers, got {yaw!r}, {pitch!r}")
    return yaw_a, pitch_a
