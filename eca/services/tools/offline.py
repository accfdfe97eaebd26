"""Deterministic offline rendering: a script's timeline through the same models on a virtual clock.

No real time and no bus: `agent.animator.TimelineAnimator` is sampled at exact frame times k / fps,
so the same seed and inputs give the same flexor frames, byte for byte in the CSV. This module adds
what needs files: the voices, the mixed audio track, the CSV and the MP4 mux.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import numpy as np

from eca.agent.animator import SpeechEvent, TimelineAnimator, Utterance
from eca.agent.face.composed import ComposedFace
from eca.agent.face.flexors import FLEXOR_NAMES
from eca.agent.gaze.backchannel import BackchannelParams
from eca.agent.gaze.params import default_eye_mode
from eca.agent.lipsync.estimator import mouth_track
from eca.agent.lipsync.pauses import speech_segments
from eca.agent.script import SayCue, Timeline
from eca.services.processes.audio.files import read_sound_file
from eca.services.processes.audio.resample import resample
from eca.services.tools.playback import AGENT_VOICE, PARTNER_VOICE, VoiceCache
from eca.services.tools.rig_csv import write_live_link_csv

AUDIO_RATE = 22_050  # espeak-ng's rate; other audio is resampled to it


@dataclass(frozen=True)
class RenderSettings:
    fps: float = 30.0
    size: tuple[int, int] = (640, 480)
    view: str = "full"
    eyes: str | None = field(default_factory=default_eye_mode)  # None: the script's own eye-mode cues decide
    seed: int = 0
    face: str = "flexor"  # every agent's face: a drawer kind or an avatar file (renderer/faces.py)


@dataclass
class RenderedTimeline:
    """What a render produced, besides the files: per frame, its time, the agent's role and emotion in
    force, the eye angles and lid, and the flexor values (units in docs/scripts.md, "The flexor CSV"); and the
    composed face's angles in degrees (agent/face/composed.py), which the rig frames are made of."""

    t_s: np.ndarray
    eye_yaw_deg: np.ndarray
    eye_pitch_deg: np.ndarray
    lid: np.ndarray
    flexors: np.ndarray  # (frames, N_FLEXORS)
    role: tuple[str, ...] = ()
    emotion: tuple[str, ...] = ()
    emotion_intensity: np.ndarray = field(default_factory=lambda: np.zeros(0))
    audio: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.float32))
    head_deg: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (frames, 3): yaw, pitch, roll
    eyes_deg: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))  # (frames, 4): left, right yaw and pitch


def face_angles(face: ComposedFace) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
    """A composed face's (head yaw, pitch, roll) and (left eye yaw, pitch, right eye yaw, pitch), degrees."""
    left, right = face.left_eye, face.right_eye
    return ((face.head_yaw_deg, face.head_pitch_deg, face.head_roll_deg),
            (left.yaw_deg, left.pitch_deg, right.yaw_deg, right.pitch_deg))


def write_rig_csv(path: Path, rendered: RenderedTimeline, fps: float) -> None:
    """The rig frames of one rendered face as a Live Link Face CSV (services/tools/rig_csv.py)."""
    write_live_link_csv(path, fps, rendered.flexors, rendered.head_deg, rendered.eyes_deg)


def load_audio(path: str | Path) -> np.ndarray:
    """Mono float32 at AUDIO_RATE from any file soundfile reads; AudioFileError (a ValueError naming the
    file and the cause) when it cannot be read."""
    mono, rate = read_sound_file(path)
    return resample(mono, rate, AUDIO_RATE).astype(np.float32) if rate != AUDIO_RATE else mono


def gather_speech(timeline: Timeline, agent: str, voices: VoiceCache | None) -> list[Utterance]:
    """Every line on the timeline, the agent's own with its mouth track."""
    return [u for u, _ in _lines(timeline, agent, voices)]


def speech_events(lines: list[tuple[Utterance, str]], min_pause_s: float) -> list[SpeechEvent]:
    """When each speaker's voice starts and stops: its pauses of `min_pause_s` or more, found in the audio."""
    events: list[SpeechEvent] = []
    for line, speaker in lines:
        for start, end in speech_segments(line.samples, AUDIO_RATE, min_pause_s):
            events += [(line.start_s + start, speaker, True), (line.start_s + end, speaker, False)]
    return events


def said_lines(timeline: Timeline, voices: VoiceCache | None,
               voice_for: Callable[[str], str]) -> Iterator[tuple[SayCue, np.ndarray]]:
    """Each say on the timeline that has a sound, with its samples: its own audio file, or its text spoken
    in the voice `voice_for(agent)` when there is a voice cache."""
    for cue in timeline.cues:
        if not isinstance(cue, SayCue):
            continue
        if cue.audio_path is not None:
            path = Path(cue.audio_path)
        elif voices is not None and cue.text:
            path = voices.path_for(cue.text, voice_for(cue.agent))
        else:
            continue
        yield cue, load_audio(path)


def _lines(timeline: Timeline, agent: str, voices: VoiceCache | None) -> list[tuple[Utterance, str]]:
    def voice_for(speaker: str) -> str:
        return AGENT_VOICE if speaker == agent else PARTNER_VOICE

    return [(Utterance(cue.t_s, samples, mouth_track(samples, AUDIO_RATE) if cue.agent == agent else None),
             cue.agent) for cue, samples in said_lines(timeline, voices, voice_for)]


def mix(utterances: list[Utterance], length_s: float) -> np.ndarray:
    n = int(np.ceil(length_s * AUDIO_RATE))
    for u in utterances:
        n = max(n, int(round(u.start_s * AUDIO_RATE)) + u.samples.size)
    track = np.zeros(n, dtype=np.float32)
    for u in utterances:
        start = int(round(u.start_s * AUDIO_RATE))
        track[start:start + u.samples.size] += u.samples
    return np.clip(track, -1.0, 1.0)


# The CSV's columns before the flexors; docs/scripts.md ("The flexor CSV") gives each one's unit and range.
CSV_STATE_COLUMNS = ("t_s", "role", "emotion", "emotion_intensity", "eye_yaw_deg", "eye_pitch_deg", "lid")
CSV_COLUMNS = (*CSV_STATE_COLUMNS, *FLEXOR_NAMES)


def fixed6(value: float) -> str:
    # Six decimals (a microsecond, a millionth of a flexor's range); -0 printed as 0 so that a value
    # rounding to zero reads the same from either side.
    text = f"{value:.6f}"
    return text[1:] if text == "-0.000000" else text


def agent_fields(rendered: RenderedTimeline, k: int) -> tuple[str, ...]:
    """Frame k's columns after `t_s` (CSV_COLUMNS[1:]) as text: role and emotion as names, numbers with six
    decimals."""
    state = (rendered.role[k], rendered.emotion[k], fixed6(float(rendered.emotion_intensity[k])),
             fixed6(float(rendered.eye_yaw_deg[k])), fixed6(float(rendered.eye_pitch_deg[k])),
             fixed6(float(rendered.lid[k])))
    return (*state, *(fixed6(float(v)) for v in rendered.flexors[k]))


def write_flexor_csv(path: Path, rendered: RenderedTimeline) -> None:
    """One header line (CSV_COLUMNS), then one line per frame in fixed-precision text, so identical
    frames give identical bytes. Role and emotion are names; every number has six decimals."""
    with open(path, "w", newline="\n", encoding="utf-8") as fh:
        fh.write(",".join(CSV_COLUMNS) + "\n")
        for k, t in enumerate(rendered.t_s):
            fh.write(",".join((fixed6(float(t)), *agent_fields(rendered, k))) + "\n")


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
            on_frame: Callable[[int, ComposedFace], None] | None = None) -> RenderedTimeline:
    """Every frame's flexors (and eye angles) for the timeline; `on_frame(k, face)` sees each composed face."""
    lines = _lines(timeline, agent, voices)
    utterances = [u for u, _ in lines]
    audio = mix(utterances, timeline.length_s)
    length_s = max(timeline.length_s, audio.size / AUDIO_RATE)
    n_frames = int(np.floor(length_s * settings.fps)) + 1
    backchannel = BackchannelParams.load()
    animator = TimelineAnimator(timeline, agent, seed=settings.seed, eyes=settings.eyes, utterances=utterances,
                                sample_rate=AUDIO_RATE, speech=speech_events(lines, backchannel.min_pause_s),
                                backchannel=backchannel)
    t_s = np.arange(n_frames) / settings.fps
    flexors = np.empty((n_frames, len(FLEXOR_NAMES)))
    eyes = np.empty((n_frames, 3))
    head_deg = np.empty((n_frames, 3))
    eyes_deg = np.empty((n_frames, 4))
    intensity = np.empty(n_frames)
    roles: list[str] = []
    emotions: list[str] = []
    for k, t in enumerate(t_s):
        frame = animator.frame_at(float(t))
        flexors[k] = frame.flexors
        eyes[k] = frame.left_eye.yaw_deg, frame.left_eye.pitch_deg, frame.lid
        head_deg[k], eyes_deg[k] = face_angles(frame)
        roles.append(frame.role)
        emotions.append(frame.emotion)
        intensity[k] = frame.emotion_intensity
        if on_frame is not None:
            on_frame(k, frame)
    return RenderedTimeline(t_s, eyes[:, 0], eyes[:, 1], eyes[:, 2], flexors, tuple(roles), tuple(emotions),
                            intensity, audio, head_deg, eyes_deg)
