"""The live scene of one agent: the latest inputs from the bus in, the face at any display time out.

A renderer feeds a `LiveScene` every message it receives about its agent (plain values, no bus types)
and asks for `compose(t_ns)` (a ComposedFace) at each frame's display time:

- emotion and head: applied at their own timestamps, so the transition runs from when the state changed,
  not from when the renderer heard of it (a renderer that starts late shows a settled face at once);
- eyes: during a saccade mode, the exact trajectory (agent/gaze/synth.py) of the latest saccade whose
  onset is at or before t, evaluated at t itself, not the last sample received; in the static and noise
  modes, or before the first saccade, the eye-state samples interpolated at t (held past the newest);
- lids: the eye-state samples interpolated at t;
- mouth: the lip-sync keys of the utterance whose sample is at the DAC at t. A clock anchor maps an
  utterance's sample index to a DAC time, so sample(t) = anchor.sample + (t - anchor.dac) * rate; the
  weights are interpolated between keys. With no utterance playing (before its first sample, after its
  end, after a reset or an interruption) the mouth is handed back to the emotion.

Everything is a function of the inputs (values with their timestamps) and t: the same inputs give the
same frames at any frame rate. Pure numpy and stdlib.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from eca.agent.face.composed import ComposedFace
from eca.agent.face.frame import FlexorFrame
from eca.agent.face.gestures import HEAD_LEXEMES
from eca.agent.face.model import MOUTH_FLEXORS, FaceModel
from eca.agent.gaze.params import default_eye_mode
from eca.agent.gaze.synth import eye_position_one
from eca.agent.vocabulary import EYE_MODES, ROLES, SACCADE_MODES

_NEVER = 1 << 62


@dataclass(frozen=True)
class SaccadeEvent:
    """One saccade as the gaze service announced it (degrees, nanoseconds, seconds)."""

    onset_ns: int
    from_deg: tuple[float, float]
    to_deg: tuple[float, float]
    duration_s: float

    @property
    def end_ns(self) -> int:
        return self.onset_ns + round(self.duration_s * 1e9)

    def position_at(self, t_ns: int) -> tuple[float, float]:
        return eye_position_one(t_ns, self.onset_ns, self.from_deg, self.to_deg, self.duration_s)


@dataclass(frozen=True)
class EyeSample:
    t_ns: int
    yaw_deg: float
    pitch_deg: float
    lid: float
    mode: str


@dataclass
class _Utterance:
    """What the scene knows of one utterance: its keys, its clock anchors and its end."""

    sample_rate: int
    positions: list[int] = field(default_factory=list)
    rows: list[np.ndarray] = field(default_factory=list)  # weights per key, MOUTH_FLEXORS order
    anchors: list[tuple[int, int]] = field(default_factory=list)  # (dac_time_ns, sample_index), sorted
    estimated_start: bool = False  # the only anchor is the speech-started time, not a measured one
    end_sample: float = math.inf  # nothing at or after this sample is heard (finished / interrupted)
    closed_from_ns: int = _NEVER  # a reset closes the mouth from this time on
    last_update_ns: int = 0
    # Found silent from here on (past its end): every frame after that skips it at once, and a scene keeps a minute
    # of utterances. Only a new anchor can move where it ends (a later end or a reset only make it silent sooner).
    silent_from_ns: int = _NEVER

    def add_keys(self, positions: Sequence[int], rows: np.ndarray) -> None:
        for p, row in zip(positions, rows, strict=True):
            i = bisect.bisect_left(self.positions, p)
            if i < len(self.positions) and self.positions[i] == p:
                self.rows[i] = row
            else:
                self.positions.insert(i, int(p))
                self.rows.insert(i, row)

    def sample_at(self, t_ns: int) -> float | None:
        """The sample at the DAC at t_ns, from the latest anchor at or before t (else the first one)."""
        if not self.anchors:
            return None
        i = bisect.bisect_right(self.anchors, (t_ns, _NEVER)) - 1
        dac_ns, sample = self.anchors[max(i, 0)]
        return sample + (t_ns - dac_ns) * self.sample_rate / 1e9

    def playing_at(self, t_ns: int) -> float | None:
        """The sample heard at t_ns, or None when this utterance is silent then."""
        if t_ns >= self.closed_from_ns or t_ns >= self.silent_from_ns:
            return None
        sample = self.sample_at(t_ns)
        if sample is None or sample < 0:
            return None
        if sample >= self.end_sample:
            if t_ns >= self.anchors[-1][0]:  # on the last anchor's line, which only runs on: silent from here
                self.silent_from_ns = t_ns
            return None
        return sample

    def weights_at(self, sample: float) -> np.ndarray:
        """Interpolated key weights at a sample position; zeros (closed) outside the known keys."""
        pos = self.positions
        if not pos or sample < pos[0]:
            return np.zeros(len(MOUTH_FLEXORS))
        j = bisect.bisect_right(pos, sample) - 1
        if j >= len(pos) - 1:
            spacing = pos[-1] - pos[-2] if len(pos) > 1 else self.sample_rate // 100
            # A key describes the block that follows it; past that block the keys have not come yet.
            return self.rows[-1].copy() if sample - pos[-1] <= spacing else np.zeros(len(MOUTH_FLEXORS))
        frac = (sample - pos[j]) / (pos[j + 1] - pos[j])
        return (1.0 - frac) * self.rows[j] + frac * self.rows[j + 1]


class LiveScene:
    """One agent's face composed from live inputs; see the module docstring."""

    def __init__(self, seed: int = 0, idle_noise: bool = True, model: FaceModel | None = None,
                 history_s: float = 2.0, max_utterances: int = 16) -> None:
        self.model = model if model is not None else FaceModel(seed=seed, idle_noise=idle_noise, t_ns=0)
        self.history_ns = round(history_s * 1e9)
        self.max_utterances = max_utterances
        self.role = "listening"
        self.speaker = ""
        self.eye_mode = default_eye_mode()  # the commanded mode (eyes state) until eye samples say otherwise
        self.emotion: tuple[str, float] = ("natural", 1.0)
        self.head: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._settled_change_ns = 0
        self._head_change_ns = 0
        self.attention: tuple[float, float] = (0.0, 0.0)
        self._attention_change_ns = 0
        self._saccades: list[SaccadeEvent] = []  # sorted by onset
        self._onsets: list[int] = []  # their onset times
        self._samples: list[EyeSample] = []  # sorted by time
        self._sample_t: list[int] = []  # their times
        self._mode_runs: list[tuple[int, str]] = []  # (first sample time, mode) of each run of one mode
        self._utterances: dict[str, _Utterance] = {}
        self._starts: dict[str, int] = {}  # speech-started DAC times of utterances not seen yet

    # --- inputs ----------------------------------------------------------------------------------

    def set_role(self, role: str, t_ns: int, speaker: str = "") -> None:
        if role not in ROLES:
            raise ValueError(f"unknown role {role!r}; roles: {', '.join(ROLES)}")
        self.role = role
        self.speaker = speaker

    def set_emotion(self, name: str, intensity: float, transition_s: float, t_ns: int) -> None:
        """From t_ns (or the previous change, if that was later) blend toward the emotion."""
        t = max(int(t_ns), self._settled_change_ns)
        self.model.set_emotion(name, intensity, transition_s, t)
        self._settled_change_ns = t
        self.emotion = self.model.emotion

    def move_head(self, turn: float, nod: float, tilt: float, duration_s: float, t_ns: int) -> None:
        t = max(int(t_ns), self._head_change_ns)
        self.model.move_head(turn, nod, tilt, duration_s, t)
        self._head_change_ns = t
        self.head = (float(turn), float(nod), float(tilt))

    def attend(self, yaw_deg: float, pitch_deg: float, duration_s: float, t_ns: int) -> None:
        """Turn the head toward the person attended (the gaze service's attention state), on top of the
        scripted head; from t_ns or the previous change, if that was later."""
        for name, value in (("yaw", yaw_deg), ("pitch", pitch_deg), ("duration", duration_s)):
            if not math.isfinite(value):
                raise ValueError(f"attention {name} must be a finite number, got {value!r}")
        t = max(int(t_ns), self._attention_change_ns)
        self.model.attend(yaw_deg, pitch_deg, duration_s, t)
        self._attention_change_ns = t
        self.attention = (float(yaw_deg), float(pitch_deg))

    def nod(self, onset_ns: int, amplitude_deg: float, duration_s: float) -> None:
        """A listener's nod from onset_ns (a backchannel)."""
        self.model.nod(amplitude_deg, duration_s, int(onset_ns))

    def head_gesture(self, gesture_id: str, lexeme: str, onset_ns: int, amplitude_deg: float, duration_s: float,
                     repetitions: int) -> None:
        """A head gesture on the master clock (a BML head behaviour); it replaces the one of the same id."""
        if lexeme not in HEAD_LEXEMES:
            raise ValueError(f"a head gesture is one of {', '.join(HEAD_LEXEMES)}, got {lexeme!r}")
        self.model.head_gesture(gesture_id, lexeme, amplitude_deg, duration_s, repetitions,
                                int(onset_ns))

    def expression(self, expression_id: str, onset_ns: int, peak_ns: int, relax_ns: int, end_ns: int,
                   flexors: Mapping[str, float]) -> None:
        """A facial expression on the master clock (a BML faceLexeme, faceFacs); it replaces the one of the
        same id."""
        self.model.expression(expression_id, onset_ns, peak_ns, relax_ns, end_ns, flexors)

    def set_eye_mode(self, mode: str) -> None:
        """The commanded eye mode; the eye samples' own mode takes precedence once they arrive."""
        if mode not in EYE_MODES:
            raise ValueError(f"unknown eye mode {mode!r}; modes: {', '.join(EYE_MODES)}")
        self.eye_mode = mode

    def add_saccade(self, onset_ns: int, from_deg: tuple[float, float], to_deg: tuple[float, float],
                    duration_s: float) -> None:
        values = (*from_deg, *to_deg, duration_s)
        if not all(math.isfinite(v) for v in values) or duration_s < 0:
            raise ValueError(f"a saccade needs finite angles and a duration >= 0, got {values}")
        event = SaccadeEvent(int(onset_ns), (float(from_deg[0]), float(from_deg[1])),
                             (float(to_deg[0]), float(to_deg[1])), float(duration_s))
        i = bisect.bisect_right(self._onsets, event.onset_ns)
        self._onsets.insert(i, event.onset_ns)
        self._saccades.insert(i, event)

    def add_eye_sample(self, t_ns: int, yaw_deg: float, pitch_deg: float, lid: float, mode: str) -> None:
        if mode not in EYE_MODES:
            raise ValueError(f"unknown eye mode {mode!r}; modes: {', '.join(EYE_MODES)}")
        if not (math.isfinite(yaw_deg) and math.isfinite(pitch_deg) and math.isfinite(lid)):
            raise ValueError(f"an eye sample needs finite values, got {(yaw_deg, pitch_deg, lid)}")
        t = int(t_ns)
        sample = EyeSample(t, float(yaw_deg), float(pitch_deg), min(1.0, max(0.0, float(lid))), mode)
        if not self._sample_t or t >= self._sample_t[-1]:
            self._sample_t.append(t)
            self._samples.append(sample)
        else:
            i = bisect.bisect_right(self._sample_t, t)
            self._sample_t.insert(i, t)
            self._samples.insert(i, sample)
        if not self._mode_runs or (self._mode_runs[-1][1] != mode and sample.t_ns >= self._mode_runs[-1][0]):
            self._mode_runs.append((sample.t_ns, mode))
        self.eye_mode = self._samples[-1].mode

    def speech_started(self, request_id: str, dac_time_ns: int, sample_rate: int | None = None) -> None:
        """The utterance's first sample reaches the DAC at dac_time_ns (used until anchors arrive)."""
        utt = self._utterance(request_id, sample_rate)
        if utt is None:
            self._starts[request_id] = int(dac_time_ns)
            while len(self._starts) > self.max_utterances:
                del self._starts[next(iter(self._starts))]
        elif not utt.anchors:
            utt.anchors.append((int(dac_time_ns), 0))
            utt.estimated_start = True
            utt.last_update_ns = int(dac_time_ns)

    def speech_ended(self, request_id: str, played_s: float, t_ns: int) -> None:
        """Finished or interrupted after played_s seconds of audio: silent from that sample on."""
        utt = self._utterances.get(request_id)
        if utt is None:
            return
        utt.end_sample = min(utt.end_sample, max(0.0, played_s) * utt.sample_rate)
        utt.last_update_ns = max(utt.last_update_ns, int(t_ns))

    def speech_failed(self, request_id: str, t_ns: int) -> None:
        """Failed (the audio service died or restarted, say): no played_s and no mouth reset will come, so
        the mouth closes from the last moment the voice was known to play (its latest clock anchor)."""
        self._starts.pop(request_id, None)
        utt = self._utterances.get(request_id)
        if utt is None:
            return
        last_heard = utt.anchors[-1][0] if utt.anchors else int(t_ns)
        utt.closed_from_ns = min(utt.closed_from_ns, int(t_ns), last_heard)
        utt.last_update_ns = max(utt.last_update_ns, int(t_ns))

    def add_clock_anchor(self, request_id: str, sample_index: int, sample_rate: int, dac_time_ns: int) -> None:
        utt = self._utterance(request_id, sample_rate)
        assert utt is not None
        if utt.sample_rate != sample_rate:
            raise ValueError(f"utterance {request_id!r} changed its sample rate from {utt.sample_rate} "
                             f"to {sample_rate}")
        anchor = (int(dac_time_ns), int(sample_index))
        if utt.estimated_start:
            utt.anchors.clear()  # measured anchors replace the speech-started estimate
            utt.estimated_start = False
        bisect.insort(utt.anchors, anchor)
        utt.silent_from_ns = _NEVER  # where it ends may have moved
        utt.last_update_ns = max(utt.last_update_ns, anchor[0])

    def add_mouth_keys(self, request_id: str, sample_rate: int, sample_index: Sequence[int],
                       weights: Mapping[str, Sequence[float]], reset: bool = False, t_ns: int = 0) -> None:
        """Lip-sync keys of an utterance. reset: close the mouth from t_ns and drop every key known so
        far (an interruption); keys that come with the reset start that utterance afresh."""
        unknown = set(weights) - set(MOUTH_FLEXORS)
        if unknown:
            raise ValueError(f"unknown mouth shapes {sorted(unknown)}; mouth shapes: {', '.join(MOUTH_FLEXORS)}")
        n = len(sample_index)
        for name, values in weights.items():
            if len(values) != n:
                raise ValueError(f"mouth shape {name!r} has {len(values)} weights for {n} keys")
        rows = np.zeros((n, len(MOUTH_FLEXORS)))
        for name, values in weights.items():
            rows[:, MOUTH_FLEXORS.index(name)] = np.clip(np.asarray(values, dtype=np.float64), 0.0, 1.0)
        if not np.all(np.isfinite(rows)):
            raise ValueError("mouth weights must be finite")
        if reset:
            for utt in self._utterances.values():
                utt.closed_from_ns = min(utt.closed_from_ns, int(t_ns))
                utt.positions.clear()
                utt.rows.clear()
            if n:
                self._utterances.pop(request_id, None)
        if n:
            target = self._utterance(request_id, sample_rate)
            assert target is not None
            target.add_keys(list(sample_index), rows)
            target.last_update_ns = max(target.last_update_ns, int(t_ns))
        self._prune_utterances()

    # --- outputs ---------------------------------------------------------------------------------

    def eye_mode_at(self, t_ns: int) -> tuple[str, int]:
        """(mode, the time the latest run of non-saccade modes began before t; -1 if none)."""
        runs = self._mode_runs
        if not runs:
            return self.eye_mode, -1
        i = bisect.bisect_right(runs, (t_ns, "\uffff")) - 1
        mode = runs[max(i, 0)][1]
        since = -1
        for k in range(max(i, 0), -1, -1):
            if runs[k][1] not in SACCADE_MODES:
                since = runs[k][0]
                break
        return mode, since

    def eyes_at(self, t_ns: int) -> tuple[float | None, float | None, float | None]:
        """(yaw_deg, pitch_deg, lid) at t_ns; None where nothing is known yet."""
        mode, valid_after = self.eye_mode_at(t_ns)
        lid = None
        yaw: float | None = None
        pitch: float | None = None
        if self._samples:
            yaw, pitch, lid = self._interpolate_samples(t_ns)
        if mode in SACCADE_MODES:
            saccade = self.saccade_at(t_ns)
            if saccade is not None and saccade.onset_ns >= valid_after:
                yaw, pitch = saccade.position_at(t_ns)
        return yaw, pitch, lid

    def saccade_at(self, t_ns: int) -> SaccadeEvent | None:
        """The latest saccade whose onset is at or before t_ns."""
        i = bisect.bisect_right(self._onsets, t_ns) - 1
        return self._saccades[i] if i >= 0 else None

    def mouth_at(self, t_ns: int) -> dict[str, float] | None:
        """Mouth-shape weights at t_ns, or None when no utterance is heard then."""
        row = self.mouth_row_at(t_ns)
        return None if row is None else {name: float(v) for name, v in zip(MOUTH_FLEXORS, row, strict=True)}

    def mouth_row_at(self, t_ns: int) -> np.ndarray | None:
        """mouth_at's weights as a row in MOUTH_FLEXORS order (each in [0, 1]), or None."""
        best: tuple[int, float, _Utterance] | None = None
        for utt in self._utterances.values():
            sample = utt.playing_at(t_ns)
            if sample is None:
                continue
            started = utt.anchors[0][0] - round(utt.anchors[0][1] * 1e9 / utt.sample_rate)
            if best is None or started > best[0]:
                best = (started, sample, utt)
        if best is None:
            return None
        return best[2].weights_at(best[1])

    def voiced_at(self, t_ns: int) -> bool:
        """Whether an utterance is heard at t_ns (mouth_row_at is not None), without working out its weights."""
        return any(utt.playing_at(t_ns) is not None for utt in self._utterances.values())

    def compose(self, t_ns: int) -> ComposedFace:
        """The composed face at display time t_ns (agent/face/composed.py), with the role in force."""
        t = int(t_ns)
        self.pose_model(t)
        return self.model.compose(t, role=self.role)

    def pose_model(self, t_ns: int) -> bool:
        """Give the face model this scene's eyes and mouth at t_ns (what compose does before composing, and a batch
        of many faces, agent/face/batch.py); whether an utterance is heard then (voiced_at, without a second look)."""
        yaw, pitch, lid = self.eyes_at(t_ns)
        self.model.set_eyes(yaw, pitch, lid)
        mouth = self.mouth_row_at(t_ns)
        self.model.set_mouth_row(mouth)
        return mouth is not None

    def frame_at(self, t_ns: int) -> FlexorFrame:
        """The composed face's flexor frame at display time t_ns."""
        return self.compose(t_ns).frame

    def prune(self, t_ns: int) -> None:
        """Forget inputs no frame at or after t_ns - history can need (call with the frame time)."""
        horizon = int(t_ns) - self.history_ns
        keep_from = bisect.bisect_right(self._onsets, horizon) - 1  # the one in force at the horizon stays
        if keep_from > 0:
            del self._saccades[:keep_from]
            del self._onsets[:keep_from]
        keep_from = bisect.bisect_right(self._sample_t, horizon) - 1
        if keep_from > 0:
            del self._samples[:keep_from]
            del self._sample_t[:keep_from]
        if len(self._mode_runs) > 16:
            del self._mode_runs[:-16]
        self._prune_utterances(horizon)

    # --- internals -------------------------------------------------------------------------------

    def _utterance(self, request_id: str, sample_rate: int | None) -> _Utterance | None:
        utt = self._utterances.get(request_id)
        if utt is None:
            if sample_rate is None:
                return None
            if sample_rate <= 0:
                raise ValueError(f"sample rate must be positive, got {sample_rate}")
            utt = self._utterances[request_id] = _Utterance(int(sample_rate))
            start = self._starts.pop(request_id, None)
            if start is not None:
                utt.anchors.append((start, 0))
                utt.estimated_start = True
                utt.last_update_ns = start
        return utt

    def _prune_utterances(self, horizon: int | None = None) -> None:
        if horizon is not None:
            for rid in [r for r, u in self._utterances.items() if u.last_update_ns < horizon - 60 * 10**9]:
                del self._utterances[rid]
        while len(self._utterances) > self.max_utterances:
            oldest = min(self._utterances, key=lambda r: self._utterances[r].last_update_ns)
            del self._utterances[oldest]

    def _interpolate_samples(self, t_ns: int) -> tuple[float, float, float]:
        s = self._samples
        i = bisect.bisect_right(self._sample_t, t_ns)
        if i == 0 or i >= len(s):
            one = s[0] if i == 0 else s[-1]
            return one.yaw_deg, one.pitch_deg, one.lid
        a, b = s[i - 1], s[i]
        frac = (t_ns - a.t_ns) / max(1, b.t_ns - a.t_ns)
        return (a.yaw_deg + frac * (b.yaw_deg - a.yaw_deg), a.pitch_deg + frac * (b.pitch_deg - a.pitch_deg),
                a.lid + frac * (b.lid - a.lid))

