"""Deterministic offline rendering: a script's timeline through the same models on a virtual clock.

No real time and no bus: the frames are computed at exact frame times k / fps, so the same seed and
inputs give the same flexor frames, byte for byte in the CSV. The seed drives only the eyes and the
blinks (the face's idle noise has its own fixed seed), so another seed changes nothing else.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import numpy as np
import soundfile

from agent.clock import nanoseconds
from agent.config import load_toml
from agent.face.flexors import FLEXOR_NAMES
from agent.face.model import FaceModel
from agent.gaze.engine import GazeEngine
from agent.lipsync.estimator import MouthTrack, mouth_track
from agent.script import EmotionCue, GazeCue, HeadCue, RoleCue, SayCue, Timeline
from services.audio.resample import resample
from services.playback import AGENT_VOICE, PARTNER_VOICE, VoiceCache

AUDIO_RATE = 22_050  # espeak-ng's rate; other audio is resampled to it
FACE_IDLE_SEED = 7  # fixed: the render seed changes eyes and blinks only


@dataclass(frozen=True)
class RenderSettings:
    fps: float = 30.0
    size: tuple[int, int] = (640, 480)
    view: str = "full"
    eyes: str | None = "saccade+blink"  # None: the script's own eye-mode cues decide
    seed: int = 0


@dataclass
class RenderedTimeline:
    """What a render produced, besides the files: per-frame times, eye angles and flexor values."""

    t_s: np.ndarray
    eye_yaw_deg: np.ndarray
    eye_pitch_deg: np.ndarray
    lid: np.ndarray
    flexors: np.ndarray  # (frames, N_FLEXORS)
    audio: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.float32))


@dataclass
class _Utterance:
    start_s: float
    samples: np.ndarray
    track: MouthTrack | None  # the agent's own lines move its mouth


def load_audio(path: str | Path) -> np.ndarray:
    """Mono float32 at AUDIO_RATE from any file soundfile reads."""
    data, rate = soundfile.read(str(path), dtype="float32", always_2d=True)
    mono = data.mean(axis=1)
    return resample(mono, int(rate), AUDIO_RATE).astype(np.float32) if rate != AUDIO_RATE else mono


def gather_speech(timeline: Timeline, agent: str, voices: VoiceCache | None) -> list[_Utterance]:
    out = []
    for cue in timeline.cues:
        if not isinstance(cue, SayCue):
            continue
        if cue.audio_path is not None:
            path: Path | None = Path(cue.audio_path)
        elif voices is not None and cue.text:
            path = voices.path_for(cue.text, AGENT_VOICE if cue.agent == agent else PARTNER_VOICE)
        else:
            path = None
        if path is None:
            continue
        samples = load_audio(path)
        track = mouth_track(samples, AUDIO_RATE) if cue.agent == agent else None
        out.append(_Utterance(cue.t_s, samples, track))
    return out


def mix(utterances: list[_Utterance], length_s: float) -> np.ndarray:
    n = int(np.ceil(length_s * AUDIO_RATE))
    for u in utterances:
        n = max(n, int(round(u.start_s * AUDIO_RATE)) + u.samples.size)
    track = np.zeros(n, dtype=np.float32)
    for u in utterances:
        start = int(round(u.start_s * AUDIO_RATE))
        track[start:start + u.samples.size] += u.samples
    return np.clip(track, -1.0, 1.0)


class TimelineAnimator:
    """The models for one agent, fed the timeline's cues at their exact times, sampled per frame."""

    def __init__(self, timeline: Timeline, agent: str, settings: RenderSettings,
                 utterances: list[_Utterance]) -> None:
        self.agent = agent
        self.settings = settings
        self.cues = [c for c in timeline.cues if c.agent == agent and not isinstance(c, SayCue)]
        self.next_cue = 0
        self.utterances = [u for u in utterances if u.track is not None]
        head = load_toml("flexor_units")["head"]
        self.head_deg = (float(head["turn_deg"]), float(head["nod_deg"]))
        self.head = [0.0, 0.0, 0.0]
        self.target = [0.0, 0.0]  # gaze target yaw, pitch (degrees): a cue may leave an axis alone
        self.face = FaceModel(seed=FACE_IDLE_SEED, idle_noise=True)
        self.gaze = GazeEngine(1, settings.seed, start_ns=0)
        if settings.eyes is not None:
            self.gaze.set_mode(0, settings.eyes, 0)

    def frame_at(self, t_s: float) -> tuple[np.ndarray, tuple[float, float, float]]:
        t_ns = nanoseconds(t_s)
        while self.next_cue < len(self.cues) and nanoseconds(self.cues[self.next_cue].t_s) <= t_ns:
            cue = self.cues[self.next_cue]
            self._apply(cue, max(nanoseconds(cue.t_s), self.gaze.now_ns))
            self.next_cue += 1
        tick = self.gaze.tick(t_ns)
        yaw, pitch, lid = float(tick.yaw_deg[0]), float(tick.pitch_deg[0]), float(tick.lid[0])
        self.face.set_eyes(yaw, pitch, lid)
        self.face.set_mouth(self._mouth_at(t_s))
        return self.face.frame_at(t_ns).values, (yaw, pitch, lid)

    def _apply(self, cue: RoleCue | EmotionCue | HeadCue | GazeCue, t_ns: int) -> None:
        if isinstance(cue, RoleCue):
            self.gaze.set_role(0, cue.role, t_ns)
        elif isinstance(cue, EmotionCue):
            self.face.set_emotion(cue.name, cue.intensity, cue.transition_s, t_ns)
            self.gaze.set_emotion(0, cue.name, cue.intensity, t_ns)
        elif isinstance(cue, HeadCue):
            for axis, value in enumerate((cue.turn, cue.nod, cue.tilt)):
                if value is not None:
                    self.head[axis] = value
            self.face.move_head(*self.head, cue.duration_s, t_ns)
            self.gaze.set_head(0, self.head[0] * self.head_deg[0], self.head[1] * self.head_deg[1], t_ns)
        elif isinstance(cue, GazeCue):
            if cue.mode is not None and self.settings.eyes is None:
                self.gaze.set_mode(0, cue.mode, t_ns)
            if cue.yaw_deg is not None or cue.pitch_deg is not None:
                for axis, value in enumerate((cue.yaw_deg, cue.pitch_deg)):
                    if value is not None:
                        self.target[axis] = value
                self.gaze.set_target(0, *self.target, t_ns)

    def _mouth_at(self, t_s: float) -> dict[str, float] | None:
        for u in self.utterances:
            index = (t_s - u.start_s) * AUDIO_RATE
            if 0 <= index < u.samples.size:
                assert u.track is not None
                return u.track.weights_at(index)
        return None


def write_flexor_csv(path: Path, t_s: np.ndarray, flexors: np.ndarray) -> None:
    """Fixed-precision text, so identical frames give identical bytes."""
    with open(path, "w", newline="\n") as fh:
        fh.write("t_s," + ",".join(FLEXOR_NAMES) + "\n")
        for t, row in zip(t_s, flexors, strict=True):
            fh.write(f"{t:.6f}," + ",".join(f"{v:.6f}" for v in row) + "\n")


def mux_audio(video_path: Path, audio: np.ndarray, out_path: Path) -> None:
    """Copy the video stream and add the audio as AAC into one MP4."""
    import av

    with av.open(str(video_path)) as src, av.open(str(out_path), mode="w") as dst:
        v_in = src.streams.video[0]
        v_out = dst.add_stream_from_template(v_in)
        a_out = dst.add_stream("aac", rate=AUDIO_RATE, layout="mono")
        a_out.bit_rate = 48_000  # speech: plenty at 22 kHz mono, a third of the default
        for packet in src.demux(v_in):
            if packet.dts is None:
                continue
            packet.stream = v_out
            dst.mux(packet)
        pcm = (audio * 32767).astype(np.int16)
        chunk = 1024
        for start in range(0, pcm.size, chunk):
            frame = av.AudioFrame.from_ndarray(pcm[None, start:start + chunk], format="s16", layout="mono")
            frame.sample_rate = AUDIO_RATE
            frame.pts = start
            frame.time_base = Fraction(1, AUDIO_RATE)
            for packet in a_out.encode(frame):
                dst.mux(packet)
        for packet in a_out.encode(None):
            dst.mux(packet)


def animate(timeline: Timeline, agent: str, settings: RenderSettings, voices: VoiceCache | None,
            on_frame: Callable[[int, np.ndarray], None] | None = None) -> RenderedTimeline:
    """Every frame's flexors (and eye angles) for the timeline; `on_frame(k, flexors)` sees each."""
    utterances = gather_speech(timeline, agent, voices)
    audio = mix(utterances, timeline.length_s)
    length_s = max(timeline.length_s, audio.size / AUDIO_RATE)
    n_frames = int(np.floor(length_s * settings.fps)) + 1
    animator = TimelineAnimator(timeline, agent, settings, utterances)
    t_s = np.arange(n_frames) / settings.fps
    flexors = np.empty((n_frames, len(FLEXOR_NAMES)))
    eyes = np.empty((n_frames, 3))
    for k, t in enumerate(t_s):
        flexors[k], eyes[k] = animator.frame_at(float(t))
        if on_frame is not None:
            on_frame(k, flexors[k])
    return RenderedTimeline(t_s, eyes[:, 0], eyes[:, 1], eyes[:, 2], flexors, audio)
