"""Dialogue scripts in XML, in the shape of the paper's Table 1 (docs/scripts.md has the schema).

    <dialogue agent="ada" partner="user">
      <params href="head.txt"/>
      <turn speaker="ada" emotion="happy">Good morning!</turn>
      <turn speaker="user">Morning. Is the report ready?</turn>
      <silence duration="2" emotion="disappointed"/>
    </dialogue>

Turns follow one another; a turn lasts its `duration`, else its audio's length (measured through the
`duration_of` hook), else an estimate from its word count. Everything becomes one Timeline.
"""

from __future__ import annotations

import math
import re
import wave
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from agent.script.elements import AnimationElement, SayCue, Timeline, flexor_tuple, merge
from agent.script.errors import ScriptError
from agent.script.paramfile import (
    AGENT_ID_RE,
    DEFAULT_EMOTION_TRANSITION_S,
    ParamFile,
    eye_range_deg,
    parse_params,
)
from agent.script.poses import emotion_pose
from agent.script.textfile import read_bytes
from agent.script.vocab import (
    EYE_MODES,
    ROLES,
    Role,
    emotion_names,
    parse_emotion,
    parse_eye_mode,
    parse_role,
)
from agent.script.xmltree import Node, parse_xml

DEFAULT_WPM = 160.0  # a calm speaking rate; espeak-ng's default is 175
DEFAULT_GAP_S = 0.3  # between two speech turns: conversational turn-taking gaps are ~0.2-0.5 s
MIN_SPEECH_S = 0.6
DEFAULT_HEAD_S = 1.0

_NUMBER_RE = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_ATTRS = {
    "dialogue": {"agent", "partner", "wpm", "gap", "title"},
    "params": {"href", "offset", "agent"},
    "turn": {"speaker", "role", "emotion", "intensity", "transition", "audio", "duration", "id"},
    "silence": {"duration", "speaker", "role", "emotion", "intensity", "transition"},
    "head": {"turn", "nod", "tilt", "duration", "at"},
    "gaze": {"mode", "yaw", "pitch", "at", "duration"},
}

DurationOf = Callable[[Path], float]


def wav_duration(path: Path) -> float:
    """Seconds of a WAV file (stdlib only); other formats need the service layer's hook."""
    if path.suffix.lower() not in (".wav", ".wave"):
        raise ValueError(f"cannot measure {path.suffix or 'extensionless'} audio here; use WAV or "
                         "give the turn a duration")
    with wave.open(str(path), "rb") as wav:
        return wav.getnframes() / float(wav.getframerate())


def estimate_speech_s(text: str, wpm: float = DEFAULT_WPM) -> float:
    """Speaking time of `text` from its word count."""
    return max(MIN_SPEECH_S, len(text.split()) * 60.0 / wpm)


@dataclass(frozen=True)
class Dialogue:
    path: str
    agent: str
    partner: str
    turns: int
    silences: int
    params: tuple[ParamFile, ...]
    timeline: Timeline


class _Builder:
    def __init__(self, name: str, base: Path, duration_of: DurationOf,
                 text_duration: Callable[[str], float] | None) -> None:
        self.name = name
        self.base = base
        self.duration_of = duration_of
        self.text_duration = text_duration
        self.elements: list[AnimationElement] = []
        self.says: list[SayCue] = []
        self.params: list[ParamFile] = []
        self.ids: set[str] = set()
        self.roles: list[tuple[float, Role, int]] = []
        self.emotions: list[tuple[float, str, float, float, int]] = []

    def fail(self, node: Node, message: str) -> ScriptError:
        return ScriptError(self.name, node.line, node.column, f"<{node.tag}>: {message}")

    def check_attrs(self, node: Node, required: tuple[str, ...] = ()) -> None:
        allowed = _ATTRS[node.tag]
        for key in node.attrs:
            if key not in allowed:
                raise self.fail(node, f"unknown attribute {key!r}; allowed: {', '.join(sorted(allowed))}")
        for key in required:
            if key not in node.attrs:
                raise self.fail(node, f"missing attribute {key!r}")

    def number(self, node: Node, key: str, default: float, lo: float, hi: float, unit: str = "") -> float:
        value = self.optional(node, key, lo, hi, unit)
        return default if value is None else value

    def optional(self, node: Node, key: str, lo: float, hi: float, unit: str = "") -> float | None:
        if key not in node.attrs:
            return None
        raw = node.attrs[key].strip()
        if not _NUMBER_RE.fullmatch(raw):
            raise self.fail(node, f"attribute {key}={node.attrs[key]!r} is not a number")
        value = float(raw)
        if not (math.isfinite(value) and lo <= value <= hi):
            raise self.fail(node, f"attribute {key}={raw} is out of range [{lo:g}, {hi:g}]{unit}")
        return value

    def agent_id(self, node: Node, key: str, default: str | None) -> str:
        value = node.attrs.get(key, default)
        if value is None:
            raise self.fail(node, f"missing attribute {key!r}")
        if not AGENT_ID_RE.fullmatch(value):
            raise self.fail(node, f"attribute {key}={value!r} must be 1-64 letters, digits, '_', '-' or '.'")
        return value

    def path(self, node: Node, key: str) -> Path:
        raw = node.attrs[key].strip()
        if not raw:
            raise self.fail(node, f"attribute {key} is empty")
        try:
            path = (self.base / raw).resolve()
            found = path.is_file()
        except (OSError, ValueError):  # a name too long for the OS, or one holding a NUL
            found = False
            path = self.base / raw
        if not found:
            raise self.fail(node, f"{key} file {raw!r} not found (looked for {path})")
        return path

    # --- the document ---------------------------------------------------------------------------

    def build(self, root: Node) -> Dialogue:
        if root.tag != "dialogue":
            raise self.fail(root, "the root element must be <dialogue>")
        self.check_attrs(root, ("agent",))
        self.agent = self.agent_id(root, "agent", None)
        self.partner = self.agent_id(root, "partner", "user")
        if self.partner == self.agent:
            raise self.fail(root, "agent and partner must differ")
        self.wpm = self.number(root, "wpm", DEFAULT_WPM, 40, 400, " words per minute")
        self.gap = self.number(root, "gap", DEFAULT_GAP_S, 0, 60, " seconds")
        if root.text.strip():
            raise self.fail(root, "text directly inside <dialogue>; put speech in a <turn>")
        cursor = 0.0
        previous_speech = False
        turns = silences = 0
        for child in root.children:
            if child.tag == "params":
                self.include(child)
            elif child.tag == "turn":
                if previous_speech:
                    cursor += self.gap
                cursor = self.turn(child, cursor, turns + 1)
                previous_speech, turns = True, turns + 1
            elif child.tag == "silence":
                cursor = self.silence(child, cursor)
                previous_speech, silences = False, silences + 1
            else:
                raise self.fail(child, "unknown element; expected <turn>, <silence> or <params>")
        self.flush_states(cursor)
        timeline = merge([*self.elements, *(e for p in self.params for e in p.elements)], self.says,
                         min_length_s=cursor)
        return Dialogue(self.name, self.agent, self.partner, turns, silences, tuple(self.params), timeline)

    def include(self, node: Node, base_s: float = 0.0) -> None:
        """A parameter file whose times count from `base_s` (the dialogue's, turn's or silence's start)."""
        self.check_attrs(node, ("href",))
        path = self.path(node, "href")
        offset = self.number(node, "offset", 0.0, 0, 1e6, " seconds")
        agent = self.agent_id(node, "agent", self.agent)
        # Errors inside it name it as the dialogue does, relative to the dialogue's own name.
        shown = str(Path(self.name).parent / node.attrs["href"].strip())
        self.params.append(parse_params(read_bytes(path), shown, agent=agent, offset_s=base_s + offset))

    def turn(self, node: Node, start: float, index: int) -> float:
        self.check_attrs(node, ("speaker",))
        speaker = node.attrs["speaker"]
        if speaker not in (self.agent, self.partner):
            raise self.fail(node, f"speaker {speaker!r} is neither the agent {self.agent!r} nor the "
                                  f"partner {self.partner!r}")
        text = " ".join(node.text.split())
        audio = self.path(node, "audio") if "audio" in node.attrs else None
        duration = self.optional(node, "duration", 0.01, 3600, " seconds")
        if duration is None:
            duration = self.speech_duration(node, text, audio)
        if text or audio is not None:
            uid = node.attrs.get("id") or f"{Path(self.name).stem}-{index:02d}"
            if uid in self.ids:
                raise self.fail(node, f"utterance id {uid!r} is used twice")
            self.ids.add(uid)
            self.says.append(SayCue(start, speaker, uid, text, None if audio is None else str(audio),
                                    duration))
        default_role: Role = "talking" if speaker == self.agent else "listening"
        self.states(node, start, duration, default_role)
        self.moves(node, start, duration)
        return start + duration

    def speech_duration(self, node: Node, text: str, audio: Path | None) -> float:
        if audio is not None:
            try:
                seconds = float(self.duration_of(audio))
            except Exception as exc:  # a hook or a broken file: either way the script cannot play
                raise self.fail(node, f"cannot measure audio {node.attrs['audio']!r}: {exc}") from None
            if not (math.isfinite(seconds) and seconds > 0):
                raise self.fail(node, f"audio {node.attrs['audio']!r} has no length ({seconds})")
            return seconds
        if not text:
            raise self.fail(node, "a turn needs text, an audio file or a duration")
        if self.text_duration is not None:
            seconds = float(self.text_duration(text))
            if not (math.isfinite(seconds) and seconds > 0):
                raise self.fail(node, f"speech duration of the text is {seconds}; expected seconds > 0")
            return seconds
        return estimate_speech_s(text, self.wpm)

    def silence(self, node: Node, start: float) -> float:
        self.check_attrs(node, ("duration",))
        if node.text.strip():
            raise self.fail(node, "a silence holds no text")
        duration = self.optional(node, "duration", 0.01, 3600, " seconds")
        assert duration is not None
        if "speaker" in node.attrs and node.attrs["speaker"] not in (self.agent, self.partner):
            raise self.fail(node, f"speaker {node.attrs['speaker']!r} is neither agent nor partner")
        self.states(node, start, duration, "silence")
        self.moves(node, start, duration)
        return start + duration

    # --- role and emotion: one element per change ---------------------------------------------

    def states(self, node: Node, start: float, duration: float, default_role: Role) -> None:
        role = parse_role(node.attrs.get("role", default_role))
        if role is None:
            raise self.fail(node, f"unknown role {node.attrs['role']!r}; expected one of {', '.join(ROLES)}")
        if not self.roles or self.roles[-1][1] != role:
            self.roles.append((start, role, node.line))
        if "emotion" not in node.attrs:
            for key in ("intensity", "transition"):
                if key in node.attrs:
                    raise self.fail(node, f"attribute {key} without an emotion")
            return
        emotion = parse_emotion(node.attrs["emotion"])
        if emotion is None:
            raise self.fail(node, f"unknown emotion {node.attrs['emotion']!r}; expected one of "
                                  f"{', '.join(emotion_names())}")
        intensity = self.number(node, "intensity", 1.0, 0, 1)
        transition = self.number(node, "transition", min(DEFAULT_EMOTION_TRANSITION_S, duration), 0, 60,
                                 " seconds")
        if not self.emotions or self.emotions[-1][1:3] != (emotion, intensity):
            self.emotions.append((start, emotion, intensity, transition, node.line))

    def flush_states(self, end: float) -> None:
        for i, (start, role, line) in enumerate(self.roles):
            stop = self.roles[i + 1][0] if i + 1 < len(self.roles) else end
            self.elements.append(AnimationElement(
                start, max(stop - start, 1e-6), "status", self.agent, flexor_tuple({}), role=role,
                file=self.name, line=line))
        for i, (start, name, intensity, transition, line) in enumerate(self.emotions):
            stop = self.emotions[i + 1][0] if i + 1 < len(self.emotions) else end
            self.elements.append(AnimationElement(
                start, max(stop - start, 1e-6), "emotion", self.agent, emotion_pose(name, intensity),
                transition_s=transition, emotion=name, intensity=intensity, file=self.name, line=line))

    # --- head and gaze moves inside a turn or silence ------------------------------------------

    def moves(self, node: Node, start: float, duration: float) -> None:
        for child in node.children:
            if child.tag == "head":
                self.head(child, start)
            elif child.tag == "gaze":
                self.gaze(child, start, duration)
            elif child.tag == "params":
                self.include(child, start)
            else:
                raise self.fail(child, f"unknown element inside <{node.tag}>; expected <head>, <gaze> "
                                       "or <params>")
            if child.children:
                raise self.fail(child.children[0], f"<{child.tag}> holds no elements")

    def head(self, node: Node, start: float) -> None:
        self.check_attrs(node)
        axes = tuple(self.optional(node, k, -1, 1) for k in ("turn", "nod", "tilt"))
        if all(a is None for a in axes):
            raise self.fail(node, "give at least one of turn, nod, tilt (flexor values in [-1, 1])")
        at = self.number(node, "at", 0.0, 0, 3600, " seconds")
        duration = self.number(node, "duration", DEFAULT_HEAD_S, 0.01, 3600, " seconds")
        flexors = {k: v for k, v in zip(("turn", "nod", "tilt"), axes, strict=True) if v is not None}
        self.elements.append(AnimationElement(
            start + at, duration, "head", self.agent, flexor_tuple(flexors),
            transition_s=duration, head=axes, file=self.name, line=node.line))

    def gaze(self, node: Node, start: float, turn_s: float) -> None:
        self.check_attrs(node)
        mode = None
        if "mode" in node.attrs:
            mode = parse_eye_mode(node.attrs["mode"])
            if mode is None:
                raise self.fail(node, f"unknown eye mode {node.attrs['mode']!r}; expected one of "
                                      f"{', '.join(EYE_MODES)}")
        x_deg, y_deg = eye_range_deg()
        yaw = self.optional(node, "yaw", -x_deg, x_deg, " degrees")
        pitch = self.optional(node, "pitch", -y_deg, y_deg, " degrees")
        if (yaw is None) != (pitch is None):
            raise self.fail(node, "a gaze target needs both yaw and pitch")
        if mode is None and yaw is None:
            raise self.fail(node, "give a mode, or a target as yaw and pitch (degrees)")
        at = self.number(node, "at", 0.0, 0, 3600, " seconds")
        duration = self.number(node, "duration", max(turn_s - at, 0.01), 0.01, 3600, " seconds")
        flexors = {} if yaw is None else {"look_x": yaw / x_deg, "look_y": pitch / y_deg}
        self.elements.append(AnimationElement(
            start + at, duration, "gaze", self.agent, flexor_tuple(flexors), eye_mode=mode,
            yaw_deg=yaw, pitch_deg=pitch, file=self.name, line=node.line))


def parse_dialogue(data: bytes, name: str = "<dialogue>", base_dir: str | Path | None = None, *,
                   duration_of: DurationOf | None = None,
                   text_duration: Callable[[str], float] | None = None) -> Dialogue:
    """Parse a dialogue's XML; audio and parameter files resolve against `base_dir` (default: cwd)."""
    root = parse_xml(data, name)
    base = Path(base_dir) if base_dir is not None else Path.cwd()
    return _Builder(name, base, duration_of or wav_duration, text_duration).build(root)


def load_dialogue(path: str | Path, *, duration_of: DurationOf | None = None,
                  text_duration: Callable[[str], float] | None = None) -> Dialogue:
    """Read and parse a dialogue file; its audio and parameter paths are relative to it."""
    path = Path(path)
    return parse_dialogue(read_bytes(path), str(path), path.resolve().parent, duration_of=duration_of,
                          text_duration=text_duration)
