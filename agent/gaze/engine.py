"""GazeEngine: the Attention Monitor, Parameter Generator and Saccade Synthesizer for N agents at once.

Every agent's state lives in numpy arrays. A tick compares one next-event-time array against the clock
and gathers only the agents whose gaze timer or blink timer expired; their events are processed at
their exact scheduled times (never quantised to the tick), so the trajectory does not depend on the
tick rate. Each agent draws from its own counter-based stream (seed, agent index, per-agent counter),
so adding an agent leaves every other agent's trajectory unchanged.

Each per-agent quantity is its own contiguous 1-D array: numpy gathers and scatters single columns
several times faster than rows of a 2-D array, and with a million agents memory traffic, not
arithmetic, sets the tick time.

Events from outside (role, emotion, mode, head, target) take effect at their own timestamp; one stamped
before the last tick is applied at the last tick's time.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from agent.counter_rng import splitmix64
from agent.gaze.blink import evoked_blink_probability, lid_closure
from agent.gaze.events import BlinkOnsets, GazeTick, SaccadeOnsets
from agent.gaze.generator import direction_from_uniform, magnitude_from_uniform
from agent.gaze.params import KINDS, MODES, ROLES, GazeParams, check_name
from agent.gaze.synth import saccade_progress
from agent.noise import perlin1d, perlin_blink

__all__ = ["GazeEngine", "GazeTick", "SaccadeOnsets", "BlinkOnsets", "DEFAULT_ROLE"]

NEVER_NS = 1 << 62
_NS = 1_000_000_000
_TWO_POW_MINUS_53 = 1.0 / float(1 << 53)
_HOLD_TABLE_INTERVALS = 32_768

STATIC, NOISE, SACCADE, SACCADE_BLINK = (MODES.index(m) for m in ("static", "noise", "saccade", "saccade+blink"))
MUTUAL, AWAY, HEAD = (KINDS.index(k) for k in ("mutual", "away", "head"))
DEFAULT_ROLE = "silence"

SACCADE_STREAM, BLINK_STREAM = 0, 1

# Per-agent arrays: name -> (dtype, initial value).
_STATE: dict[str, tuple[type, float | int]] = {
    "onset": (np.int64, 0), "end": (np.int64, 0),  # the current (or last) saccade, ns
    "next_saccade": (np.int64, NEVER_NS), "next_blink": (np.int64, NEVER_NS),
    "next_event": (np.int64, NEVER_NS), "blink_onset": (np.int64, -NEVER_NS),
    "from_yaw": (np.float64, 0.0), "from_pitch": (np.float64, 0.0),
    "to_yaw": (np.float64, 0.0), "to_pitch": (np.float64, 0.0),
    "target_yaw": (np.float64, 0.0), "target_pitch": (np.float64, 0.0),
    "interval_scale": (np.float64, 1.0), "magnitude_scale": (np.float64, 1.0), "mutual_shift": (np.float64, 0.0),
    "bias_direction": (np.float64, 0.0), "bias_strength": (np.float64, 0.0),
    "head_yaw": (np.float64, 0.0), "head_pitch": (np.float64, 0.0),
    "head_ref_yaw": (np.float64, 0.0), "head_ref_pitch": (np.float64, 0.0),
    "role": (np.int8, 0), "mode": (np.int8, 0), "fix_kind": (np.int8, MUTUAL),
    "key_saccade": (np.uint64, 0), "key_blink": (np.uint64, 0),
    "counter_saccade": (np.uint64, 0), "counter_blink": (np.uint64, 0),
}  # fmt: skip


class _State:
    """Per-agent arrays, one attribute each (see _STATE)."""

    onset: np.ndarray
    end: np.ndarray
    next_saccade: np.ndarray
    next_blink: np.ndarray
    next_event: np.ndarray
    blink_onset: np.ndarray
    from_yaw: np.ndarray
    from_pitch: np.ndarray
    to_yaw: np.ndarray
    to_pitch: np.ndarray
    target_yaw: np.ndarray
    target_pitch: np.ndarray
    interval_scale: np.ndarray
    magnitude_scale: np.ndarray
    mutual_shift: np.ndarray
    bias_direction: np.ndarray
    bias_strength: np.ndarray
    head_yaw: np.ndarray
    head_pitch: np.ndarray
    head_ref_yaw: np.ndarray
    head_ref_pitch: np.ndarray
    role: np.ndarray
    mode: np.ndarray
    fix_kind: np.ndarray
    key_saccade: np.ndarray
    key_blink: np.ndarray
    counter_saccade: np.ndarray
    counter_blink: np.ndarray

    def __init__(self) -> None:
        for name, (dtype, _) in _STATE.items():
            setattr(self, name, np.empty(0, dtype=dtype))

    def grow(self, count: int, overrides: dict[str, np.ndarray | float | int]) -> None:
        for name, (dtype, fill) in _STATE.items():
            extra = np.empty(count, dtype=dtype)
            extra[:] = overrides.get(name, fill)
            setattr(self, name, np.concatenate([getattr(self, name), extra]))


def derive_seed(seed: int, purpose: int) -> int:
    """Independent seeds for the saccade, blink and noise streams of one engine seed."""
    return int(splitmix64(np.uint64((seed * 8 + purpose) & 0xFFFFFFFFFFFFFFFF)))


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
        self._stream_seeds = (derive_seed(self.seed, 1), derive_seed(self.seed, 2))
        self._seed_noise = derive_seed(self.seed, 3)
        self._seed_perlin_blink = derive_seed(self.seed, 4)
        self._now_ns = int(start_ns)
        p = self.params
        self._max_magnitude = np.array([p.roles[r].max_magnitude_deg for r in ROLES])
        self._p_mutual = np.array([p.roles[r].mutual_probability for r in ROLES])
        self._blink_mean_s = np.array([60.0 / p.roles[r].blink_rate_per_min for r in ROLES])
        self._blink_duration_ns = int(round(p.blink.duration_s * _NS))
        self._pull_window_ns = int(round(p.blink.pull_window_s * _NS))
        self._hold_quantiles = self._hold_table()
        cumulative = np.cumsum(p.direction_probability)
        self._direction_cumulative = cumulative[:-1]  # a uniform beyond the last edge falls in the last bin
        self._bin_cos = np.cos(np.deg2rad(p.direction_bins_deg))
        self._bin_sin = np.sin(np.deg2rad(p.direction_bins_deg))
        self._biased_agents = 0  # how many agents' emotion tilts the direction bins
        self._n = 0
        self._s = _State()
        self._flight = np.empty(0, np.int64)
        self._blinking = np.empty(0, np.int64)
        self._new_flight: list[np.ndarray] = []
        self._new_blinking: list[np.ndarray] = []
        self._saccade_chunks: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self._blink_chunks: list[tuple[np.ndarray, np.ndarray]] = []
        self._members_cache: dict[int, np.ndarray] = {}
        if n_agents:
            self.add_agents(int(n_agents), self._now_ns, role, mode)

    def _hold_table(self) -> np.ndarray:
        """Quantile tables of the six (role, mutual/away) hold distributions, one row each, raveled."""
        u = np.linspace(0.0, 1.0, _HOLD_TABLE_INTERVALS + 1)
        rows = []
        for role in ROLES:
            for distribution in (self.params.roles[role].mutual_interval, self.params.roles[role].away_interval):
                rows.append(distribution.sample_s(u))
        return np.concatenate(rows)

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
        t = max(int(t_ns), self._now_ns)
        new = np.arange(self._n, self._n + count, dtype=np.int64)
        # The same per-agent keys counter_rng.hash3 derives for (stream seed, stream = agent index).
        keys = [splitmix64(splitmix64(np.uint64(seed)) ^ new.astype(np.uint64)) for seed in self._stream_seeds]
        self._s.grow(
            count,
            {
                "onset": t, "end": t, "role": ROLES.index(role), "mode": MODES.index(mode),
                "key_saccade": keys[SACCADE_STREAM], "key_blink": keys[BLINK_STREAM],
            },
        )  # fmt: skip
        self._n += count
        self._members_cache.clear()
        if MODES.index(mode) >= SACCADE:
            self._s.next_saccade[new] = t
        if MODES.index(mode) == SACCADE_BLINK:
            self._s.next_blink[new] = t + self._blink_interval_ns(new)
        self._refresh_next_event(new)
        self._advance(new, t)
        return new

    @property
    def n_agents(self) -> int:
        return self._n

    @property
    def now_ns(self) -> int:
        return self._now_ns

    def role_of(self, i: int) -> str:
        return ROLES[int(self._s.role[self._indices(i)][0])]

    def mode_of(self, i: int) -> str:
        return MODES[int(self._s.mode[self._indices(i)][0])]

    # ------------------------------------------------------------------ the Attention Monitor's inputs

    def set_role(self, i: int | Sequence[int] | np.ndarray, role: str, t_ns: int) -> None:
        """Switch the conversational role; agents whose role changes decide a new saccade at once."""
        check_name(role, ROLES, "role")
        idx, t = self._prepare(i, t_ns)
        st = self._s
        code = ROLES.index(role)
        idx = idx[st.role[idx] != code]
        st.role[idx] = code
        saccading = idx[st.mode[idx] >= SACCADE]
        st.next_saccade[saccading] = t
        blinking = idx[st.mode[idx] == SACCADE_BLINK]
        st.next_blink[blinking] = t + self._blink_interval_ns(blinking)
        self._refresh_next_event(idx)
        self._advance(idx, t)

    def set_emotion(self, i: int | Sequence[int] | np.ndarray, name: str, intensity: float, t_ns: int) -> None:
        """Modulate the statistics of every later saccade decision (configs/gaze_emotions.toml)."""
        emotion = self.params.emotion(name, float(intensity))
        idx, _ = self._prepare(i, t_ns)
        st = self._s
        st.interval_scale[idx] = emotion.interval_scale
        st.magnitude_scale[idx] = emotion.magnitude_scale
        st.mutual_shift[idx] = emotion.mutual_shift
        st.bias_direction[idx] = emotion.bias_direction_deg
        biased_before = int(np.count_nonzero(st.bias_strength[idx]))
        st.bias_strength[idx] = emotion.bias_strength
        self._biased_agents += int(np.count_nonzero(st.bias_strength[idx])) - biased_before

    def set_mode(self, i: int | Sequence[int] | np.ndarray, mode: str, t_ns: int) -> None:
        """Switch the eye mode: static, noise, saccade or saccade+blink."""
        check_name(mode, MODES, "eye mode")
        idx, t = self._prepare(i, t_ns)
        st = self._s
        code = MODES.index(mode)
        idx = idx[st.mode[idx] != code]
        if not idx.size:
            return
        yaw, pitch = self._shown_position(idx, t)
        was_saccading = st.mode[idx] >= SACCADE
        st.mode[idx] = code
        self._members_cache.clear()
        if code >= SACCADE:
            start = idx[~was_saccading]
            self._fixate(start, t, yaw[~was_saccading], pitch[~was_saccading])
            st.next_saccade[start] = t
        else:
            self._fixate(idx, t, yaw, pitch)
            st.next_saccade[idx] = NEVER_NS
        if code == SACCADE_BLINK:
            st.next_blink[idx] = t + self._blink_interval_ns(idx)
        else:
            st.next_blink[idx] = NEVER_NS
            st.blink_onset[idx] = -NEVER_NS
        self._refresh_next_event(idx)
        self._advance(idx, t)

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
        st = self._s
        st.head_yaw[idx] = np.broadcast_to(yaw, idx.shape)
        st.head_pitch[idx] = np.broadcast_to(pitch, idx.shape)
        d_yaw = st.head_yaw[idx] - st.head_ref_yaw[idx]
        d_pitch = st.head_pitch[idx] - st.head_ref_pitch[idx]
        turn = np.hypot(d_yaw, d_pitch)
        turned = turn > self.params.head_turn_threshold_deg
        idx, d_yaw, d_pitch, turn = idx[turned], d_yaw[turned], d_pitch[turned], turn[turned]
        st.head_ref_yaw[idx] = st.head_yaw[idx]
        st.head_ref_pitch[idx] = st.head_pitch[idx]
        saccading = st.mode[idx] >= SACCADE
        idx, d_yaw, d_pitch, turn = idx[saccading], d_yaw[saccading], d_pitch[saccading], turn[saccading]
        if not idx.size:
            return
        times = np.full(idx.size, t, dtype=np.int64)
        amplitude = np.minimum(turn, self._max_magnitude[st.role[idx]])
        to_yaw = self._clip_yaw(st.target_yaw[idx] + amplitude * d_yaw / turn)
        to_pitch = self._clip_pitch(st.target_pitch[idx] + amplitude * d_pitch / turn)
        u_hold = self._draw(idx, SACCADE_STREAM, 1)
        hold = self._sample_hold(idx, np.zeros(idx.size, dtype=bool), u_hold) * st.interval_scale[idx]
        self._launch(idx, times, to_yaw, to_pitch, amplitude, np.full(idx.size, HEAD, np.int8), hold)

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
        st = self._s
        st.target_yaw[idx] = self._clip_yaw(np.broadcast_to(yaw, idx.shape))
        st.target_pitch[idx] = self._clip_pitch(np.broadcast_to(pitch, idx.shape))
        follow = (st.mode[idx] >= SACCADE) & (st.fix_kind[idx] == MUTUAL)
        follow &= (st.to_yaw[idx] != st.target_yaw[idx]) | (st.to_pitch[idx] != st.target_pitch[idx])
        idx = idx[follow]
        if not idx.size:
            return
        times = np.full(idx.size, t, dtype=np.int64)
        kind = np.full(idx.size, MUTUAL, np.int8)
        self._launch(idx, times, st.target_yaw[idx], st.target_pitch[idx], None, kind, None)

    # ------------------------------------------------------------------ the tick

    def tick(self, t_ns: int) -> GazeTick:
        """Advance every agent to `t_ns`; return the eye state there and the onsets since the last tick."""
        t = int(t_ns)
        if t < self._now_ns:
            raise ValueError(f"tick time {t} ns is before the previous tick at {self._now_ns} ns")
        st = self._s
        due = np.flatnonzero(st.next_event <= t)
        if due.size:
            self._advance(due, t)
        self._now_ns = t
        yaw = st.to_yaw.copy()
        pitch = st.to_pitch.copy()
        flight = self._merge(self._flight, self._new_flight)
        self._flight = flight[st.end[flight] > t]
        if self._flight.size:
            yaw[self._flight], pitch[self._flight] = self._saccade_position(self._flight, np.int64(t))
        lid = np.zeros(self._n)
        blinking = self._merge(self._blinking, self._new_blinking)
        elapsed_ns = t - st.blink_onset[blinking]
        still = elapsed_ns < self._blink_duration_ns
        self._blinking = blinking[still]
        if self._blinking.size:
            lid[self._blinking] = lid_closure(elapsed_ns[still] * 1e-9, self.params.blink)
        self._apply_non_saccade_modes(t, yaw, pitch, lid)
        return GazeTick(t, yaw, pitch, lid, self._take_saccades(), self._take_blinks())

    # ------------------------------------------------------------------ events

    def _prepare(self, i: int | Sequence[int] | np.ndarray, t_ns: int) -> tuple[np.ndarray, int]:
        idx = self._indices(i)
        t = max(int(t_ns), self._now_ns)
        self._advance(idx, t)
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

    def _draw(self, idx: np.ndarray, stream: int, count: int) -> np.ndarray:
        """`count` uniforms in [0, 1) per agent from its own stream: shape (len(idx),), or (len(idx), count).

        Bit for bit counter_rng.uniform01(stream seed, agent index, counter), with the per-agent key cached.
        """
        st = self._s
        keys, counters = (
            (st.key_saccade, st.counter_saccade) if stream == SACCADE_STREAM else (st.key_blink, st.counter_blink)
        )
        key, counter = keys[idx], counters[idx]
        counters[idx] = counter + np.uint64(count)
        if count == 1:
            bits = splitmix64(key ^ counter)
        else:
            bits = splitmix64(key[:, None] ^ (counter[:, None] + np.arange(count, dtype=np.uint64)))
        return (bits >> np.uint64(11)).astype(np.float64) * _TWO_POW_MINUS_53

    def _refresh_next_event(self, idx: np.ndarray) -> None:
        st = self._s
        st.next_event[idx] = np.minimum(st.next_saccade[idx], st.next_blink[idx])

    def _advance(self, idx: np.ndarray, t: int) -> None:
        """Process every timer event at or before `t` of the given agents, in time order per agent.

        One pass handles up to three events per agent (a blink, then a saccade decision, then a blink),
        each only when it is that agent's earliest pending event, so at video rates one pass suffices.
        """
        st = self._s
        while idx.size:
            idx = idx[st.next_event[idx] <= t]
            if not idx.size:
                return
            next_saccade, next_blink = st.next_saccade[idx], st.next_blink[idx]
            blink_first = next_blink < next_saccade  # a tie goes to the saccade, which may carry the blink
            if blink_first.any():
                self._blink(idx[blink_first], next_blink[blink_first])
                next_blink = st.next_blink[idx]
            saccade_now = (next_saccade <= t) & (next_saccade <= next_blink)
            if saccade_now.any():
                self._decide(idx[saccade_now], next_saccade[saccade_now])
                next_saccade, next_blink = st.next_saccade[idx], st.next_blink[idx]
            blink_now = (next_blink <= t) & (next_blink < next_saccade)
            if blink_now.any():
                self._blink(idx[blink_now], next_blink[blink_now])

    def _decide(self, idx: np.ndarray, times: np.ndarray) -> None:
        """The gaze timer expired (or the regime changed): choose mutual or away and launch the saccade."""
        st = self._s
        role = st.role[idx]
        u = self._draw(idx, SACCADE_STREAM, 4)
        mutual = u[:, 0] < np.clip(self._p_mutual[role] + st.mutual_shift[idx], 0.0, 1.0)
        magnitude = magnitude_from_uniform(u[:, 1], self.params, self._max_magnitude[role], st.magnitude_scale[idx])
        if self._biased_agents:
            direction = np.deg2rad(
                direction_from_uniform(u[:, 2], self.params, st.bias_direction[idx], st.bias_strength[idx])
            )
            cos, sin = np.cos(direction), np.sin(direction)
        else:  # the common case: the table's bins, read through precomputed cosines and sines
            bin_index = np.searchsorted(self._direction_cumulative, u[:, 2], side="right")
            cos, sin = self._bin_cos[bin_index], self._bin_sin[bin_index]
        target_yaw, target_pitch = st.target_yaw[idx], st.target_pitch[idx]
        to_yaw = np.where(mutual, target_yaw, self._clip_yaw(target_yaw + magnitude * cos))
        to_pitch = np.where(mutual, target_pitch, self._clip_pitch(target_pitch + magnitude * sin))
        hold = self._sample_hold(idx, mutual, u[:, 3], role) * st.interval_scale[idx]
        kind = np.where(mutual, MUTUAL, AWAY).astype(np.int8)
        self._launch(idx, times, to_yaw, to_pitch, np.where(mutual, np.nan, magnitude), kind, hold)

    def _sample_hold(
        self, idx: np.ndarray, mutual: np.ndarray, u: np.ndarray, role: np.ndarray | None = None
    ) -> np.ndarray:
        """Inverse-CDF hold times (s) from the quantile table of each agent's (role, mutual/away)."""
        role = self._s.role[idx] if role is None else role
        row = role.astype(np.int64) * 2 + (~mutual)
        x = u * _HOLD_TABLE_INTERVALS
        cell = np.minimum(x.astype(np.int64), _HOLD_TABLE_INTERVALS - 1)
        frac = x - cell
        at = row * (_HOLD_TABLE_INTERVALS + 1) + cell
        table = self._hold_quantiles
        return table[at] * (1.0 - frac) + table[at + 1] * frac

    def _launch(
        self,
        idx: np.ndarray,
        times: np.ndarray,
        to_yaw: np.ndarray,
        to_pitch: np.ndarray,
        magnitude: np.ndarray | None,
        kind: np.ndarray,
        hold_s: np.ndarray | None,
    ) -> None:
        """Start saccades at `times` from where each eye is then. Without `hold_s` the hold timer is kept."""
        st = self._s
        from_yaw, from_pitch = self._saccade_position(idx, times)
        d_yaw, d_pitch = to_yaw - from_yaw, to_pitch - from_pitch
        amplitude = np.hypot(d_yaw, d_pitch)
        direction = np.mod(np.rad2deg(np.arctan2(d_pitch, d_yaw)), 360.0)
        duration_ns = np.rint((self.params.d0_s + self.params.d_s_per_deg * amplitude) * _NS).astype(np.int64)
        end = times + duration_ns
        st.onset[idx], st.end[idx] = times, end
        if hold_s is not None:
            next_saccade = end + np.rint(hold_s * _NS).astype(np.int64)
        else:
            next_saccade = np.maximum(st.next_saccade[idx], end)
            hold_s = (next_saccade - end) * 1e-9
        st.next_saccade[idx] = next_saccade
        st.from_yaw[idx], st.from_pitch[idx] = from_yaw, from_pitch
        st.to_yaw[idx], st.to_pitch[idx] = to_yaw, to_pitch
        st.fix_kind[idx] = kind
        next_blink = self._couple_blinks(idx, times, amplitude, kind)
        st.next_event[idx] = np.minimum(next_saccade, next_blink)
        self._new_flight.append(idx)
        magnitude = amplitude if magnitude is None else np.where(np.isnan(magnitude), amplitude, magnitude)
        floats = np.array(
            (from_yaw, from_pitch, to_yaw, to_pitch, magnitude, amplitude, direction, duration_ns * 1e-9, hold_s)
        )
        self._saccade_chunks.append((idx, times, kind, floats))

    def _couple_blinks(self, idx: np.ndarray, times: np.ndarray, amplitude: np.ndarray, kind: np.ndarray) -> np.ndarray:
        """Large saccades and head-led saccades pull the next due blink forward to their onset.

        Returns every agent's next blink time after the coupling."""
        st = self._s
        next_blink = st.next_blink[idx]
        with_model = st.mode[idx] == SACCADE_BLINK
        if not with_model.all():
            if not with_model.any():
                return next_blink
            next_blink[with_model] = self._couple_blinks(
                idx[with_model], times[with_model], amplitude[with_model], kind[with_model]
            )
            return next_blink
        blink = self.params.blink
        u = self._draw(idx, BLINK_STREAM, 2)  # whether to pull a blink; its follower's interval
        chance = evoked_blink_probability(amplitude, blink)
        if (kind == HEAD).any():
            chance = np.where(kind == HEAD, blink.head_turn_probability, chance)
        pull = (u[:, 0] < chance) & (next_blink - times <= self._pull_window_ns)
        if pull.any():
            pulled, onset = idx[pull], times[pull]
            next_blink[pull] += self._blink_interval_ns(pulled, u[pull, 1])
            st.next_blink[pulled] = next_blink[pull]
            st.blink_onset[pulled] = onset
            self._new_blinking.append(pulled)
            self._blink_chunks.append((pulled, onset))
        return next_blink

    def _blink(self, idx: np.ndarray, times: np.ndarray) -> None:
        st = self._s
        next_blink = times + self._blink_interval_ns(idx)
        st.blink_onset[idx] = times
        st.next_blink[idx] = next_blink
        st.next_event[idx] = np.minimum(st.next_saccade[idx], next_blink)
        self._new_blinking.append(idx)
        self._blink_chunks.append((idx, times))

    def _blink_interval_ns(self, idx: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """Refractory gap plus an exponential, with the role's mean interval 60 / rate."""
        refractory = self.params.blink.refractory_s
        u = self._draw(idx, BLINK_STREAM, 1) if u is None else u
        mean = self._blink_mean_s[self._s.role[idx]]
        return np.rint((refractory - (mean - refractory) * np.log1p(-u)) * _NS).astype(np.int64)

    # ------------------------------------------------------------------ positions

    def _saccade_position(self, idx: np.ndarray, t: np.ndarray | np.int64) -> tuple[np.ndarray, np.ndarray]:
        """Eye position at `t` along each agent's current saccade; landed eyes skip the velocity profile."""
        st = self._s
        end = st.end[idx]
        to_yaw, to_pitch = st.to_yaw[idx], st.to_pitch[idx]
        in_flight = t < end
        if not in_flight.any():
            return to_yaw, to_pitch
        onset = st.onset[idx]
        duration = (end - onset).astype(np.float64)
        elapsed = (t - onset).astype(np.float64)
        progress = saccade_progress(np.divide(elapsed, duration, out=np.ones_like(elapsed), where=duration > 0))
        remaining = 1.0 - progress  # this form is exact at both ends of the saccade
        return st.from_yaw[idx] * remaining + to_yaw * progress, st.from_pitch[idx] * remaining + to_pitch * progress

    def _noise_position(self, idx: np.ndarray, t: int) -> tuple[np.ndarray, np.ndarray]:
        p = self.params
        st = self._s
        x = t * 1e-9 * p.noise_frequency_hz
        stream = idx.astype(np.uint64) * np.uint64(2)
        yaw = st.target_yaw[idx] + p.noise_yaw_amplitude_deg * perlin1d(x, self._seed_noise, stream)
        pitch = st.target_pitch[idx] + p.noise_pitch_amplitude_deg * perlin1d(
            x, self._seed_noise, stream + np.uint64(1)
        )
        return self._clip_yaw(yaw), self._clip_pitch(pitch)

    def _shown_position(self, idx: np.ndarray, t: int) -> tuple[np.ndarray, np.ndarray]:
        """Where each eye is at `t` in its current mode."""
        st = self._s
        yaw, pitch = self._saccade_position(idx, np.int64(t))
        mode = st.mode[idx]
        static = mode == STATIC
        yaw[static], pitch[static] = st.target_yaw[idx[static]], st.target_pitch[idx[static]]
        noisy = mode == NOISE
        if noisy.any():
            yaw[noisy], pitch[noisy] = self._noise_position(idx[noisy], t)
        return yaw, pitch

    def _fixate(self, idx: np.ndarray, t: int, yaw: np.ndarray, pitch: np.ndarray) -> None:
        st = self._s
        st.onset[idx] = st.end[idx] = t
        st.from_yaw[idx] = st.to_yaw[idx] = yaw
        st.from_pitch[idx] = st.to_pitch[idx] = pitch

    def _members(self, mode: int) -> np.ndarray:
        if mode not in self._members_cache:
            self._members_cache[mode] = np.flatnonzero(self._s.mode == mode)
        return self._members_cache[mode]

    def _apply_non_saccade_modes(self, t: int, yaw: np.ndarray, pitch: np.ndarray, lid: np.ndarray) -> None:
        st = self._s
        static = self._members(STATIC)
        if static.size:
            yaw[static], pitch[static] = st.target_yaw[static], st.target_pitch[static]
        noisy = self._members(NOISE)
        if noisy.size:
            yaw[noisy], pitch[noisy] = self._noise_position(noisy, t)
        for mode in (NOISE, SACCADE):
            members = self._members(mode)
            if members.size:
                lid[members] = perlin_blink(t * 1e-9, self._seed_perlin_blink, members.astype(np.uint64))

    # ------------------------------------------------------------------ output

    @staticmethod
    def _merge(current: np.ndarray, new: list[np.ndarray]) -> np.ndarray:
        # Duplicates (an agent relaunched mid-flight) are harmless: they write the same value twice and
        # drop out together; so no costly np.unique here.
        if not new:
            return current
        merged = np.concatenate([current, *new])
        new.clear()
        return merged

    def _take_saccades(self) -> SaccadeOnsets:
        chunks = self._saccade_chunks
        if not chunks:
            return SaccadeOnsets.empty()
        if len(chunks) == 1:
            agent, onset, kind, floats = chunks[0]
        else:
            agent, onset, kind = (np.concatenate(column) for column in list(zip(*chunks, strict=True))[:3])
            floats = np.concatenate([chunk[3] for chunk in chunks], axis=1)
        chunks.clear()
        order = np.lexsort((agent, onset))
        return SaccadeOnsets.from_columns(agent[order], onset[order], kind[order], floats[:, order])

    def _take_blinks(self) -> BlinkOnsets:
        if not self._blink_chunks:
            return BlinkOnsets.empty()
        agent = np.concatenate([c[0] for c in self._blink_chunks])
        onset = np.concatenate([c[1] for c in self._blink_chunks]).astype(np.int64)
        self._blink_chunks.clear()
        order = np.lexsort((agent, onset))
        return BlinkOnsets(agent[order], onset[order])

    def _clip_yaw(self, yaw: np.ndarray) -> np.ndarray:
        limit = self.params.eye_yaw_limit_deg
        return np.clip(np.asarray(yaw, dtype=np.float64), -limit, limit)

    def _clip_pitch(self, pitch: np.ndarray) -> np.ndarray:
        limit = self.params.eye_pitch_limit_deg
        return np.clip(np.asarray(pitch, dtype=np.float64), -limit, limit)


def _finite_pair(yaw: float | np.ndarray, pitch: float | np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray]:
    yaw_a = np.asarray(yaw, dtype=np.float64)
    pitch_a = np.asarray(pitch, dtype=np.float64)
    if not (np.all(np.isfinite(yaw_a)) and np.all(np.isfinite(pitch_a))):
        raise ValueError(f"{what} yaw/pitch must be finite numbers, got {yaw!r}, {pitch!r}")
    return yaw_a, pitch_a
