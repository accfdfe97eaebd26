"""The gaze model for one agent, step by step: the reference that the vectorised GazeEngine must match.

`GazeEngine` (engine.py) runs the model for whole crowds in arrays laid out for memory traffic (rows.py).
`ReferenceAgent` is the same model written the obvious way, one object per agent: its timers (the next
saccade decision, the next spontaneous blink, the next small saccade of mode saccade+noise+blink) run in
time order, each event a few lines. tests/test_gaze_reference.py drives both through random event
sequences and requires identical trajectories; bench/gaze_engine.py times the engine against it.

Identical, bit for bit: every draw reads the same counter-based stream (counter_rng) at the same counter
as the engine's, through the same maps (generator.py, blink.py, fixation.py's tables); transcendental
functions are numpy's, which round a scalar exactly as they round an array's element (Python's math.log,
math.hypot and friends differ from them in the last bit on some inputs); and the arithmetic keeps the
engine's order of operations wherever rounding depends on it. The lid alone is computed another way:
here by the curve itself (blink.lid_closure), in the engine one straight piece at a time (inflight.py),
which agree to rounding (~1e-16).

Events follow the engine's rules: one stamped before the last tick applies at the last tick's time; the
timer events before an event's time run first, those at its time wait, so every cue of one instant is
in before a decision of that instant; at one instant a decision comes before a blink and before a small
saccade (which the new fixation replaces).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from eca.agent.counter_rng import hash3, stream_key, uniform01
from eca.agent.gaze.blink import blink_interval_ns, blink_spread_ns, evoked_blink_probability, lid_closure
from eca.agent.gaze.fixation import AMPLITUDE_TABLE_INTERVALS, ANGLES, microsaccade_quantiles
from eca.agent.gaze.generator import (
    BLINK_STREAM,
    FIXATION_STREAM,
    NOISE_STREAM,
    PERLIN_BLINK_STREAM,
    SACCADE_STREAM,
    TARGET_CHOICE_STREAM,
    derive_seed,
    direction_index_from_uniform,
    direction_unit_steps,
    hold_from_uniform,
    hold_quantiles,
    magnitude_from_uniform,
    mutual_probability,
)
from eca.agent.gaze.params import (  # the mode codes in order: saccades from SACCADE on, blinks from SACCADE_BLINK on
    DEFAULT_ROLE,
    FIXATIONAL,
    MODES,
    NOISE,
    ROLES,
    SACCADE,
    SACCADE_BLINK,
    STATIC,
    GazeParams,
    check_name,
)
from eca.agent.gaze.synth import saccade_progress
from eca.agent.noise import perlin1d, perlin_blink

NEVER_NS = 1 << 62
_NS = 1_000_000_000
_HALF = 1.0 / float(1 << 32)  # a 32-bit half of a hash as a uniform in [0, 1)
TOWARD = ("mutual", "away")


class Onset(NamedTuple):
    """One saccade as a GazeEngine tick reports it (events.SaccadeOnsets, one row)."""

    onset_ns: int
    kind: str
    from_yaw_deg: float
    from_pitch_deg: float
    to_yaw_deg: float
    to_pitch_deg: float
    magnitude_deg: float
    amplitude_deg: float
    direction_deg: float
    duration_s: float
    hold_s: float


class ReferenceTick(NamedTuple):
    """The agent's eye state at `t_ns` and its saccade and blink onsets since the last tick, in time order."""

    t_ns: int
    yaw_deg: float
    pitch_deg: float
    lid: float
    saccades: list[Onset]
    blinks: list[int]


class _Tables:
    """The model's tables, built once per GazeParams and shared by its agents: the hold times' quantiles per
    (role, away), the direction bins' unit steps, the microsaccade amplitudes' quantiles."""

    def __init__(self, params: GazeParams) -> None:
        self.holds = {(role, away): hold_quantiles(params, role, away) for role in ROLES for away in (False, True)}
        self.direction_steps = direction_unit_steps(params)
        self.microsaccade_amplitudes = microsaccade_quantiles(params)


_TABLES: dict[int, tuple[GazeParams, _Tables]] = {}


def _tables(params: GazeParams) -> _Tables:
    entry = _TABLES.get(id(params))
    if entry is None or entry[0] is not params:  # the params are kept, so their id is not reused
        entry = _TABLES[id(params)] = (params, _Tables(params))
    return entry[1]


def _clip(value: float, limit: float) -> float:
    return min(max(value, -limit), limit)


class ReferenceAgent:
    """Agent `index` of a GazeEngine(seed=`seed`), created at `start_ns` in `role` and `mode`."""

    def __init__(
        self,
        index: int,
        seed: int,
        params: GazeParams | None = None,
        start_ns: int = 0,
        role: str = DEFAULT_ROLE,
        mode: str | None = None,
    ) -> None:
        p = self.params = params if params is not None else GazeParams.load()
        mode = p.default_mode if mode is None else mode
        check_name(role, ROLES, "role")
        check_name(mode, MODES, "eye mode")
        self.index = index
        self._seeds = {stream: derive_seed(seed, stream) for stream in (
            SACCADE_STREAM, BLINK_STREAM, NOISE_STREAM, PERLIN_BLINK_STREAM, FIXATION_STREAM, TARGET_CHOICE_STREAM)}
        self._draws = dict.fromkeys(self._seeds, 0)  # each stream's counter
        self._tables = _tables(p)
        self._yaw_limit, self._pitch_limit = p.eye_yaw_limit_deg, p.eye_pitch_limit_deg
        self._blink_s = p.blink.duration_s
        self.now_ns = t = int(start_ns)
        self.role, self.mode = role, MODES.index(mode)
        # The current saccade (a fixation is a saccade that has landed): onset, landing, from and to.
        self.onset_ns = self.end_ns = t
        self.from_deg = self.to_deg = (0.0, 0.0)
        self.kind = "mutual"
        self.target = (0.0, 0.0)  # where mutual gaze looks
        self.targets: tuple[list[float], list[float], np.ndarray] | None = None  # several (set_targets)
        self.head = self.head_ref = (0.0, 0.0)  # the head, and where it was at the last head-led saccade
        self.interval_scale, self.magnitude_scale, self.mutual_shift = 1.0, 1.0, 0.0
        self.bias_direction, self.bias_strength = 0.0, 0.0
        # Cues for the next decision: its outcome forced (shift_gaze), a turn boundary's blink (set_role).
        self.forced: str | None = None
        self.turn_blink = False
        self.next_saccade = t if self.mode >= SACCADE else NEVER_NS
        self.next_blink = NEVER_NS
        self.blink_onset = -NEVER_NS
        if self.mode >= SACCADE_BLINK:
            self.next_blink = t + self._blink_interval()
        # The fixational movements of mode saccade+noise+blink: the fixation's base point (where the saccade
        # landed), the eye's offset from it, the point held (0 the gaze target, then the face features),
        # when the eye last landed, the fixation's context (role, mutual gaze) and the spread of its
        # intervals, and the next small saccade's onset. The first fixation starts where the first
        # saccade lands.
        self.base = (0.0, 0.0)
        self.offset = (0.0, 0.0)
        self.held = 0
        self.landed_ns = 0
        self.fixation_context = (role, False)
        self.small_spread_ns = 0
        self.next_small = NEVER_NS
        self._preferred_eye = int(stream_key(self._seeds[FIXATION_STREAM], index)) & 1
        self._saccades: list[Onset] = []
        self._blinks: list[int] = []

    # ------------------------------------------------------------------ draws

    def _uniforms(self, stream: int, count: int) -> list[float]:
        """The next `count` uniforms in [0, 1) of one of the agent's streams."""
        first = self._draws[stream]
        self._draws[stream] = first + count
        counters = np.arange(first, first + count, dtype=np.uint64)
        return [float(u) for u in uniform01(self._seeds[stream], self.index, counters)]

    def _halves(self, count: int) -> list[float]:
        """2 * `count` uniforms from the next `count` hashes of the fixational stream, two 32-bit ones from each
        hash: the high halves first, then the low ones."""
        first = self._draws[FIXATION_STREAM]
        self._draws[FIXATION_STREAM] = first + count
        hashes = [int(h) for h in hash3(self._seeds[FIXATION_STREAM], self.index,
                                         np.arange(first, first + count, dtype=np.uint64))]
        return [(h >> 32) * _HALF for h in hashes] + [(h & 0xFFFFFFFF) * _HALF for h in hashes]

    # ------------------------------------------------------------------ the Attention Monitor's inputs

    def set_role(self, role: str, t_ns: int) -> None:
        check_name(role, ROLES, "role")
        t = self._begin(t_ns)
        if role == self.role:
            return
        self.role = role
        if self.mode >= SACCADE:
            self.next_saccade = t  # decide at once in the new regime
        if self.mode >= SACCADE_BLINK:
            self.next_blink = t + self._blink_interval()
        if self.mode == FIXATIONAL:
            self.turn_blink = True

    def shift_gaze(self, toward: str, t_ns: int) -> None:
        check_name(toward, TOWARD, "gaze shift")
        t = self._begin(t_ns)
        if self.mode >= SACCADE:
            self.next_saccade = t
            self.forced = toward

    def blink_at(self, t_ns: int) -> bool:
        """Blink now if the next blink is due within the pull window (it is pulled forward)."""
        t = self._begin(t_ns)
        if self.mode < SACCADE_BLINK or self.next_blink - t > self._pull_window_ns:
            return False
        self.next_blink += self._blink_interval()
        self._blink(t)
        return True

    def set_emotion(self, name: str, intensity: float, t_ns: int) -> None:
        emotion = self.params.emotion(name, float(intensity))
        self._begin(t_ns)
        self.interval_scale, self.magnitude_scale = emotion.interval_scale, emotion.magnitude_scale
        self.mutual_shift = emotion.mutual_shift
        self.bias_direction, self.bias_strength = emotion.bias_direction_deg, emotion.bias_strength

    def set_mode(self, mode: str, t_ns: int) -> None:
        check_name(mode, MODES, "eye mode")
        t = self._begin(t_ns)
        new, old = MODES.index(mode), self.mode
        if new == old:
            return
        shown = self._shown_position(t)
        was_saccading = old >= SACCADE
        self.mode = new
        # The eye holds where it is shown: as it leaves or enters the saccade modes, and when it leaves the
        # fixational movements after landing (the offset becomes the rest). A saccade in flight flies on.
        fixate = not was_saccading or new < SACCADE or (old == FIXATIONAL and self.end_ns <= t)
        if fixate:
            self.onset_ns = self.end_ns = t
            self.from_deg = self.to_deg = shown
            if not was_saccading:
                self.next_saccade = t if new >= SACCADE else NEVER_NS
        if new < SACCADE:
            self.next_saccade = NEVER_NS
        if new >= SACCADE_BLINK:
            self.next_blink = t + self._blink_interval()
        else:
            self.next_blink, self.blink_onset = NEVER_NS, -NEVER_NS
        if old == FIXATIONAL:
            self.next_small, self.offset = NEVER_NS, (0.0, 0.0)
        if new == FIXATIONAL:
            self._start_fixation(max(self.end_ns, t))

    def set_head(self, yaw_deg: float, pitch_deg: float, t_ns: int) -> None:
        """A head turn beyond the threshold since the last head-led saccade starts a saccade toward it."""
        yaw, pitch = _finite(yaw_deg, pitch_deg, "head")
        t = self._begin(t_ns)
        self.head = (yaw, pitch)
        d_yaw, d_pitch = yaw - self.head_ref[0], pitch - self.head_ref[1]
        turn = float(np.hypot(d_yaw, d_pitch))
        if not turn > self.params.head_turn_threshold_deg:
            return
        self.head_ref = self.head
        if self.mode < SACCADE:
            return
        amplitude = min(turn, self.params.roles[self.role].max_magnitude_deg)
        to = (_clip(self.target[0] + amplitude * d_yaw / turn, self._yaw_limit),
              _clip(self.target[1] + amplitude * d_pitch / turn, self._pitch_limit))
        u_hold, u_pull, u_follow = self._uniforms(SACCADE_STREAM, 3)
        hold = self._hold_s(u_hold, away=True)
        self._launch(t, to, "head", hold, u_pull, u_follow, magnitude=amplitude)

    def set_target(self, yaw_deg: float, pitch_deg: float, t_ns: int) -> None:
        yaw, pitch = _finite(yaw_deg, pitch_deg, "target")
        t = self._begin(t_ns)
        self.targets = None
        self._point_at(yaw, pitch, t)

    def set_targets(self, yaw_deg: list[float], pitch_deg: list[float], weights: list[float], t_ns: int) -> None:
        """Mutual gaze chooses among several points, one drawn per decision (and one now)."""
        t = self._begin(t_ns)
        w = np.asarray(weights, dtype=np.float64)
        self.targets = ([_clip(float(y), self._yaw_limit) for y in yaw_deg],
                        [_clip(float(p), self._pitch_limit) for p in pitch_deg], np.cumsum(w / w.sum())[:-1])
        self._point_at(*self._choose_target(), t)

    def _choose_target(self) -> tuple[float, float]:
        assert self.targets is not None
        yaws, pitches, cumulative = self.targets
        (u,) = self._uniforms(TARGET_CHOICE_STREAM, 1)
        k = int(np.searchsorted(cumulative, u, side="right"))
        return yaws[k], pitches[k]

    def _point_at(self, yaw: float, pitch: float, t: int) -> None:
        """Move the gaze target; an eye holding mutual gaze follows it at once, keeping its hold timer."""
        self.target = (_clip(yaw, self._yaw_limit), _clip(pitch, self._pitch_limit))
        if self.mode >= SACCADE and self.kind == "mutual" and self.to_deg != self.target:
            u_pull, u_follow = self._uniforms(SACCADE_STREAM, 2)
            self._launch(t, self.target, "mutual", None, u_pull, u_follow)

    # ------------------------------------------------------------------ time

    def tick(self, t_ns: int) -> ReferenceTick:
        """Run every event up to `t_ns`; the eye state there and the onsets since the last tick."""
        t = int(t_ns)
        if t < self.now_ns:
            raise ValueError(f"tick time {t} ns is before the previous tick at {self.now_ns} ns")
        if min(self.next_saccade, self.next_blink, self.next_small) <= t:
            self._run_before(t + 1)
        self.now_ns = t
        yaw, pitch = self._shown_position(t)
        if self.mode >= SACCADE_BLINK:
            elapsed_s = (t - self.blink_onset) * 1e-9
            # Past the curve's end the lid is open (lid_closure's value there, without its cost every tick).
            lid = float(lid_closure(elapsed_s, self.params.blink)) if elapsed_s <= self._blink_s else 0.0
        elif self.mode >= NOISE:
            lid = float(perlin_blink(t * 1e-9, self._seeds[PERLIN_BLINK_STREAM], self.index))
        else:
            lid = 0.0
        saccades, self._saccades = self._saccades, []
        blinks, self._blinks = self._blinks, []
        return ReferenceTick(t, yaw, pitch, lid, saccades, blinks)

    def _begin(self, t_ns: int) -> int:
        """An event's time (never before the last tick), with every timer event before it run."""
        t = max(int(t_ns), self.now_ns)
        self._run_before(t)
        return t

    def _run_before(self, t: int) -> None:
        """Run the timer events before `t` in time order; at one instant a decision goes first."""
        while min(self.next_saccade, self.next_blink, self.next_small) < t:
            if self.next_small < min(self.next_saccade, self.next_blink):
                self._small_saccade()
            elif self.next_saccade <= self.next_blink:
                self._decide()
            else:  # a spontaneous blink, and the next one drawn
                onset = self.next_blink
                self.next_blink = onset + self._blink_interval()
                self._blink(onset)

    # ------------------------------------------------------------------ the Parameter Generator

    def _decide(self) -> None:
        """The gaze timer expired (or the regime changed): mutual or away, magnitude, direction and hold."""
        t = self.next_saccade
        u_mutual, u_magnitude, u_direction, u_hold, u_pull, u_follow = self._uniforms(SACCADE_STREAM, 6)
        if self.targets is not None:
            self.target = self._choose_target()
        away = u_mutual >= float(mutual_probability(self.params, np.array(ROLES.index(self.role)), self.mutual_shift))
        if self.forced is not None:
            away = self.forced == "away"
        least_pull = self.params.blink.turn_probability if self.turn_blink else 0.0
        self.forced, self.turn_blink = None, False
        magnitude = float(magnitude_from_uniform(u_magnitude, self.params,
                                                 self.params.roles[self.role].max_magnitude_deg, self.magnitude_scale))
        bin_index = int(direction_index_from_uniform(u_direction, self.params, self.bias_direction, self.bias_strength))
        if away:
            step_yaw, step_pitch = self._tables.direction_steps
            to = (_clip(float(step_yaw[bin_index]) * magnitude + self.target[0], self._yaw_limit),
                  _clip(float(step_pitch[bin_index]) * magnitude + self.target[1], self._pitch_limit))
        else:
            to = self.target
        hold = self._hold_s(u_hold, away)
        self._launch(t, to, "away" if away else "mutual", hold, u_pull, u_follow,
                     magnitude=magnitude if away else None, least_pull=least_pull)

    def _hold_s(self, u: float, away: bool) -> float:
        return hold_from_uniform(u, self._tables.holds[self.role, away], self.interval_scale)

    # ------------------------------------------------------------------ the Saccade Synthesizer

    def _launch(
        self,
        t: int,
        to: tuple[float, float],
        kind: str,
        hold_s: float | None,
        u_pull: float,
        u_follow: float,
        magnitude: float | None = None,
        least_pull: float = 0.0,
    ) -> None:
        """A saccade from where the eye is at `t` to `to`. With a hold the gaze timer restarts from the landing
        (and the cues for the next decision are spent); without one it keeps running."""
        p = self.params
        if hold_s is not None:
            self.forced, self.turn_blink = None, False
        if self.mode == FIXATIONAL:
            self._run_small_saccades_before(t)
        start = self._position(t)
        if self.mode == FIXATIONAL and t >= self.end_ns:  # from where the small saccades left the eye
            start = (_clip(start[0] + self.offset[0], self._yaw_limit),
                     _clip(start[1] + self.offset[1], self._pitch_limit))
        d_yaw, d_pitch = to[0] - start[0], to[1] - start[1]
        amplitude = float(np.hypot(d_yaw, d_pitch))
        duration_ns = int(np.rint(amplitude * (p.d_s_per_deg * _NS) + p.d0_s * _NS))  # main sequence, eq. 2
        end = t + duration_ns
        if hold_s is not None:
            next_saccade = end + int(np.rint(hold_s * _NS))
        else:
            next_saccade = max(self.next_saccade, end)
            hold_s = (next_saccade - end) * 1e-9
        self.onset_ns, self.end_ns, self.next_saccade = t, end, next_saccade
        self.from_deg, self.to_deg, self.kind = start, to, kind
        # A large saccade, a head-led one or a turn boundary pulls the next blink forward when it is due soon.
        if kind == "head":
            chance = p.blink.head_turn_probability
        else:
            chance = max(float(evoked_blink_probability(amplitude, p.blink)), least_pull)
        if u_pull < chance and self.next_blink - t <= self._pull_window_ns and self.mode >= SACCADE_BLINK:
            self.next_blink += int(blink_interval_ns(self._blink_spread_ns(), u_follow, p.blink))
            self._blink(t)
        if self.mode == FIXATIONAL:
            self._start_fixation(end)
        direction = float(np.arctan2(d_pitch, d_yaw)) * (180.0 / math.pi)
        direction += (direction < 0.0) * 360.0
        self._saccades.append(Onset(
            t, kind, start[0], start[1], to[0], to[1], amplitude if magnitude is None else magnitude, amplitude,
            direction, duration_ns * 1e-9, hold_s,
        ))  # fmt: skip

    def _position(self, t: int) -> tuple[float, float]:
        """Where the current saccade has the eye at `t`: the bell velocity profile between from and to."""
        if t >= self.end_ns:
            return self.to_deg
        progress = float(saccade_progress((t - self.onset_ns) / max(self.end_ns - self.onset_ns, 1)))
        remaining = 1.0 - progress  # this form is exact at both ends
        return (self.from_deg[0] * remaining + self.to_deg[0] * progress,
                self.from_deg[1] * remaining + self.to_deg[1] * progress)

    def _shown_position(self, t: int) -> tuple[float, float]:
        """Where the eye is at `t` in its mode."""
        p = self.params
        if self.mode == STATIC:
            return self.target
        if self.mode == NOISE:
            x = t * 1e-9 * p.noise_frequency_hz
            seed = self._seeds[NOISE_STREAM]
            return (
                _clip(self.target[0] + p.noise_yaw_amplitude_deg * float(perlin1d(x, seed, 2 * self.index)),
                      self._yaw_limit),
                _clip(self.target[1] + p.noise_pitch_amplitude_deg * float(perlin1d(x, seed, 2 * self.index + 1)),
                      self._pitch_limit),
            )
        yaw, pitch = self._position(t)
        if self.mode == FIXATIONAL and t >= self.end_ns:
            yaw = _clip(yaw + self.offset[0], self._yaw_limit)
            pitch = _clip(pitch + self.offset[1], self._pitch_limit)
        return yaw, pitch

    # ------------------------------------------------------------------ blinks

    @property
    def _pull_window_ns(self) -> int:
        return int(round(self.params.blink.pull_window_s * _NS))

    def _blink_spread_ns(self) -> float:
        return float(blink_spread_ns(self.params.blink, self.params.roles[self.role].blink_rate_per_min))

    def _blink_interval(self) -> int:
        (u,) = self._uniforms(BLINK_STREAM, 1)
        return int(blink_interval_ns(self._blink_spread_ns(), u, self.params.blink))

    def _blink(self, t: int) -> None:
        self.blink_onset = t
        self._blinks.append(t)

    # ------------------------------------------------------------------ fixational movements

    def _start_fixation(self, landing_ns: int) -> None:
        """A new fixation where the current saccade lands; a small saccade pending is dropped."""
        fix = self.params.fixation
        self.fixation_context = (self.role, self.kind == "mutual")
        self.base, self.offset, self.held, self.landed_ns = self.to_deg, (0.0, 0.0), 0, landing_ns
        rate = fix.event_rate_hz(*self.fixation_context)
        spread_ns = 1.0 / rate * self.interval_scale * _NS - self._small_refractory_ns
        self.small_spread_ns = int(np.rint(max(spread_ns, 0.0)))
        self.next_small = landing_ns + self._small_interval(self._halves(1)[0])

    @property
    def _small_refractory_ns(self) -> int:
        return int(round(self.params.fixation.refractory_s * _NS))

    def _small_interval(self, u: float) -> int:
        """Onset to next onset: the refractory gap plus an exponential."""
        return int(np.rint(-float(self.small_spread_ns) * np.log1p(-u))) + self._small_refractory_ns

    def _run_small_saccades_before(self, t: int) -> None:
        while self.next_small < t:
            self._small_saccade()

    def _small_saccade(self) -> None:
        """The drift since the last landing, then a scan to a face feature (mutual gaze only) or a
        microsaccade back toward the point held."""
        p, fix = self.params, self.params.fixation
        t = self.next_small
        u_interval, u_kind, u_amplitude, u_jitter, u_radius, u_angle = self._halves(3)
        off_yaw, off_pitch = self.offset
        if fix.drift_diffusion_deg2_per_s:  # Brownian: a radius and a direction
            variance = (t - self.landed_ns) * (-2e-9 * (2.0 * fix.drift_diffusion_deg2_per_s))
            radius = float(np.sqrt(float(np.log1p(-u_radius)) * variance))
            angle = (int(u_angle * ANGLES) + 0.5) * (2.0 * np.pi / ANGLES)
            off_yaw = float(np.cos(angle)) * radius + off_yaw
            off_pitch = float(np.sin(angle)) * radius + off_pitch
        role, mutual = self.fixation_context
        rate = fix.event_rate_hz(role, mutual)
        p_scan = (rate - fix.microsaccade_rate_hz) / rate
        points = [(0.0, 0.0)] + [(float(y), float(x)) for y, x in fix.features_deg]
        if u_kind < p_scan:  # a scan: the feature by its share, from the same uniform
            shares = np.cumsum(fix.feature_weights(role, self._preferred_eye))
            self.held = 1 + (u_kind >= p_scan * shares[0]) + (u_kind >= p_scan * shares[1])
            to_off = points[self.held]
            kind = "scan"
        else:  # a microsaccade: the amplitude from its quantile table, heading back toward the point held
            x = u_amplitude * AMPLITUDE_TABLE_INTERVALS
            cell = int(x)
            x -= cell
            quantiles = self._tables.microsaccade_amplitudes
            amplitude = float((quantiles[cell + 1] - quantiles[cell]) * x + quantiles[cell])
            toward_yaw, toward_pitch = points[self.held][0] - off_yaw, points[self.held][1] - off_pitch
            norm = math.sqrt(toward_yaw * toward_yaw + toward_pitch * toward_pitch)
            if norm < 1e-12:  # on the point: the heading is the spread alone
                toward_yaw, norm = 1.0, 1.0
            amplitude /= norm
            spread = math.radians(fix.correction_spread_deg)
            turn = (int(u_jitter * ANGLES) + 0.5) / ANGLES * (2.0 * spread) - spread
            cos_turn, sin_turn = float(np.cos(turn)), float(np.sin(turn))
            to_off = ((toward_yaw * cos_turn - toward_pitch * sin_turn) * amplitude + off_yaw,
                      (toward_yaw * sin_turn + toward_pitch * cos_turn) * amplitude + off_pitch)
            kind = "micro"
        base = self.base
        start = (_clip(base[0] + off_yaw, self._yaw_limit), _clip(base[1] + off_pitch, self._pitch_limit))
        end = (_clip(base[0] + to_off[0], self._yaw_limit), _clip(base[1] + to_off[1], self._pitch_limit))
        d_yaw, d_pitch = end[0] - start[0], end[1] - start[1]
        moved = math.sqrt(d_yaw * d_yaw + d_pitch * d_pitch)
        landing = t + int(np.rint(moved * (p.d_s_per_deg * _NS) + p.d0_s * _NS))
        self.offset, self.landed_ns = to_off, landing
        self.next_small = t + self._small_interval(u_interval)
        direction = float(np.arctan2(d_pitch, d_yaw)) * (180.0 / math.pi)
        direction += (direction < 0.0) * 360.0
        self._saccades.append(Onset(t, kind, start[0], start[1], end[0], end[1], moved, moved, direction,
                                    (landing - t) * 1e-9, (self.next_small - landing) * 1e-9))


def _finite(yaw: float, pitch: float, what: str) -> tuple[float, float]:
    if not (math.isfinite(yaw) and math.isfinite(pitch)):
        raise ValueError(f"{what} yaw/pitch must be finite numbers, got {yaw!r}, {pitch!r}")
    return float(yaw), float(pitch)
