"""Offline rendering of a dialogue of several agents: their faces side by side, one CSV (and each agent's rig
frames), the mixed voices.

`agent.conversation_animator.ConversationAnimator` is sampled at exact frame times k / fps, as the single
agent's animator is (services/tools/offline.py), so the same seed and inputs give the same frames. Each agent
speaks its lines with a voice of its own and its mouth follows them; the user's lines are heard. The
picture holds one panel per agent, left to right in seat order, each drawn by the same renderer.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from eca.agent.animator import SpeechEvent, Utterance
from eca.agent.conversation_animator import ConversationAnimator
from eca.agent.face.composed import ComposedFace
from eca.agent.face.flexors import FLEXOR_NAMES
from eca.agent.gaze.backchannel import BackchannelParams
from eca.agent.gaze.situated import SituatedParams
from eca.agent.lipsync.estimator import mouth_track
from eca.agent.script import Timeline
from eca.services.tools.offline import (
    AUDIO_RATE,
    CSV_STATE_COLUMNS,
    RenderedTimeline,
    RenderSettings,
    agent_fields,
    face_angles,
    fixed6,
    mix,
    said_lines,
    speech_events,
    write_rig_csv,
)
from eca.services.tools.playback import AGENT_VOICE, PARTNER_VOICE, VoiceCache
from eca.services.tools.rig_csv import rig_csv_path

# espeak-ng voices by seat, cycled: the first agent speaks as the single agent does, the user as the
# partner does; none of the agents speaks with the user's.
AGENT_VOICES = (AGENT_VOICE, "en-us+m1", "en-us+f4", "en-us+m7", "en-us+f2", "en-us+m2")
PANEL_HEIGHT, PANEL_WIDTH = 300, 400  # each agent's panel when no --size is given (4:3, as one face)

# One CSV for all agents: a row per frame and agent (seat order), with whose turn it is.
CONVERSATION_CSV_COLUMNS = (CSV_STATE_COLUMNS[0], "agent", "speaker", "addressees", *CSV_STATE_COLUMNS[1:],
                            *FLEXOR_NAMES)


def voice_of(speaker: str, agents: Sequence[str]) -> str:
    """The espeak-ng voice a speaker's lines are spoken with."""
    return AGENT_VOICES[agents.index(speaker) % len(AGENT_VOICES)] if speaker in agents else PARTNER_VOICE


def default_size(n_agents: int) -> tuple[int, int]:
    return PANEL_WIDTH * n_agents, PANEL_HEIGHT


@dataclass
class RenderedConversation:
    """What a render produced besides the files: per frame its time and whose turn it is ('' and () between
    turns), and per agent (seat order) what services.tools.offline.RenderedTimeline holds for one."""

    agents: tuple[str, ...]
    t_s: np.ndarray
    speaker: tuple[str, ...]
    addressees: tuple[tuple[str, ...], ...]
    faces: tuple[RenderedTimeline, ...]
    audio: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.float32))


def gather_lines(timeline: Timeline, agents: Sequence[str], voices: VoiceCache | None,
                 min_pause_s: float) -> tuple[list[Utterance], dict[str, list[Utterance]], list[SpeechEvent]]:
    """Every line on the timeline (to mix), each agent's own (with its mouth track), and when each speaker's
    voice starts and stops (its pauses of `min_pause_s` or more, found in the audio)."""
    heard: list[Utterance] = []
    spoken: dict[str, list[Utterance]] = {agent: [] for agent in agents}
    voiced: list[tuple[Utterance, str]] = []
    for cue, samples in said_lines(timeline, voices, lambda speaker: voice_of(speaker, agents)):
        own = cue.agent in spoken
        line = Utterance(cue.t_s, samples, mouth_track(samples, AUDIO_RATE) if own else None)
        heard.append(line)
        if own:
            spoken[cue.agent].append(line)
        voiced.append((line, cue.agent))
    return heard, spoken, speech_events(voiced, min_pause_s)


def animate_conversation(
    timeline: Timeline, agents: Sequence[str], settings: RenderSettings, voices: VoiceCache | None,
    on_frame: Callable[[int, list[ComposedFace]], None] | None = None, situated: SituatedParams | None = None,
) -> RenderedConversation:
    """Every frame of every agent; `on_frame(k, the composed face of each agent)` sees each frame."""
    agents = tuple(agents)
    backchannel = BackchannelParams.load()
    heard, spoken, speech = gather_lines(timeline, agents, voices, backchannel.min_pause_s)
    audio = mix(heard, timeline.length_s)
    length_s = max(timeline.length_s, audio.size / AUDIO_RATE)
    n_frames = int(np.floor(length_s * settings.fps)) + 1
    animator = ConversationAnimator(timeline, agents, seed=settings.seed, eyes=settings.eyes, utterances=spoken,
                                    sample_rate=AUDIO_RATE, situated=situated, speech=speech,
                                    backchannel=backchannel)
    t_s = np.arange(n_frames) / settings.fps
    n = len(agents)
    flexors = np.empty((n, n_frames, len(FLEXOR_NAMES)))
    eyes = np.empty((n, n_frames, 3))
    head_deg = np.empty((n, n_frames, 3))
    eyes_deg = np.empty((n, n_frames, 4))
    intensity = np.empty((n, n_frames))
    roles: list[list[str]] = [[] for _ in agents]
    emotions: list[list[str]] = [[] for _ in agents]
    speakers: list[str] = []
    addressees: list[tuple[str, ...]] = []
    for k, t in enumerate(t_s):
        frame = animator.frame_at(float(t))
        for a, face in enumerate(frame.faces):
            flexors[a, k] = face.flexors
            eyes[a, k] = face.left_eye.yaw_deg, face.left_eye.pitch_deg, face.lid
            head_deg[a, k], eyes_deg[a, k] = face_angles(face)
            intensity[a, k] = face.emotion_intensity
            roles[a].append(face.role)
            emotions[a].append(face.emotion)
        speakers.append(frame.speaker or "")
        addressees.append(frame.addressees)
        if on_frame is not None:
            on_frame(k, list(frame.faces))
    faces = tuple(RenderedTimeline(t_s, eyes[a, :, 0], eyes[a, :, 1], eyes[a, :, 2], flexors[a], tuple(roles[a]),
                                   tuple(emotions[a]), intensity[a], head_deg=head_deg[a], eyes_deg=eyes_deg[a])
                  for a in range(n))
    return RenderedConversation(agents, t_s, tuple(speakers), tuple(addressees), faces, audio)


def write_conversation_csv(path: Path, rendered: RenderedConversation) -> None:
    """One header line (CONVERSATION_CSV_COLUMNS), then per frame one line per agent in seat order, in the
    single-agent CSV's fixed-precision text, with whose turn it is (names; addressees separated by spaces)."""
    with open(path, "w", newline="\n", encoding="utf-8") as fh:
        fh.write(",".join(CONVERSATION_CSV_COLUMNS) + "\n")
        for k, t in enumerate(rendered.t_s):
            turn = (fixed6(float(t)),)
            for agent, face in zip(rendered.agents, rendered.faces, strict=True):
                fields = (*turn, agent, rendered.speaker[k], " ".join(rendered.addressees[k]), *agent_fields(face, k))
                fh.write(",".join(fields) + "\n")


def write_conversation_rig_csvs(csv_path: Path, rendered: RenderedConversation, fps: float) -> list[Path]:
    """Each agent's rig frames as a Live Link Face CSV beside the conversation's CSV (one face a file, as the
    format holds one: services/tools/rig_csv.py); returns the files, in seat order."""
    paths = []
    for agent, face in zip(rendered.agents, rendered.faces, strict=True):
        paths.append(rig_csv_path(csv_path, agent))
        write_rig_csv(paths[-1], face, fps)
    return paths


def render_conversation_video(timeline: Timeline, voices: VoiceCache | None, agents: Sequence[str],
                              settings: RenderSettings, output: Path, csv_path: Path | None,
                              label: str = "render", rig: bool = False) -> RenderedConversation:
    """Render the agents side by side to `output` (MP4 with the mixed voices) and the CSV; with `rig`, each
    agent's rig frames beside the CSV too (write_conversation_rig_csvs)."""
    from eca.services.tools.video_render import render_panels

    def write_csvs(path: Path, result: RenderedConversation) -> None:
        write_conversation_csv(path, result)
        if rig:
            write_conversation_rig_csvs(path, result, settings.fps)

    return render_panels(lambda draw: animate_conversation(timeline, agents, settings, voices, on_frame=draw),
                         lambda result: result.audio, len(agents), settings.size, settings.fps, timeline.length_s,
                         settings.view, output, csv_path, write_csvs, label, face=settings.face)
