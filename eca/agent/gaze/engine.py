"""GazeEngine: the Attention Monitor, Parameter Generator and Saccade Synthesizer for N agents at once.

The model is that of reference.py, one agent written step by step; this is the same model for whole crowds
(tests/test_gaze_reference.py holds the two to identical trajectories). Every agent's state lives in numpy
arrays (state.py). A tick compares one next-event-time array against the clock and gathers only the agents
whose gaze timer or blink timer expired; their events are processed at their exact scheduled times (never
quantised to the tick), so the trajectory does not depend on the tick rate. Each agent draws from its own
counter-based stream (seed, agent index, per-agent counter), so adding an agent leaves every other agent's
trajectory unchanged.

The steps, each in its module: events from outside *prepare* their agents (run what was due before, then
apply the cue: this module); the gaze timer expiring makes a *decision* (mutual or away, magnitude,
direction, hold: decide.py); a decision, a head turn or a moved target *launches* a saccade (launch.py); in
mode saccade+noise+blink the eye *fixates* between saccades with small saccades and drift (fixation.py);
spontaneous and gaze-evoked *blinks* run on their own timer (blink_timers.py); the modes without Eyes Alive
saccades move the eyes their own way (modes.py); and the tick *reports* every eye's state and the onsets
(onsets.py).

What a tick costs, with a million agents, is random access to per-agent state, not arithmetic; with a
hundred thousand, the fixed cost of each numpy call. Hence the layout (state.py, rows.py), and:

- Role and emotion are folded into per-agent derived columns (P(mutual), the magnitude map, the hold
  table row, the blink spread) when they change, so a decision needs no table look-ups by role.
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
saccades, on their own timers and stream; a launch starts from where the small saccades due before it left
the eye, and starts a new fixation where it lands. A tick runs every agent's small saccades due by then
in one batch before its timer events (each agent's only up to its decision), so the launches of the
decisions find them run; a launch from an event between ticks runs them itself.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from eca.agent.gaze.blink_timers import BlinkTimers
from eca.agent.gaze.decide import Decider
from eca.agent.gaze.events import BlinkOnsets, GazeTick, SaccadeOnsets
from eca.agent.gaze.fixation import Fixations
from eca.agent.gaze.generator import (
    BLINK_STREAM,
    FIXATION_STREAM,
    NOISE_STREAM,
    PERLIN_BLINK_STREAM,
    SACCADE_STREAM,
    TARGET_CHOICE_STREAM,
    derive_seed,
)
from eca.agent.gaze.inflight import Flights
from eca.agent.gaze.launch import Launcher
from eca.agent.gaze.modes import EyeModes
from eca.agent.gaze.onsets import OnsetLog
from eca.agent.gaze.params import (
    DEFAULT_ROLE,
    FIXATIONAL,
    MODES,
    ROLES,
    SACCADE,
    SACCADE_BLINK,
    GazeParams,
    check_name,
)
from eca.agent.gaze.rows import (
    BLINK_ONSET,
    COUNTER_SACCADE,
    END,
    FROM_PITCH,
    FROM_YAW,
    INTERVAL_SCALE,
    KEY_BLINK,
    KEY_SACCADE,
    KIND,
    MODE,
    N_COLUMNS,
    NEXT_BLINK,
    NEXT_SACCADE,
    ONSET,
    ROLE,
    TARGET_PITCH,
    TARGET_YAW,
    TO_PITCH,
    TO_YAW,
    column_pair,
    float_bits,
    read_only,
    row_uniforms,
    stream_keys,
)
from eca.agent.gaze.state import (
    FORCE_AWAY,
    FORCE_MUTUAL,
    HEAD,
    MUTUAL,
    NEVER_NS,
    TURN_BLINK,
    GazeState,
)

__all__ = ["GazeEngine", "GazeTick", "SaccadeOnsets", "BlinkOnsets", "DEFAULT_ROLE", "derive_seed"]

TOWARD: dict[str, int] = {"mutual": FORCE_MUTUAL, "away": FORCE_AWAY}


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
        self._seed_perlin_blink = derive_seed(self.seed, PERLIN_BLINK_STREAM)
        self._now_ns = int(start_ns)
        p = self.params
        self._state = state = GazeState()
        self._log = OnsetLog()
        self._fixations = Fixations(p, derive_seed(self.seed, FIXATION_STREAM))
        self._flights = Flights()
        self._blinks = BlinkTimers(p.blink, state, self._log)
        self._decider = Decider(p, state, derive_seed(self.seed, TARGET_CHOICE_STREAM))
        self._launcher = Launcher(p, state, self._fixations, self._flights, self._blinks, self._log)
        self._modes = EyeModes(p, state, self._launcher, self._fixations, derive_seed(self.seed, NOISE_STREAM),
                               self._seed_perlin_blink)
        self._dirty: list[np.ndarray] = []  # agents whose mode changed: resting position and open lid again
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
        state = self._state
        new = np.arange(state.n, state.n + count, dtype=np.int64)
        rows = np.zeros((count, N_COLUMNS), np.int64)  # the bits of 0.0 are 0: eyes at the primary position
        rows[:, ONSET] = rows[:, END] = t
        rows[:, NEXT_SACCADE] = t if mode_code >= SACCADE else NEVER_NS  # the first decision, at t
        rows[:, NEXT_BLINK] = NEVER_NS
        rows[:, BLINK_ONSET] = -NEVER_NS
        rows[:, KEY_SACCADE] = stream_keys(self._seed_saccade, new)
        rows[:, KEY_BLINK] = stream_keys(self._seed_blink, new)
        rows[:, ROLE], rows[:, MODE], rows[:, KIND] = ROLES.index(role), mode_code, MUTUAL
        rows[:, INTERVAL_SCALE] = float_bits(1.0)
        state.grow(rows, mode_code)
        self._blinks.grow(state.n)
        self._fixations.grow(count)
        if mode_code == FIXATIONAL:
            state.fixating += count
        self._decider.derive(new)
        fresh = state.rows[new]
        self._blinks.schedule(fresh, t)
        state.store(new, fresh)
        return new

    @property
    def n_agents(self) -> int:
        return self._state.n

    @property
    def now_ns(self) -> int:
        return self._now_ns

    @property
    def _rows(self) -> np.ndarray:
        """The per-agent row matrix (rows.py's columns), for tests and tools that inspect the state."""
        return self._state.rows

    def role_of(self, i: int) -> str:
        return ROLES[int(self._state.rows[self._state.indices(i)[0], ROLE])]

    def mode_of(self, i: int) -> str:
        return MODES[int(self._state.mode[self._state.indices(i)[0]])]

    # ------------------------------------------------------------------ the Attention Monitor's inputs

    def set_role(self, i: int | Sequence[int] | np.ndarray, role: str, t_ns: int) -> None:
        """Switch the conversational role; agents whose role changes decide a new saccade at `t`, once
        every other cue of that instant is in (the decision runs at the next tick or later event). In mode
        saccade+noise+blink the turn boundary may bring a blink ([blink] turn_probability)."""
        check_name(role, ROLES, "role")
        idx, t = self._prepare(i, t_ns)
        state = self._state
        code = ROLES.index(role)
        idx = idx[state.rows[idx, ROLE] != code]
        if not idx.size:
            return
        state.rows[idx, ROLE] = code
        self._decider.derive(idx)
        rows = state.rows[idx]
        rows[rows[:, MODE] >= SACCADE, NEXT_SACCADE] = t
        self._blinks.schedule(rows, t)
        state.store(idx, rows)
        state.cue(idx[rows[:, MODE] == FIXATIONAL], TURN_BLINK, 0)

    def shift_gaze(self, i: int | Sequence[int] | np.ndarray, toward: str, t_ns: int) -> None:
        """Make the next decision now, with its outcome fixed: "mutual" (at the gaze target) or "away"
        (magnitude, direction and hold drawn as usual). For turn-taking gaze: a speaker looks away as a
        long turn starts and back at the listener as it ends (Kendon 1967)."""
        check_name(toward, tuple(TOWARD), "gaze shift")
        idx, t = self._prepare(i, t_ns)
        state = self._state
        idx = idx[state.mode[idx] >= SACCADE]
        if idx.size:
            state.rows[idx, NEXT_SACCADE] = t
            state.next_event[idx] = np.minimum(state.next_event[idx], t)
            state.cue(idx, TOWARD[toward], FORCE_MUTUAL | FORCE_AWAY)

    def blink_at(self, i: int | Sequence[int] | np.ndarray, t_ns: int) -> np.ndarray:
        """Blink now if a blink is due within the pull window (statistical blink modes only): the due blink
        is pulled forward, as a gaze shift pulls it, so the configured rates still hold. For listener
        feedback at a partner's pause. Returns the agents that blinked."""
        idx, t = self._prepare(i, t_ns)
        rows = self._state.rows[idx]
        j = self._blinks.pull(idx, rows, t)
        if j.size:
            self._state.store(idx, rows)
        return idx[j]

    def set_emotion(self, i: int | Sequence[int] | np.ndarray, name: str, intensity: float, t_ns: int) -> None:
        """Modulate the statistics of every later saccade decision (configs/gaze_emotions.toml)."""
        emotion = self.params.emotion(name, float(intensity))
        idx, _ = self._prepare(i, t_ns)
        state = self._state
        state.rows[idx, INTERVAL_SCALE] = float_bits(emotion.interval_scale)
        state.magnitude_scale[idx] = emotion.magnitude_scale
        state.mutual_shift[idx] = emotion.mutual_shift
        state.bias_direction[idx] = emotion.bias_direction_deg
        biased_before = int(np.count_nonzero(state.bias_strength[idx]))
        state.bias_strength[idx] = emotion.bias_strength
        state.biased_agents += int(np.count_nonzero(state.bias_strength[idx])) - biased_before
        self._decider.derive(idx)

    def set_mode(self, i: int | Sequence[int] | np.ndarray, mode: str, t_ns: int) -> None:
        """Switch the eye mode (MODES). Agents that start saccading decide their first saccade at `t`, once
        every other cue of that instant is in."""
        check_name(mode, MODES, "eye mode")
        idx, t = self._prepare(i, t_ns)
        state = self._state
        code = MODES.index(mode)
        idx = idx[state.mode[idx] != code]
        if not idx.size:
            return
        yaw, pitch = self._modes.shown_position(idx, t)
        old = state.mode[idx].copy()
        was_saccading = old >= SACCADE
        state.set_modes(idx, code)
        state.flight_stale = True  # eyes stopped mid-flight fixate where they are
        self._dirty.append(idx)
        rows = state.rows[idx]
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
            self._blinks.schedule(rows, t)
        else:
            self._blinks.stop(rows, idx)
        state.store(idx, rows)
        leaving = idx[old == FIXATIONAL]
        self._fixations.stop(leaving)
        state.fixating -= leaving.size
        if code == FIXATIONAL:
            state.fixating += idx.size
            self._launcher.start_fixations(idx, rows, np.maximum(rows[:, END], t), floats[:, TO_YAW : TO_PITCH + 1].T)

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
        state = self._state
        state.head_yaw[idx] = np.broadcast_to(yaw, idx.shape)
        state.head_pitch[idx] = np.broadcast_to(pitch, idx.shape)
        d_yaw = state.head_yaw[idx] - state.head_ref_yaw[idx]
        d_pitch = state.head_pitch[idx] - state.head_ref_pitch[idx]
        turn = np.hypot(d_yaw, d_pitch)
        turned = turn > self.params.head_turn_threshold_deg
        idx, d_yaw, d_pitch, turn = idx[turned], d_yaw[turned], d_pitch[turned], turn[turned]
        state.head_ref_yaw[idx] = state.head_yaw[idx]
        state.head_ref_pitch[idx] = state.head_pitch[idx]
        saccading = state.mode[idx] >= SACCADE
        idx, d_yaw, d_pitch, turn = idx[saccading], d_yaw[saccading], d_pitch[saccading], turn[saccading]
        if not idx.size:
            return
        rows = state.rows[idx]
        floats = rows.view(np.float64)
        amplitude = np.minimum(turn, self._decider.max_magnitude[rows[:, ROLE]])
        to = np.stack([
            self._clip_yaw(floats[:, TARGET_YAW] + amplitude * d_yaw / turn),
            self._clip_pitch(floats[:, TARGET_PITCH] + amplitude * d_pitch / turn),
        ])
        u = row_uniforms(rows, KEY_SACCADE, COUNTER_SACCADE, 3)  # hold, blink pull, blink follower
        hold = self._decider.hold_s(rows, u[0], None)
        kind = np.full(idx.size, HEAD, np.int8)
        times = np.full(idx.size, t, dtype=np.int64)
        self._launcher.launch(idx, rows, times, to, kind, hold, u[1], u[2], magnitude=amplitude, head=True)
        state.store(idx, rows)

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
        self._decider.drop_targets(idx)
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
        self._decider.set_targets(agent, self._clip_yaw(yaws), self._clip_pitch(pitches), np.cumsum(w / w.sum())[:-1])
        chosen_yaw, chosen_pitch = self._decider.choose_target(agent)
        self._point_at(idx, np.array([chosen_yaw]), np.array([chosen_pitch]), t)

    def _point_at(self, idx: np.ndarray, yaw: np.ndarray, pitch: np.ndarray, t: int) -> None:
        rows = self._state.rows[idx]
        floats = rows.view(np.float64)
        floats[:, TARGET_YAW] = self._clip_yaw(np.broadcast_to(yaw, idx.shape))
        floats[:, TARGET_PITCH] = self._clip_pitch(np.broadcast_to(pitch, idx.shape))
        follow = (rows[:, MODE] >= SACCADE) & (rows[:, KIND] == MUTUAL)
        follow &= (floats[:, TO_YAW] != floats[:, TARGET_YAW]) | (floats[:, TO_PITCH] != floats[:, TARGET_PITCH])
        j = np.flatnonzero(follow)
        if j.size:
            moving = rows[j]
            to = moving.view(np.float64)[:, TARGET_YAW : TARGET_PITCH + 1].T
            u = row_uniforms(moving, KEY_SACCADE, COUNTER_SACCADE, 2)  # blink pull, blink follower
            times = np.full(j.size, t, dtype=np.int64)
            kind = np.full(j.size, MUTUAL, np.int8)
            self._launcher.launch(idx[j], moving, times, to, kind, None, u[0], u[1])
            rows[j] = moving
        self._state.store(idx, rows)

    # ------------------------------------------------------------------ the tick

    def tick(self, t_ns: int) -> GazeTick:
        """Advance every agent to `t_ns`; return the eye state there and the onsets since the last tick.

        The eye state is written in the order its sources ran, so the latest wins: the eyes that landed
        (inflight.Flights.land), then the small saccades of the fixations (mode saccade+noise+blink) that
        follow landings, then the timer events, whose launches put more eyes in flight; then every eye in
        flight (no eye in flight has small saccades), and the small saccades the timer events' new
        fixations may already have due."""
        t = int(t_ns)
        if t < self._now_ns:
            raise ValueError(f"tick time {t} ns is before the previous tick at {self._now_ns} ns")
        state = self._state
        due = state.due(t)
        eyes, lid = state.eyes, state.lid
        yaw, pitch = eyes[:, 0], eyes[:, 1]
        n = state.n
        if self._dirty:
            changed = np.concatenate(self._dirty)
            self._dirty.clear()
            yaw[changed], pitch[changed] = column_pair(state.rows.view(np.float64), changed, TO_YAW, TO_PITCH)
            lid[changed] = 0.0
        if state.flight_stale:
            self._keep_current_flights()
        self._flights.land(t, eyes)
        if state.fixating:
            self._run_small_saccades(t, eyes)
        if due.size:
            self._advance_due(due, t, fixations_run=True)
        self._now_ns = t
        if state.flight_stale:  # a decision relaunched an eye in flight (shift_gaze)
            self._keep_current_flights()
        self._flights.write_positions(t, eyes)
        # After the flights (a landing writes the landing point): where the small saccades run between ticks
        # left the eyes that have landed; then those of the fixations the decisions started.
        self._fixations.write_pending(eyes, lambda agents: state.rows.reshape(-1).take(
            agents * N_COLUMNS + END) <= t)
        if state.fixating and due.size:
            restarted = due[self._fixations.next_ns.take(due) <= t]
            if restarted.size:
                self._fixations.run_due(restarted, t + 1, eyes)
        blinks = self._log.take_blinks(n)
        self._blinks.write_lids(t, lid, blinks)
        self._modes.write(t, yaw, pitch, lid)
        saccades = self._log.take_saccades(self._fixations.take_onsets(), n)
        return GazeTick(t, read_only(yaw[:n]), read_only(pitch[:n]), read_only(lid[:n]), saccades, blinks)

    def _keep_current_flights(self) -> None:
        state = self._state
        state.flight_stale = False
        self._flights.keep_current(lambda agents: state.rows.take(agents, axis=0)[:, [ONSET, END]])

    def _run_small_saccades(self, t: int, eyes: np.ndarray) -> None:
        """Run the small saccades due by `t` of mode saccade+noise+blink, before the timer events.

        An agent whose gaze timer also expires runs them only up to its decision, whose launch restarts
        its fixation: the small saccades it would run first (launch.py), run here in the same batch as
        everyone's, and their landings are marked for write_pending, as the launch's own are. (Blinks and
        small saccades share no state: they run in either order.)"""
        fixations = self._fixations
        agents = fixations.due(t)
        if not agents.size:
            return
        state = self._state
        flat = state.rows.reshape(-1)
        timed = state.due_mask.take(agents).nonzero()[0]  # their timers expire too: tick() computed which
        decide_at = flat.take(agents.take(timed) * N_COLUMNS + NEXT_SACCADE)
        decides = decide_at <= t
        if not np.count_nonzero(decides):
            fixations.run_due(agents, t + 1, eyes)
            return
        deciding, decide_at = timed[decides], decide_at[decides]
        steps = fixations.next_ns.take(agents.take(deciding)) < decide_at
        fixations.mark_unwritten(agents.take(deciding[steps]))
        before = np.full(agents.size, t + 1, np.int64)
        before[deciding] = decide_at
        if np.count_nonzero(steps) < steps.size:
            keep = np.ones(agents.size, dtype=bool)
            keep[deciding[~steps]] = False
            agents, before = agents[keep], before[keep]
        fixations.run_due(agents, before, eyes)

    def _advance(self, idx: np.ndarray, t: int) -> None:
        """Process every timer event at or before `t` of the given agents, in time order per agent."""
        if idx.size:
            idx = idx[self._state.next_event[idx] <= t]
            if idx.size:
                self._advance_due(idx, t)

    def _advance_due(self, idx: np.ndarray, t: int, fixations_run: bool = False) -> None:
        """Process the due agents' timer events in rounds until none is left at or before `t`: each round
        takes every agent's earliest event, a blink (a tie goes to the saccade, which may carry the blink)
        and, if that leaves its saccade the earliest and due, the saccade decision. At video rates one
        round does nearly everything; the next has the few blinks due after a decision.

        A blink works on its five columns of the row matrix in place: gathering whole rows and storing
        them back costs more. Decisions read and write most of a row, so they gather their rows as one
        batch. Which is which is read from the rows' timers, lines both then find in cache.

        `fixations_run`: the small saccades before each agent's first decision have run (tick)."""
        state = self._state
        while idx.size:
            next_saccade, next_blink = column_pair(state.rows, idx, NEXT_SACCADE, NEXT_BLINK)
            blink_first = next_blink < next_saccade
            deciding = idx
            due: list[np.ndarray] = []
            if np.count_nonzero(blink_first):
                blinking = idx[blink_first]
                saccade_at = next_saccade[blink_first]
                blink_at = self._blinks.fire(blinking)
                state.next_event[blinking] = np.minimum(saccade_at, blink_at)
                decides = (saccade_at <= t) & (saccade_at <= blink_at)
                due.append(blinking[(blink_at <= t) & (blink_at < saccade_at)])  # another blink first
                deciding = np.concatenate([idx[~blink_first], blinking[decides]])
            if deciding.size:
                rows = state.rows.take(deciding, axis=0)
                d = self._decider.decide(deciding, rows)
                self._launcher.launch(deciding, rows, d.times, d.to, d.kind, d.hold_s, d.u_pull, d.u_follow,
                                      d.magnitude, d.away, least_pull=d.least_pull, fixations_run=fixations_run)
                state.store(deciding, rows)
                due.append(deciding[state.next_event.take(deciding) <= t])
            idx = np.concatenate(due) if due else deciding[:0]
            fixations_run = False  # a second decision this tick: its new fixation's small saccades come first

    # ------------------------------------------------------------------ prepare

    def _prepare(self, i: int | Sequence[int] | np.ndarray, t_ns: int) -> tuple[np.ndarray, int]:
        """The agents' indices and the event's time, with their events before that time run: those at the
        time itself wait, so every cue of one instant is in before any decision of that instant."""
        idx = self._state.indices(i)
        t = max(int(t_ns), self._now_ns)
        self._advance(idx, t - 1)
        if self._state.fixating:
            self._fixations.advance(idx, t)
        return idx, t

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
