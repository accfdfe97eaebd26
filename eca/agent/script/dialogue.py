"""Dialogue scripts in XML, in the shape of the paper's Table 1 (docs/scripts.md has the schema).

    <dialogue agent="ada" partner="user">
      <params href="head.txt"/>
      <turn speaker="ada" emotion="happy">Good morning!</turn>
      <turn speaker="user">Morning. Is the report ready?</turn>
      <silence duration="2" emotion="disappointed"/>
    </dialogue>

Turns follow one another; a turn lasts its `duration`, else its audio's length (measured through the
`duration_of` hook), else an estimate from its word count. Everything becomes one Timeline.

A dialogue of several agents (`<dialogue agents="ada bob cy">`) seats them side by side with the user in
front; each turn sets every agent's role (the speaker talking, the others listening) and adds a TurnCue
(who speaks to whom), from which the situated gaze model decides who looks at whom.

Every problem is collected and raised at once (ScriptErrors): a wrong attribute or element is reported
and the builder goes on with the next. Only XML that is not well-formed stops a file at its first
problem, since nothing after it can be trusted to be where the parser thinks.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from eca.agent.script.audiofile import AudioFileError, UnmeasurableAudio, audio_file_problem, describe, wav_duration
from eca.agent.script.elements import AnimationElement, SayCue, Timeline, TurnCue, flexor_tuple, merge
from eca.agent.script.errors import ScriptError, ScriptErrors, raise_collected
from eca.agent.script.paramfile import (
    AGENT_ID_RE,
    DEFAULT_EMOTION_TRANSITION_S,
    ParamFile,
    eye_range_deg,
    parse_params,
)
from eca.agent.script.poses import emotion_pose
from eca.agent.script.textfile import read_bytes
from eca.agent.script.vocab import (
    DEFAULT_AGENT,
    EYE_MODES,
    ROLES,
    Role,
    emotion_names,
    parse_emotion,
    parse_eye_mode,
    parse_role,
)
from eca.agent.script.xmltree import Node, parse_xml

# An agent= that names no agent of the dialogue: reported once, and nothing it would have driven is checked
# for want of an agent again.
UNKNOWN = ""
# The user's id among the people of a dialogue of several agents, as agent/gaze/situated.py names it (a test
# holds the two alike; importing it would make parsing a script load the gaze engine).
USER = "user"
DEFAULT_WPM = 160.0  # a calm speaking rate; espeak-ng's default is 175
DEFAULT_GAP_S = 0.3  # between two speech turns: conversational turn-taking gaps are ~0.2-0.5 s
MIN_SPEECH_S = 0.6
DEFAULT_HEAD_S = 1.0

_NUMBER_RE = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_ATTRS = {
    "dialogue": {"agent", "agents", "partner", "wpm", "gap", "title"},
    "params": {"href", "offset", "agent"},
    "turn": {"speaker", "role", "emotion", "intensity", "transition", "audio", "duration", "id"},
    "silence": {"duration", "speaker", "role", "emotion", "intensity", "transition"},
    "head": {"turn", "nod", "tilt", "duration", "at"},
    "gaze": {"mode", "yaw", "pitch", "at", "duration"},
}
# Attributes that only a dialogue of several agents takes: whom a turn is spoken to, and which agent a
# turn's emotion and role, or a head or gaze move, belong to.
_SEVERAL_ONLY = {"turn": {"to", "agent"}, "silence": {"agent"}, "head": {"agent"}, "gaze": {"agent"}}

DurationOf = Callable[[Path], float]
# The dialogue's agent (a tuple for a dialogue of several) -> why it may not be played, or None.
AgentCheck = Callable[[str | tuple[str, ...]], str | None]


def estimate_speech_s(text: str, wpm: float = DEFAULT_WPM) -> float:
    """Speaking time of `text` from its word count."""
    return max(MIN_SPEECH_S, len(text.split()) * 60.0 / wpm)


@dataclass(frozen=True)
class Dialogue:
    """A parsed dialogue. `agents` are the agents it animates in seat order, left to right: (agent,) for
    a dialogue of one, whose `partner` is the other person; with several, `agent` is the first and the
    partner is the user."""

    path: str
    agent: str
    partner: str
    turns: int
    silences: int
    params: tuple[ParamFile, ...]
    timeline: Timeline
    agents: tuple[str, ...] = ()


class _Builder:
    """Walks the document once, recording every problem; after one, it goes on with defaults so the
    rest is still checked (the timeline of a dialogue with problems is never used)."""

    def __init__(self, name: str, base: Path, duration_of: DurationOf,
                 text_duration: Callable[[str], float] | None, agent_check: AgentCheck | None) -> None:
        self.name = name
        self.base = base
        self.duration_of = duration_of
        self.text_duration = text_duration
        self.agent_check = agent_check
        self.errors: list[ScriptError] = []
        self.agent = ""
        self.agent_known = False  # False when the root's agent is missing or wrong: no speaker checks
        self.several = False  # a dialogue of several agents (`agents=`)
        self.agents: tuple[str, ...] = ()
        self.partner = "user"
        self.wpm = DEFAULT_WPM
        self.gap = DEFAULT_GAP_S
        self.elements: list[AnimationElement] = []
        self.says: list[SayCue] = []
        self.params: list[ParamFile] = []
        self.ids: set[str] = set()
        self.turn_cues: list[TurnCue] = []
        # Per agent, one entry per change: (start, role, line) and (start, emotion, intensity, transition, line).
        self.roles: dict[str, list[tuple[float, Role, int]]] = {}
        self.emotions: dict[str, list[tuple[float, str, float, float, int]]] = {}

    def report(self, node: Node, message: str) -> None:
        self.errors.append(ScriptError(self.name, node.line, node.column, f"<{node.tag}>: {message}"))

    def check_attrs(self, node: Node, required: tuple[str, ...] = ()) -> bool:
        """Reports unknown and missing attributes; False when a required one is missing."""
        several_only = _SEVERAL_ONLY.get(node.tag, set())
        allowed = _ATTRS[node.tag] | (several_only if self.several else set())
        for key in node.attrs:
            if key in several_only and not self.several:
                self.report(node, f"attribute {key!r} is for a dialogue of several agents (<dialogue agents=...>)")
            elif key not in allowed:
                self.report(node, f"unknown attribute {key!r}; allowed: {', '.join(sorted(allowed))}")
        missing = [key for key in required if key not in node.attrs]
        for key in missing:
            self.report(node, f"missing attribute {key!r}")
        return not missing

    def number(self, node: Node, key: str, default: float, lo: float, hi: float, unit: str = "") -> float:
        value = self.optional(node, key, lo, hi, unit)
        return default if value is None else value

    def optional(self, node: Node, key: str, lo: float, hi: float, unit: str = "") -> float | None:
        """The attribute's number; None when absent, or (reported) when it is no number or out of range."""
        if key not in node.attrs:
            return None
        raw = node.attrs[key].strip()
        if not _NUMBER_RE.fullmatch(raw):
            self.report(node, f"attribute {key}={node.attrs[key]!r} is not a number")
            return None
        value = float(raw)
        if not (math.isfinite(value) and lo <= value <= hi):
            self.report(node, f"attribute {key}={raw} is out of range [{lo:g}, {hi:g}]{unit}")
            return None
        return value

    def agent_id(self, node: Node, key: str, default: str | None) -> str | None:
        value = node.attrs.get(key, default)
        if value is None:
            return None  # a missing required attribute: check_attrs reports it
        if not AGENT_ID_RE.fullmatch(value):
            self.report(node, f"attribute {key}={value!r} must be 1-64 letters, digits, '_', '-' or '.'")
            return None
        return value

    def resolve(self, raw: str) -> Path:
        try:
            return (self.base / raw).resolve()
        except (OSError, ValueError):  # a name too long for the OS, or one holding a NUL
            return self.base / raw

    def params_path(self, node: Node) -> Path | None:
        raw = node.attrs["href"].strip()
        if not raw:
            self.report(node, "attribute href is empty")
            return None
        path = self.resolve(raw)
        try:
            found = path.is_file()
        except (OSError, ValueError):
            found = False
        if not found:
            self.report(node, f"href file {raw!r} not found (looked for {path})")
            return None
        return path

    def audio_path(self, node: Node) -> Path | None:
        raw = node.attrs["audio"].strip()
        if not raw:
            self.report(node, "attribute audio is empty")
            return None
        path = self.resolve(raw)
        problem = audio_file_problem(path)
        if problem == "not found":
            problem += f" (looked for {path})"  # where a relative name led
        if problem is not None:
            self.report(node, f"audio {raw!r} {problem}")
            return None
        return path

    # --- the document ---------------------------------------------------------------------------

    def build(self, root: Node) -> Dialogue:
        if root.tag != "dialogue":
            self.report(root, "the root element must be <dialogue>")
            raise ScriptErrors(self.errors)  # nothing else in it can be read as a dialogue
        self.several = "agents" in root.attrs  # with agent= too (an error), the rest is read as several's
        self.check_attrs(root)
        if "agent" in root.attrs and "agents" in root.attrs:
            self.report(root, "give agent (one agent) or agents (several), not both")
        elif self.several:
            self.seat_agents(root)
        elif "agent" in root.attrs:
            agent = self.agent_id(root, "agent", None)
            if agent is not None:
                self.agent, self.agent_known, self.agents = agent, True, (agent,)
            self.partner = self.agent_id(root, "partner", "user") or "user"
            if self.agent_known and self.partner == self.agent:
                self.report(root, "agent and partner must differ")
        else:
            self.report(root, "missing attribute 'agent' (one agent) or 'agents' (several)")
        if self.agent_known and self.agent_check is not None:
            problem = self.agent_check(self.agents if self.several else self.agent)
            if problem is not None:
                self.errors.append(ScriptError(self.name, root.line, root.column, problem))
        self.wpm = self.number(root, "wpm", DEFAULT_WPM, 40, 400, " words per minute")
        self.gap = self.number(root, "gap", DEFAULT_GAP_S, 0, 60, " seconds")
        if root.text.strip():
            self.report(root, "text directly inside <dialogue>; put speech in a <turn>")
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
                self.report(child, "unknown element; expected <turn>, <silence> or <params>")
        raise_collected(self.errors, self.name)
        self.flush_states(cursor)
        timeline = merge([*self.elements, *(e for p in self.params for e in p.elements)], self.says,
                         min_length_s=cursor, turns=self.turn_cues)
        return Dialogue(self.name, self.agent, self.partner, turns, silences, tuple(self.params), timeline,
                        self.agents)

    # --- a dialogue of several agents -----------------------------------------------------------

    def seat_agents(self, root: Node) -> None:
        """`agents="ada bob cy"`: two or more distinct ids, seated left to right in that order."""
        names = root.attrs["agents"].split()
        seated: list[str] = []
        for name in names:
            if not AGENT_ID_RE.fullmatch(name):
                self.report(root, f"agents: {name!r} must be 1-64 letters, digits, '_', '-' or '.'")
            elif name == USER:
                self.report(root, f"agents: {USER!r} is the user, who is always there; name the agents only")
            elif name in seated:
                self.report(root, f"agents: {name!r} is named twice")
            else:
                seated.append(name)
        if len(names) < 2:
            self.report(root, "agents names two or more agents, separated by spaces; a dialogue of one agent "
                              "names it with agent=")
        if "partner" in root.attrs:
            self.report(root, f"partner is for a dialogue of one agent; with agents= the other person is "
                              f"the user, {USER!r}")
        if len(seated) == len(names) >= 2:
            self.agents, self.agent, self.agent_known = tuple(seated), seated[0], True
        self.partner = USER

    def check_speaker(self, node: Node, speaker: str) -> None:
        if self.several:
            if speaker not in (*self.agents, USER):
                self.report(node, f"speaker {speaker!r} is not in this dialogue ({self.people()})")
        elif speaker not in (self.agent, self.partner):
            if node.tag == "silence":
                self.report(node, f"speaker {speaker!r} is neither agent nor partner")
            else:
                self.report(node, f"speaker {speaker!r} is neither the agent {self.agent!r} nor the "
                                  f"partner {self.partner!r}")

    def people(self) -> str:
        return f"{', '.join(self.agents)} or {USER}"

    def addressees(self, node: Node, speaker: str) -> tuple[str, ...]:
        """Whom a turn is spoken to: its `to` (names separated by spaces), else everyone but the speaker."""
        everyone_else = tuple(p for p in (*self.agents, USER) if p != speaker)
        if "to" not in node.attrs or not self.agent_known:
            return everyone_else
        names = node.attrs["to"].split()
        if not names:
            self.report(node, f"attribute to is empty; name whom the turn is spoken to ({self.people()})")
        chosen: list[str] = []
        for name in names:
            if name == speaker:
                self.report(node, f"to names the speaker {name!r}; a turn is spoken to the others")
            elif name not in everyone_else:
                self.report(node, f"to names {name!r}, who is not in this dialogue ({self.people()})")
            elif name in chosen:
                self.report(node, f"to names {name!r} twice")
            else:
                chosen.append(name)
        return tuple(chosen) or everyone_else

    def turn_agent(self, node: Node, speaker: str | None) -> str | None:
        """The agent a turn's or silence's emotion and role describe, and its head and gaze moves drive: the
        dialogue's agent; with several, the turn's `agent`, else its speaker when that is an agent. None when
        there is none; UNKNOWN when the `agent` named is wrong (reported)."""
        if not self.several:
            return self.agent
        if "agent" in node.attrs:
            return self.member(node, node.attrs["agent"])
        return speaker if speaker in self.agents else None

    def member(self, node: Node, name: str) -> str:
        """`name` when it is one of the dialogue's agents; UNKNOWN (reported) otherwise."""
        if self.agent_known and name not in self.agents:
            self.report(node, f"agent {name!r} is not one of the dialogue's agents ({', '.join(self.agents)})")
            return UNKNOWN
        return name

    def owner(self, node: Node, turn_agent: str | None, what: str) -> str | None:
        """The agent an element inside a turn or silence drives: its own `agent` (several agents only), else
        the turn's agent; None (reported) when neither names one, UNKNOWN when one named is wrong (reported)."""
        if self.several and "agent" in node.attrs:
            return self.member(node, node.attrs["agent"])
        if turn_agent is None and self.agent_known:
            self.whose(node, what)
        return turn_agent

    def whose(self, node: Node, what: str) -> None:
        self.report(node, f"say whose {what} this is with agent= ({', '.join(self.agents)}); only an agent's own "
                          "turn implies it")

    def include(self, node: Node, base_s: float = 0.0, turn_agent: str | None = None) -> None:
        """A parameter file whose times count from `base_s` (the dialogue's, turn's or silence's start).

        It drives its `agent`, else the dialogue's agent; in a dialogue of several, else the agent of the
        turn it is in (at the top level it must name one)."""
        if not self.check_attrs(node, ("href",)):
            return
        path = self.params_path(node)
        offset = self.number(node, "offset", 0.0, 0, 1e6, " seconds")
        if self.several and "agent" in node.attrs:
            agent = self.agent_id(node, "agent", None)
            agent = self.member(node, agent) if agent is not None else UNKNOWN
        elif self.several:
            agent = self.owner(node, turn_agent, "parameters")
        else:
            agent = self.agent_id(node, "agent", self.agent if self.agent_known else DEFAULT_AGENT)
        if path is None or not agent:
            return
        # Errors inside it name it as the dialogue does, relative to the dialogue's own name.
        shown = str(Path(self.name).parent / node.attrs["href"].strip())
        try:
            self.params.append(parse_params(read_bytes(path), shown, agent=agent, offset_s=base_s + offset))
        except ScriptError as exc:
            self.errors.extend(exc.errors)

    def turn(self, node: Node, start: float, index: int) -> float:
        self.check_attrs(node, ("speaker",))
        speaker = node.attrs.get("speaker", self.agent)
        if "speaker" in node.attrs and self.agent_known:
            self.check_speaker(node, speaker)
        text = " ".join(node.text.split())
        audio = self.audio_path(node) if "audio" in node.attrs else None
        duration = self.turn_duration(node, text, audio)
        if text or audio is not None:
            uid = node.attrs.get("id") or f"{Path(self.name).stem}-{index:02d}"
            if uid in self.ids:
                self.report(node, f"utterance id {uid!r} is used twice")
            self.ids.add(uid)
            self.says.append(SayCue(start, speaker, uid, text, None if audio is None else str(audio),
                                    duration))
        roles: dict[str, Role] = {a: "talking" if a == speaker else "listening" for a in self.agents or ("",)}
        who = self.turn_agent(node, speaker)
        if self.several:
            self.turn_cues.append(TurnCue(start, speaker, self.addressees(node, speaker), duration))
        self.states(node, start, duration, roles, who)
        self.moves(node, start, duration, who)
        return start + duration

    def turn_duration(self, node: Node, text: str, audio: Path | None) -> float:
        """The turn's `duration`, else its audio's length, else its text's; the audio is measured even
        when the duration is given, so a file that cannot play is found before anything plays."""
        given = self.optional(node, "duration", 0.01, 3600, " seconds")
        measured = self.measure(node, audio, "duration" in node.attrs) if audio is not None else None
        if given is not None:
            return given
        if measured is not None:
            return measured
        if "duration" in node.attrs or "audio" in node.attrs:
            return MIN_SPEECH_S  # the duration or the audio is wrong, and that is reported already
        if not text:
            self.report(node, "a turn needs text, an audio file or a duration")
            return MIN_SPEECH_S
        if self.text_duration is not None:
            seconds = float(self.text_duration(text))
            if not (math.isfinite(seconds) and seconds > 0):
                self.report(node, f"speech duration of the text is {seconds}; expected seconds > 0")
                return MIN_SPEECH_S
            return seconds
        return estimate_speech_s(text, self.wpm)

    def measure(self, node: Node, audio: Path, duration_given: bool) -> float | None:
        """Seconds of sound in the turn's audio file; None (reported) when it cannot be measured."""
        shown = repr(node.attrs["audio"].strip())
        try:
            seconds = float(self.duration_of(audio))
        except UnmeasurableAudio as exc:
            if not duration_given:  # the format is fine; this reader just cannot tell its length
                self.report(node, f"audio {shown} {exc.problem}")
            return None
        except AudioFileError as exc:
            self.report(node, f"audio {shown} {exc.problem}")
            return None
        except Exception as exc:  # a hook of the caller's: whatever it raises, the script cannot play
            self.report(node, f"audio {shown} cannot be measured: {describe(exc)}")
            return None
        if not (math.isfinite(seconds) and seconds > 0):
            self.report(node, f"audio {shown} holds no sound (it lasts {seconds:g} s)")
            return None
        return seconds

    def silence(self, node: Node, start: float) -> float:
        self.check_attrs(node, ("duration",))
        if node.text.strip():
            self.report(node, "a silence holds no text")
        duration = self.optional(node, "duration", 0.01, 3600, " seconds") or 0.0
        if "speaker" in node.attrs and self.agent_known:
            self.check_speaker(node, node.attrs["speaker"])
        who = self.turn_agent(node, None)
        if self.several:
            self.turn_cues.append(TurnCue(start, None, (), duration))
        self.states(node, start, duration, dict.fromkeys(self.agents or ("",), "silence"), who)
        self.moves(node, start, duration, who)
        return start + duration

    # --- role and emotion: one element per change ---------------------------------------------

    def states(self, node: Node, start: float, duration: float, roles: dict[str, Role], who: str | None) -> None:
        """Every agent's role from this turn or silence on (`roles`, with the `role` attribute for `who`, the
        turn's agent), and `who`'s emotion if the element gives one."""
        if "role" in node.attrs:
            role = parse_role(node.attrs["role"])
            if role is None:
                self.report(node, f"unknown role {node.attrs['role']!r}; expected one of {', '.join(ROLES)}")
            elif who:
                roles[who] = role
            elif who is None and self.agent_known:
                self.whose(node, "role")
        for agent, role in roles.items():
            history = self.roles.setdefault(agent, [])
            if not history or history[-1][1] != role:
                history.append((start, role, node.line))
        if "emotion" not in node.attrs:
            for key in ("intensity", "transition"):
                if key in node.attrs:
                    self.report(node, f"attribute {key} without an emotion")
            return
        emotion = parse_emotion(node.attrs["emotion"])
        if emotion is None:
            self.report(node, f"unknown emotion {node.attrs['emotion']!r}; expected one of "
                              f"{', '.join(emotion_names())}")
        intensity = self.number(node, "intensity", 1.0, 0, 1)
        transition = self.number(node, "transition", min(DEFAULT_EMOTION_TRANSITION_S, duration), 0, 60,
                                 " seconds")
        if who is None:
            if self.agent_known:
                self.whose(node, "emotion")
            return
        changes = self.emotions.setdefault(who, [])
        if emotion is not None and (not changes or changes[-1][1:3] != (emotion, intensity)):
            changes.append((start, emotion, intensity, transition, node.line))

    def flush_states(self, end: float) -> None:
        for agent, roles in self.roles.items():
            for i, (start, role, line) in enumerate(roles):
                stop = roles[i + 1][0] if i + 1 < len(roles) else end
                self.elements.append(AnimationElement(
                    start, max(stop - start, 1e-6), "status", agent, flexor_tuple({}), role=role,
                    file=self.name, line=line))
        for agent, emotions in self.emotions.items():
            for i, (start, name, intensity, transition, line) in enumerate(emotions):
                stop = emotions[i + 1][0] if i + 1 < len(emotions) else end
                self.elements.append(AnimationElement(
                    start, max(stop - start, 1e-6), "emotion", agent, emotion_pose(name, intensity),
                    transition_s=transition, emotion=name, intensity=intensity, file=self.name, line=line))

    # --- head and gaze moves inside a turn or silence ------------------------------------------

    def moves(self, node: Node, start: float, duration: float, who: str | None) -> None:
        for child in node.children:
            if child.tag == "head":
                self.head(child, start, who)
            elif child.tag == "gaze":
                self.gaze(child, start, duration, who)
            elif child.tag == "params":
                self.include(child, start, who)
            else:
                self.report(child, f"unknown element inside <{node.tag}>; expected <head>, <gaze> or <params>")
                continue
            if child.children:
                self.report(child.children[0], f"<{child.tag}> holds no elements")

    def head(self, node: Node, start: float, who: str | None) -> None:
        self.check_attrs(node)
        agent = self.owner(node, who, "head")
        axes = (self.optional(node, "turn", -1, 1), self.optional(node, "nod", -1, 1),
                self.optional(node, "tilt", -1, 1))
        if not any(k in node.attrs for k in ("turn", "nod", "tilt")):
            self.report(node, "give at least one of turn, nod, tilt (flexor values in [-1, 1])")
        at = self.number(node, "at", 0.0, 0, 3600, " seconds")
        duration = self.number(node, "duration", DEFAULT_HEAD_S, 0.01, 3600, " seconds")
        flexors = {k: v for k, v in zip(("turn", "nod", "tilt"), axes, strict=True) if v is not None}
        self.elements.append(AnimationElement(
            start + at, duration, "head", agent or "", flexor_tuple(flexors),
            transition_s=duration, head=axes, file=self.name, line=node.line))

    def gaze(self, node: Node, start: float, turn_s: float, who: str | None) -> None:
        self.check_attrs(node)
        agent = self.owner(node, who, "gaze")
        mode = None
        if "mode" in node.attrs:
            mode = parse_eye_mode(node.attrs["mode"])
            if mode is None:
                self.report(node, f"unknown eye mode {node.attrs['mode']!r}; expected one of "
                                  f"{', '.join(EYE_MODES)}")
        x_deg, y_deg = eye_range_deg()
        yaw = self.optional(node, "yaw", -x_deg, x_deg, " degrees")
        pitch = self.optional(node, "pitch", -y_deg, y_deg, " degrees")
        if ("yaw" in node.attrs) != ("pitch" in node.attrs):
            self.report(node, "a gaze target needs both yaw and pitch")
        elif not any(k in node.attrs for k in ("mode", "yaw", "pitch")):
            self.report(node, "give a mode, or a target as yaw and pitch (degrees)")
        at = self.number(node, "at", 0.0, 0, 3600, " seconds")
        duration = self.number(node, "duration", max(turn_s - at, 0.01), 0.01, 3600, " seconds")
        flexors: dict[str, float] = {}
        if yaw is not None and pitch is not None:
            flexors = {"look_x": yaw / x_deg, "look_y": pitch / y_deg}
        else:
            yaw = pitch = None  # half a target is refused above
        self.elements.append(AnimationElement(
            start + at, duration, "gaze", agent or "", flexor_tuple(flexors), eye_mode=mode,
            yaw_deg=yaw, pitch_deg=pitch, file=self.name, line=node.line))


def parse_dialogue(data: bytes, name: str = "<dialogue>", base_dir: str | Path | None = None, *,
                   duration_of: DurationOf | None = None,
                   text_duration: Callable[[str], float] | None = None,
                   agent_check: AgentCheck | None = None) -> Dialogue:
    """Parse a dialogue's XML; audio and parameter files resolve against `base_dir` (default: cwd).

    `agent_check(agent)` may refuse the dialogue's agent (a caller animating another one): its message
    becomes an error at the root element. Every problem found is raised at once as ScriptErrors.
    """
    try:
        root = parse_xml(data, name)
    except ScriptError as exc:
        raise ScriptErrors([exc]) from None
    base = Path(base_dir) if base_dir is not None else Path.cwd()
    return _Builder(name, base, duration_of or wav_duration, text_duration, agent_check).build(root)


def load_dialogue(path: str | Path, *, duration_of: DurationOf | None = None,
                  text_duration: Callable[[str], float] | None = None,
                  agent_check: AgentCheck | None = None) -> Dialogue:
    """Read and parse a dialogue file; its audio and parameter paths are relative to it."""
    path = Path(path)
    try:
        data = read_bytes(path)
    except ScriptError as exc:
        raise ScriptErrors([exc]) from None
    return parse_dialogue(data, str(path), path.resolve().parent, duration_of=duration_of,
                          text_duration=text_duration, agent_check=agent_check)
