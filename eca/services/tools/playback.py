"""From a script timeline to bus commands: what `eca play` publishes, and the voices it speaks with.

A script is replayed as ordinary commands on `cmd.`, so the services react exactly as they do to a
live dialogue manager. Lines with text and no audio file are spoken with espeak-ng; the WAVs are
made before playback starts (and cached), so timing never waits on synthesis.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path

from eca.agent.script import EmotionCue, GazeCue, HeadCue, RoleCue, SayCue, Timeline, wav_duration
from eca.protocol.messages import Message, MoveHead, Say, SetEmotion, SetEyes, SetGazeTarget, SetRole
from eca.services.processes.audio.tts import synthesize

AGENT_VOICE = "en-us+f3"
PARTNER_VOICE = "en-us+m3"


def default_cache_dir() -> Path:
    root = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(root) / "eca" / "voice"


@dataclass
class VoiceCache:
    """espeak-ng speech for a text and voice, synthesized once and kept by content hash."""

    directory: Path = field(default_factory=default_cache_dir)

    def path_for(self, text: str, voice: str = AGENT_VOICE) -> Path:
        key = hashlib.sha1(f"{voice}\n{text}".encode()).hexdigest()[:16]
        path = self.directory / f"{key}.wav"
        if not path.exists():
            tmp = path.with_suffix(f".{os.getpid()}.tmp.wav")
            synthesize(text, tmp, voice=voice)
            os.replace(tmp, path)  # atomic: a parallel run never reads half a file
        return path

    def duration_of_text(self, text: str) -> float:
        return wav_duration(self.path_for(text))


@dataclass
class CueTranslator:
    """Turns cues into commands for the agent; tracks the head so a cue may leave an axis alone."""

    agent: str
    voices: VoiceCache | None = None
    head: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gaze: tuple[float, float] = (0.0, 0.0)

    def commands(self, cue: RoleCue | EmotionCue | HeadCue | GazeCue | SayCue) -> list[Message]:
        if cue.agent != self.agent:
            return []  # the partner's lines: heard, not animated (their role cues are the agent's)
        if isinstance(cue, RoleCue):
            return [SetRole(agent=self.agent, role=cue.role)]
        if isinstance(cue, EmotionCue):
            return [SetEmotion(agent=self.agent, name=cue.name, intensity=cue.intensity,
                               transition_s=min(cue.transition_s, 30.0))]
        if isinstance(cue, HeadCue):
            self.head = cue.targets(self.head)
            return [MoveHead(agent=self.agent, turn=self.head[0], nod=self.head[1], tilt=self.head[2],
                             duration_s=min(cue.duration_s, 30.0))]
        if isinstance(cue, GazeCue):
            out: list[Message] = []
            if cue.mode is not None:
                out.append(SetEyes(agent=self.agent, mode=cue.mode))
            target = cue.target(self.gaze)
            if target is not None:
                self.gaze = target
                out.append(SetGazeTarget(agent=self.agent, yaw_deg=target[0], pitch_deg=target[1]))
            return out
        path = cue.audio_path
        if path is None:
            if self.voices is None:
                return []
            path = str(self.voices.path_for(cue.text, AGENT_VOICE))
        return [Say(agent=self.agent, request_id=cue.utterance_id, audio_path=path, text=cue.text or None)]


def prepare_voices(timeline: Timeline, voices: VoiceCache, agent: str) -> None:
    """Synthesize every line before playback, so publishing never waits on espeak-ng."""
    for cue in timeline.cues:
        if isinstance(cue, SayCue) and cue.audio_path is None and cue.text:
            voices.path_for(cue.text, AGENT_VOICE if cue.agent == agent else PARTNER_VOICE)
