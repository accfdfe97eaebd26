"""Every message on the eca bus: one small typed dataclass per message type.

The envelope fields (protocol version, type, agent id, sequence number, timestamp, source service) are
common to all; the rest is the body. Field limits live in each field's metadata, so the codec, the
documentation and the tests read one definition. Units are in the field names (`_s`, `_ns`, `_deg`).
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

PROTOCOL_VERSION = 1

# The shared names (agent/vocabulary.py defines them for the models; tests/test_protocol_vocabulary.py
# holds the two alike, so the protocol needs no import of the models).
Role = Literal["talking", "listening", "silence"]
EyeMode = Literal["static", "noise", "saccade", "saccade+blink", "saccade+noise+blink"]
SaccadeKind = Literal["mutual", "away", "head", "scan", "micro"]

# Pseudo agent id of messages that concern no single agent (heartbeats, errors about no agent, the list of
# agents). Which types may carry it is each type's AGENT_SCOPE.
ALL_AGENTS = "*"
AGENT_ID_PATTERN = r"[A-Za-z0-9_-]{1,32}"  # an agent id (the codec's and the config's grammar)
MAX_ADDRESSEES = 16  # the people one say can be addressed to
# Agents created at run time (`create_agent`), at most: a bound of the protocol's lists; the instance's own
# limit is the config's [conversations] max, at most this. The configured agents are at most 64
# (protocol/endpoints.py MAX_AGENTS), so an instance has at most MAX_LIVE_AGENTS agents at once.
MAX_CREATED_AGENTS = 256
MAX_LIVE_AGENTS = 64 + MAX_CREATED_AGENTS


def bounded(default: Any = dataclasses.MISSING, *, lo: float | None = None, hi: float | None = None,
            max_len: int | None = None, item_max_len: int | None = None, min_len: int | None = None,
            doc: str = "") -> Any:
    """A dataclass field with the limits the codec enforces and the protocol document prints.

    `max_len` bounds a string's characters or a list's or map's entries; `item_max_len` the characters
    of each string in a list of strings; `min_len` the fewest entries of a list (with `max_len` equal to it:
    a list of exactly that many, such as a rig frame's 52 ARKit weights)."""
    meta = {"lo": lo, "hi": hi, "max_len": max_len, "item_max_len": item_max_len, "min_len": min_len, "doc": doc}
    if isinstance(default, list | dict):
        factory = type(default)
        return dataclasses.field(default_factory=factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


_REGISTRY: dict[str, type[Message]] = {}  # TYPE -> class, in the order the types are defined


@dataclass(frozen=True, kw_only=True)
class Message:
    """The envelope every message carries."""

    TYPE: ClassVar[str] = ""
    CATEGORY: ClassVar[str] = ""  # first part of the topic: cmd, state, event, stream, sys, error
    # What the agent field may hold: "one" an agent id; "all" only '*' (the message is about the instance);
    # "any" either (a heartbeat, an error that may concern no agent). The codec enforces it both ways, so a
    # command or state for '*' never reaches a service as if '*' were an agent.
    AGENT_SCOPE: ClassVar[Literal["one", "all", "any"]] = "one"

    agent: str = bounded(max_len=32, doc="agent id: letters, digits, '_' and '-'; '*' for all agents")
    seq: int = bounded(0, lo=0, hi=2**63 - 1, doc="the publisher's count of its messages on this topic, from 1")
    t_ns: int = bounded(0, lo=0, hi=2**63 - 1, doc="monotonic clock of the publishing host, ns")
    source: str = bounded("", max_len=64, doc="the publishing service or client")

    def __init_subclass__(cls, **kwargs: Any) -> None:
        # A class with a TYPE of its own is a message type: it registers itself, so defining it is all it
        # takes to put it on the wire. A class without one is a shared base of fields (SpeechEndings).
        super().__init_subclass__(**kwargs)
        own = cls.__dict__.get("TYPE")
        if own:
            if own in _REGISTRY:
                raise TypeError(f"message type {own!r} is defined twice: {_REGISTRY[own].__name__}, {cls.__name__}")
            _REGISTRY[own] = cls

    def consistency_problem(self) -> tuple[str, str] | None:
        """(field, problem) when fields disagree with each other; checked by the codec both ways."""
        return None


# --- commands: from dialogue managers, the CLI, script replay and key presses --------------------


# A command that sets a state shares that state's fields: a base without a TYPE holds them, and the
# command adds its request id. `as_state` turns the command into the state it produces.

REQUEST_ID_DOC = "optional; acknowledged, or echoed in an error"


@dataclass(frozen=True, kw_only=True)
class RoleFields(Message):
    role: Role = bounded(doc="talking, listening or silence")
    speaker: str = bounded("", max_len=32, doc="who holds the floor (an agent id, 'user', or empty)")


@dataclass(frozen=True, kw_only=True)
class EmotionFields(Message):
    name: str = bounded(max_len=32, doc="one of the emotions in configs/emotions.toml")
    intensity: float = bounded(1.0, lo=0.0, hi=1.0, doc="0 = natural, 1 = the full expression")
    transition_s: float = bounded(0.5, lo=0.0, hi=30.0, doc="blend time from the current expression, from t_ns")


@dataclass(frozen=True, kw_only=True)
class HeadFields(Message):
    turn: float = bounded(0.0, lo=-1.0, hi=1.0, doc="yaw target, +1 = the agent's right")
    nod: float = bounded(0.0, lo=-1.0, hi=1.0, doc="pitch target, +1 = chin up")
    tilt: float = bounded(0.0, lo=-1.0, hi=1.0, doc="roll target, +1 = toward the right shoulder")
    duration_s: float = bounded(0.5, lo=0.0, hi=30.0, doc="time to reach the targets, from t_ns")


@dataclass(frozen=True, kw_only=True)
class EyesFields(Message):
    mode: EyeMode = bounded(doc="static, noise, saccade, saccade+blink (the paper's conditions and its "
                                "future work) or saccade+noise+blink (its recommendation)")


@dataclass(frozen=True, kw_only=True)
class GazeTargetFields(Message):
    yaw_deg: float = bounded(0.0, lo=-60.0, hi=60.0, doc="where mutual gaze looks, + = agent's right")
    pitch_deg: float = bounded(0.0, lo=-45.0, hi=45.0, doc="+ = up")
    target: str = bounded("", max_len=32, doc="what is there (e.g. 'user' or an agent id)")


@dataclass(frozen=True, kw_only=True)
class StateCommand(Message):
    """A command whose effect is a state: its fields are that state's (STATE), plus a request id."""

    STATE: ClassVar[type[Message]]

    def as_state(self, **changes: Any) -> Message:
        """The state this command sets (the envelope left to the publisher), with `changes` applied."""
        shared = {f.name for f in dataclasses.fields(self.STATE)} - ENVELOPE_FIELDS
        values = {name: getattr(self, name) for name in shared if hasattr(self, name)}
        return self.STATE(agent=self.agent, **{**values, **changes})


@dataclass(frozen=True, kw_only=True)
class SetRole(StateCommand, RoleFields):
    TYPE = "set_role"
    CATEGORY = "cmd"
    request_id: str = bounded("", max_len=64, doc=REQUEST_ID_DOC)


@dataclass(frozen=True, kw_only=True)
class SetEmotion(StateCommand, EmotionFields):
    TYPE = "set_emotion"
    CATEGORY = "cmd"
    request_id: str = bounded("", max_len=64, doc=REQUEST_ID_DOC)


@dataclass(frozen=True, kw_only=True)
class MoveHead(StateCommand, HeadFields):
    TYPE = "move_head"
    CATEGORY = "cmd"
    request_id: str = bounded("", max_len=64, doc=REQUEST_ID_DOC)


@dataclass(frozen=True, kw_only=True)
class SetEyes(StateCommand, EyesFields):
    TYPE = "set_eyes"
    CATEGORY = "cmd"
    request_id: str = bounded("", max_len=64, doc=REQUEST_ID_DOC)


@dataclass(frozen=True, kw_only=True)
class SetGazeTarget(StateCommand, GazeTargetFields):
    TYPE = "set_gaze_target"
    CATEGORY = "cmd"
    request_id: str = bounded("", max_len=64, doc=REQUEST_ID_DOC)


@dataclass(frozen=True, kw_only=True)
class Say(Message):
    TYPE = "say"
    CATEGORY = "cmd"
    request_id: str = bounded(max_len=64, doc="unique per request; lifecycle events carry it")
    start_ns: int = bounded(0, lo=0, hi=2**63 - 1, doc="its first sample is heard no earlier than this master-clock "
                                                       "time (0: as soon as it can play); silence until then")
    audio_path: str | None = bounded(None, max_len=4096, doc="a sound file the audio service can read")
    pcm: bytes | None = bounded(None, doc="inline mono PCM, signed 16-bit little-endian")
    sample_rate: int = bounded(0, lo=0, hi=192_000, doc="of pcm or of the streamed chunks; 0 with a file")
    streamed: bool = bounded(False, doc="true: the audio follows as speech_chunk messages")
    text: str | None = bounded(None, max_len=10_000,
                               doc="what is said; with no audio, the audio service speaks it (text-to-speech)")
    to: list[str] = bounded([], max_len=MAX_ADDRESSEES, item_max_len=32,
                            doc="who it is said to: agent ids of this instance and/or `user` (default everyone)")


@dataclass(frozen=True, kw_only=True)
class SpeechChunk(Message):
    TYPE = "speech_chunk"
    CATEGORY = "cmd"
    request_id: str = bounded(max_len=64, doc="the streamed say request this chunk belongs to")
    index: int = bounded(lo=0, hi=2**31, doc="0, 1, 2, ... in order")
    pcm: bytes = bounded(doc="mono PCM, signed 16-bit little-endian, at the say request's rate")
    last: bool = bounded(False, doc="true on the final chunk")


@dataclass(frozen=True, kw_only=True)
class Interrupt(Message):
    TYPE = "interrupt"
    CATEGORY = "cmd"
    request_id: str = bounded("", max_len=64, doc="the request to stop; empty = all of the agent's")
    reason: str = bounded("command", max_len=200, doc="why, reported in the interrupted event")


@dataclass(frozen=True, kw_only=True)
class UserSpeech(Message):
    TYPE = "user_speech"
    CATEGORY = "cmd"
    speaking: bool = bounded(doc="true when the user starts speaking (barge-in), false when done")
    request_id: str = bounded("", max_len=64, doc="optional; acknowledged, or echoed in an error")


@dataclass(frozen=True, kw_only=True)
class CreateAgent(Message):
    """Create the agent named by the envelope's `agent` at run time (a conversation of its own, e.g. for one web
    page), with the settings of a configured agent; the dialogue service lists it in `state.*.agents`."""

    TYPE = "create_agent"
    CATEGORY = "cmd"
    request_id: str = bounded("", max_len=64, doc=REQUEST_ID_DOC)
    like: str = bounded("", max_len=32, doc="a configured agent whose settings it copies; empty: the config's "
                                            "[conversations] template (default: the first configured agent)")


@dataclass(frozen=True, kw_only=True)
class RemoveAgent(Message):
    """Remove an agent created at run time: its pending say requests end, its states are gone."""

    TYPE = "remove_agent"
    CATEGORY = "cmd"
    request_id: str = bounded("", max_len=64, doc=REQUEST_ID_DOC)


MAX_BML_CHARS = 65_536  # one BML block's text: a long utterance with its marks and a few dozen behaviours


@dataclass(frozen=True, kw_only=True)
class Bml(Message):
    """A BML 1.0 block for the agent's realizer (the bml service; docs/bml.md): its behaviours are scheduled
    on the master clock and realized on the agent's face and voice, with the standard's feedback on
    `event.<agent>.bml_feedback`."""

    TYPE = "bml"
    CATEGORY = "cmd"
    request_id: str = bounded("", max_len=64, doc=REQUEST_ID_DOC)
    xml: str = bounded(max_len=MAX_BML_CHARS, doc="one <bml> element (BML 1.0 namespace, none, or SmartBody's "
                                                  "<act> around it), as text")


# --- states: the dialogue service's current state per agent (kept by the broker's last-value cache)


@dataclass(frozen=True, kw_only=True)
class RoleState(RoleFields):
    TYPE = "role"
    CATEGORY = "state"
    set_by: Literal["command", "speech"] = bounded("command", doc="a command, or the agent's own speech")
    addressees: list[str] = bounded([], max_len=MAX_ADDRESSEES, item_max_len=32,
                                    doc="while it talks: who it speaks to (the say's `to`; empty: everyone)")


@dataclass(frozen=True, kw_only=True)
class EmotionState(EmotionFields):
    TYPE = "emotion"
    CATEGORY = "state"


@dataclass(frozen=True, kw_only=True)
class HeadState(HeadFields):
    TYPE = "head"
    CATEGORY = "state"


@dataclass(frozen=True, kw_only=True)
class AttentionState(Message):
    TYPE = "attention"
    CATEGORY = "state"
    person: str = bounded("user", max_len=32, doc="who the agent attends: an agent id or `user`")
    yaw_deg: float = bounded(0.0, lo=-90.0, hi=90.0, doc="head turn toward that person, + = agent's right, "
                                                         "added to the scripted head")
    pitch_deg: float = bounded(0.0, lo=-90.0, hi=90.0, doc="+ = up")
    duration_s: float = bounded(0.6, lo=0.0, hi=30.0, doc="time the turn takes, from t_ns")


@dataclass(frozen=True, kw_only=True)
class EyesState(EyesFields):
    TYPE = "eyes"
    CATEGORY = "state"


@dataclass(frozen=True, kw_only=True)
class GazeTargetState(GazeTargetFields):
    TYPE = "gaze_target"
    CATEGORY = "state"


SetRole.STATE, SetEmotion.STATE, MoveHead.STATE = RoleState, EmotionState, HeadState
SetEyes.STATE, SetGazeTarget.STATE = EyesState, GazeTargetState

_AGENT_ID = re.compile(AGENT_ID_PATTERN)


@dataclass(frozen=True, kw_only=True)
class AgentsState(Message):
    """The instance's live agents, on `state.*.agents` (its agent is '*'): the configured ones, then those
    created at run time in the order of their creation. Published by the dialogue service whenever the list
    changes; the services that follow agents (gaze, audio, rig, the live scenes) add and drop agents by it, and
    the broker forgets the cached states of an agent it no longer lists."""

    TYPE = "agents"
    CATEGORY = "state"
    AGENT_SCOPE = "all"
    agents: list[str] = bounded([], max_len=MAX_LIVE_AGENTS, item_max_len=32,
                                doc="every live agent: the configured ones first, then the created ones in order")
    created: list[str] = bounded([], max_len=MAX_CREATED_AGENTS, item_max_len=32,
                                 doc="those created at run time, in order (the tail of `agents`)")
    like: list[str] = bounded([], max_len=MAX_CREATED_AGENTS, item_max_len=32,
                              doc="for each created agent, the configured agent whose settings it copies")
    max_created: int = bounded(0, lo=0, hi=MAX_CREATED_AGENTS,
                               doc="how many agents may be created at once ([conversations] max)")

    def consistency_problem(self) -> tuple[str, str] | None:
        bad = next((a for a in self.agents if not _AGENT_ID.fullmatch(a)), None)
        if bad is not None:
            return "agents", f"{bad[:40]!r} is not an agent id"
        if len(set(self.agents)) != len(self.agents):
            return "agents", "an agent listed twice"
        configured = len(self.agents) - len(self.created)
        if configured < 0 or self.agents[configured:] != self.created:
            return "created", "must be the agents listed last in `agents`, in the same order"
        if len(self.like) != len(self.created):
            return "like", f"has {len(self.like)} entries for {len(self.created)} created agents"
        own = set(self.agents[:configured])
        if any(a not in own for a in self.like):
            return "like", "names an agent that is not a configured one"
        return None


MAX_PENDING_SAYS = 64  # per agent: what one speech state can list
RECENT_ENDINGS = 16  # per agent: the latest say requests whose ending the playback state remembers
SpeechEnding = Literal["speech_finished", "speech_interrupted", "speech_failed"]


@dataclass(frozen=True, kw_only=True)
class SpeechEndings(Message):
    """How an agent's latest say requests ended, oldest first: part of the speech and playback states, so
    the ending of a request outlives its terminal event when that is lost with a broker (events are
    delivered once; a state is cached and published again)."""

    ended_ids: list[str] = bounded([], max_len=RECENT_ENDINGS, item_max_len=64,
                                   doc="the requests that ended last, oldest first (each 1-64 chars)")
    ended_as: list[SpeechEnding] = bounded([], max_len=RECENT_ENDINGS, doc="how each of them ended")
    ended_played_s: list[float] = bounded([], lo=0.0, hi=86_400.0, max_len=RECENT_ENDINGS,
                                          doc="seconds of each played")
    ended_reasons: list[str] = bounded([], max_len=RECENT_ENDINGS, item_max_len=500,
                                       doc="each one's reason (interrupted, failed; ≤ 500 chars)")

    def consistency_problem(self) -> tuple[str, str] | None:
        n = len(self.ended_ids)
        for name in ("ended_as", "ended_played_s", "ended_reasons"):
            if len(getattr(self, name)) != n:
                return name, f"has {len(getattr(self, name))} entries for {n} ended_ids"
        if "" in self.ended_ids:
            return "ended_ids", "an empty request id"
        return None

    def ending_of(self, request_id: str) -> Message | None:
        """The terminal event of `request_id` as these lists record it (the latest, if listed twice)."""
        for k in range(len(self.ended_ids) - 1, -1, -1):
            if self.ended_ids[k] == request_id:
                played, reason = self.ended_played_s[k], self.ended_reasons[k]
                agent, t_ns, source = self.agent, self.t_ns, self.source
                if self.ended_as[k] == "speech_finished":
                    return SpeechFinished(agent=agent, request_id=request_id, t_ns=t_ns, source=source, played_s=played)
                if self.ended_as[k] == "speech_interrupted":
                    return SpeechInterrupted(agent=agent, request_id=request_id, t_ns=t_ns, source=source,
                                             played_s=played, reason=reason[:200])
                return SpeechFailed(agent=agent, request_id=request_id, t_ns=t_ns, source=source, reason=reason)
        return None


@dataclass(frozen=True, kw_only=True)
class SpeechState(SpeechEndings):
    """The agent's say requests accepted and not yet ended, oldest first, one list entry per request,
    and how the latest ones ended.

    A restarted dialogue service reads it back from the cache, so it can still interrupt, feed chunks
    to and end the requests its predecessor handed to the audio service; a client that missed a
    terminal event (it was lost with a broker) finds the ending here."""

    TYPE = "speech"
    CATEGORY = "state"
    request_ids: list[str] = bounded([], max_len=MAX_PENDING_SAYS, item_max_len=64,
                                     doc="the pending requests (each 1-64 chars)")
    streamed: list[bool] = bounded([], max_len=MAX_PENDING_SAYS, doc="its audio comes as speech_chunk messages")
    next_chunk: list[int] = bounded([], lo=0, hi=2**31, max_len=MAX_PENDING_SAYS,
                                    doc="index of the next chunk it accepts (streamed)")
    chunks_done: list[bool] = bounded([], max_len=MAX_PENDING_SAYS, doc="its last chunk has come (streamed)")
    started: list[bool] = bounded([], max_len=MAX_PENDING_SAYS, doc="its speech_started has been published")
    audio_started_ns: list[int] = bounded([], lo=0, hi=2**63 - 1, max_len=MAX_PENDING_SAYS,
                                          doc="started_ns of the audio service it went to; 0: none known")

    def consistency_problem(self) -> tuple[str, str] | None:
        n = len(self.request_ids)
        for name in ("streamed", "next_chunk", "chunks_done", "started", "audio_started_ns"):
            if len(getattr(self, name)) != n:
                return name, f"has {len(getattr(self, name))} entries for {n} request_ids"
        if "" in self.request_ids:
            return "request_ids", "an empty request id"
        if len(set(self.request_ids)) != n:
            return "request_ids", "a request id listed twice"
        return super().consistency_problem()


@dataclass(frozen=True, kw_only=True)
class PlaybackState(SpeechEndings):
    """The say requests the audio service holds for the agent (queued or playing), in the order it took
    them, and how the latest ones ended; published by the audio service at each change. With the
    dialogue service's speech state it tells a restarted dialogue service which of its predecessor's
    requests ended while it was away, and how."""

    TYPE = "playback"
    CATEGORY = "state"
    request_ids: list[str] = bounded([], max_len=MAX_PENDING_SAYS, item_max_len=64,
                                     doc="the requests held (each 1-64 chars)")
    started_ns: int = bounded(0, lo=0, hi=2**63 - 1, doc="the audio service instance (its heartbeat's started_ns)")

    def consistency_problem(self) -> tuple[str, str] | None:
        if "" in self.request_ids:
            return "request_ids", "an empty request id"
        return super().consistency_problem()


# --- events: things that happened -----------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class SpeechStarted(Message):
    TYPE = "speech_started"
    CATEGORY = "event"
    request_id: str = bounded(max_len=64, doc="the say request")
    dac_time_ns: int = bounded(0, lo=0, hi=2**63 - 1, doc="when its first sample reached the DAC")


@dataclass(frozen=True, kw_only=True)
class SpeechFinished(Message):
    TYPE = "speech_finished"
    CATEGORY = "event"
    request_id: str = bounded(max_len=64, doc="the say request (terminal)")
    played_s: float = bounded(0.0, lo=0.0, hi=86_400.0, doc="seconds of audio played")


@dataclass(frozen=True, kw_only=True)
class SpeechInterrupted(Message):
    TYPE = "speech_interrupted"
    CATEGORY = "event"
    request_id: str = bounded(max_len=64, doc="the say request (terminal)")
    played_s: float = bounded(0.0, lo=0.0, hi=86_400.0, doc="seconds played before the stop")
    reason: str = bounded("", max_len=200, doc="the interrupt's reason")


@dataclass(frozen=True, kw_only=True)
class SpeechFailed(Message):
    TYPE = "speech_failed"
    CATEGORY = "event"
    request_id: str = bounded(max_len=64, doc="the say request (terminal)")
    reason: str = bounded(max_len=500, doc="what went wrong")


@dataclass(frozen=True, kw_only=True)
class Ack(Message):
    """The owning service applied a command (every command it applies but a speech_chunk; docs/protocol.md
    section 6). It follows the state the command produced (same publisher, so a subscriber of both sees the
    state first)."""

    TYPE = "ack"
    CATEGORY = "event"
    request_id: str = bounded(max_len=64, doc="the command's request_id as sent, empty when it had none")
    command: str = bounded(max_len=32, doc="the command's type, e.g. set_emotion")


@dataclass(frozen=True, kw_only=True)
class Saccade(Message):
    TYPE = "saccade"
    CATEGORY = "event"
    onset_ns: int = bounded(lo=0, hi=2**63 - 1, doc="when the eye starts to move")
    from_yaw_deg: float = bounded(lo=-90.0, hi=90.0, doc="start direction, + = agent's right")
    from_pitch_deg: float = bounded(lo=-90.0, hi=90.0, doc="+ = up")
    to_yaw_deg: float = bounded(lo=-90.0, hi=90.0, doc="landing direction")
    to_pitch_deg: float = bounded(lo=-90.0, hi=90.0, doc="+ = up")
    amplitude_deg: float = bounded(lo=0.0, hi=180.0, doc="angular size")
    direction_deg: float = bounded(lo=0.0, hi=360.0, doc="0 = agent's right, 90 = up")
    duration_s: float = bounded(lo=0.0, hi=1.0, doc="flight time; the eye lands at onset + duration")
    kind: SaccadeKind = bounded(doc="mutual (back to the target), away, head (leading a head turn), or the "
                                    "small saccades of saccade+noise+blink: scan (over the partner's face), "
                                    "micro (a microsaccade)")
    hold_s: float = bounded(0.0, lo=0.0, hi=600.0, doc="planned fixation after landing")


@dataclass(frozen=True, kw_only=True)
class Nod(Message):
    TYPE = "nod"
    CATEGORY = "event"
    onset_ns: int = bounded(lo=0, hi=2**63 - 1, doc="when the chin starts to dip")
    amplitude_deg: float = bounded(lo=0.0, hi=30.0, doc="how far it dips")
    duration_s: float = bounded(lo=0.05, hi=5.0, doc="down and back up")
    reason: Literal["backchannel"] = bounded("backchannel", doc="why: a listener's response at a partner's pause")


BmlFeedbackKind = Literal["blockProgress", "syncPointProgress", "warningFeedback", "predictionFeedback"]


@dataclass(frozen=True, kw_only=True)
class BmlFeedback(Message):
    """The BML realizer's feedback, as the standard defines it: the fields for a client that reads them, and
    the standard's own feedback element in `xml` for one that forwards it (the ActiveMQ bridge)."""

    TYPE = "bml_feedback"
    CATEGORY = "event"
    kind: BmlFeedbackKind = bounded(doc="blockProgress, syncPointProgress, warningFeedback or predictionFeedback")
    block: str = bounded(max_len=64, doc="the block's id")
    behaviour: str = bounded("", max_len=64, doc="the behaviour's id (syncPointProgress, a warning about one)")
    sync: str = bounded("", max_len=64, doc="start or end (blockProgress); the sync point (syncPointProgress); "
                                            "the warning's type (warningFeedback)")
    time_s: float = bounded(0.0, lo=-86_400.0, hi=86_400.0, doc="when, in seconds from the block's start")
    global_ns: int = bounded(0, lo=0, hi=2**63 - 1, doc="when, on the master clock (predicted, for predictions)")
    end_ns: int = bounded(0, lo=0, hi=2**63 - 1, doc="predictionFeedback: the block's predicted end")
    text: str = bounded("", max_len=2000, doc="warningFeedback: what, naming the behaviour and the line")
    request_id: str = bounded("", max_len=64, doc="the bml command's request id")
    xml: str = bounded("", max_len=8192, doc="the standard's feedback element (bml-1.0 namespace)")


@dataclass(frozen=True, kw_only=True)
class Expression(Message):
    """A facial behaviour on the master clock (a BML faceLexeme or faceFacs): flexor offsets added over the
    emotion, rising from `onset_ns` to full at `peak_ns`, held until `relax_ns`, gone at `end_ns`. One with
    the `id` of an expression the face holds replaces it (an earlier end cuts it short)."""

    TYPE = "expression"
    CATEGORY = "event"
    id: str = bounded(max_len=64, doc="the behaviour (block:behaviour)")
    onset_ns: int = bounded(lo=0, hi=2**63 - 1, doc="when it starts")
    peak_ns: int = bounded(lo=0, hi=2**63 - 1, doc="when it reaches full strength (attackPeak)")
    relax_ns: int = bounded(lo=0, hi=2**63 - 1, doc="when it starts to go")
    end_ns: int = bounded(lo=0, hi=2**63 - 1, doc="when it is gone")
    flexors: dict[str, float] = bounded({}, lo=-1.0, hi=1.0, max_len=32,
                                        doc="flexor name -> offset at full strength, flexor units")

    def consistency_problem(self) -> tuple[str, str] | None:
        if not self.onset_ns <= self.peak_ns <= self.relax_ns <= self.end_ns:
            return "end_ns", "onset_ns <= peak_ns <= relax_ns <= end_ns does not hold"
        return None


HeadLexeme = Literal["nod", "shake", "tilt"]


@dataclass(frozen=True, kw_only=True)
class HeadGesture(Message):
    """A head gesture on the master clock (a BML head behaviour): `repetitions` strokes of a nod (the chin
    down), a shake (left-right) or a tilt, from `onset_ns` over `duration_s`; repetition i's stroke is at
    onset + (i + 0.5) * duration / repetitions. One with the `id` of a gesture under way replaces it."""

    TYPE = "head_gesture"
    CATEGORY = "event"
    id: str = bounded(max_len=64, doc="the behaviour (block:behaviour)")
    lexeme: HeadLexeme = bounded(doc="nod, shake or tilt")
    onset_ns: int = bounded(lo=0, hi=2**63 - 1, doc="when the head starts to move")
    duration_s: float = bounded(lo=0.0, hi=30.0, doc="all repetitions, start to end (0: cut short at onset)")
    repetitions: int = bounded(1, lo=1, hi=20, doc="strokes")
    amplitude_deg: float = bounded(lo=0.0, hi=30.0, doc="each stroke's angle")


# --- streams: continuous data -------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class ClockAnchor(Message):
    TYPE = "clock_anchor"
    CATEGORY = "stream"
    request_id: str = bounded(max_len=64, doc="the utterance playing")
    sample_index: int = bounded(lo=0, hi=2**62, doc="sample of that utterance ...")
    sample_rate: int = bounded(lo=1, hi=192_000, doc="its rate")
    dac_time_ns: int = bounded(lo=0, hi=2**63 - 1, doc="... at the DAC at this monotonic time")


@dataclass(frozen=True, kw_only=True)
class MouthKeys(Message):
    TYPE = "mouth"
    CATEGORY = "stream"
    request_id: str = bounded(max_len=64, doc="the utterance")
    sample_rate: int = bounded(lo=1, hi=192_000, doc="rate of the sample positions")
    sample_index: list[int] = bounded([], lo=0, hi=2**62, max_len=100_000,
                                      doc="position of each key in the utterance")
    weights: dict[str, list[float]] = bounded({}, lo=0.0, hi=1.0, max_len=16,
                                             doc="mouth flexor name -> one weight 0..1 per key")
    reset: bool = bounded(False, doc="true: close the mouth and drop earlier keys (interruption)")

    def consistency_problem(self) -> tuple[str, str] | None:
        n = len(self.sample_index)
        for name, values in self.weights.items():
            if len(values) != n:
                return f"weights.{name}", f"has {len(values)} values for {n} sample positions"
        return None


@dataclass(frozen=True, kw_only=True)
class EyeStates(Message):
    """The eyes of many agents at one tick of the gaze service (`t_ns`), on `stream.*.eye_states`: entry i of
    each list is agent `agents[i]`'s. One message per tick for all the agents it moves (a reaction's for those
    it concerns), not one per agent: the eyes are the bus's most frequent stream, and a message costs every
    hop the same whatever it carries."""

    TYPE = "eye_states"
    CATEGORY = "stream"
    AGENT_SCOPE = "all"
    agents: list[str] = bounded([], max_len=MAX_LIVE_AGENTS, item_max_len=32, doc="the agents, each once")
    yaw_deg: list[float] = bounded([], lo=-90.0, hi=90.0, max_len=MAX_LIVE_AGENTS,
                                   doc="each one's eye direction in the head, + = agent's right")
    pitch_deg: list[float] = bounded([], lo=-90.0, hi=90.0, max_len=MAX_LIVE_AGENTS, doc="+ = up")
    lid: list[float] = bounded([], lo=0.0, hi=1.0, max_len=MAX_LIVE_AGENTS,
                               doc="lid closure, 0 open .. 1 closed")
    mode: list[EyeMode] = bounded([], max_len=MAX_LIVE_AGENTS, doc="the eye condition in force")

    def consistency_problem(self) -> tuple[str, str] | None:
        n = len(self.agents)
        for name in ("yaw_deg", "pitch_deg", "lid", "mode"):
            if len(getattr(self, name)) != n:
                return name, f"has {len(getattr(self, name))} entries for {n} agents"
        bad = next((a for a in self.agents if not _AGENT_ID.fullmatch(a)), None)
        if bad is not None:
            return "agents", f"{bad[:40]!r} is not an agent id"
        if len(set(self.agents)) != n:
            return "agents", "an agent listed twice"
        return None

    def rows(self) -> Iterator[tuple[str, float, float, float, EyeMode]]:
        """(agent, yaw_deg, pitch_deg, lid, mode) of each agent."""
        return zip(self.agents, self.yaw_deg, self.pitch_deg, self.lid, self.mode, strict=True)


@dataclass(frozen=True, kw_only=True)
class FaceFrame(Message):
    TYPE = "face_frame"
    CATEGORY = "stream"
    frame_ns: int = bounded(lo=0, hi=2**63 - 1, doc="the display time this frame was composed for")
    flexors: dict[str, float] = bounded({}, lo=-1.0, hi=1.0, max_len=64,
                                        doc="flexor name -> value in [-1, 1]")


# The lengths of a rig frame's weight lists: ARKit's 52 blendshapes, the 15 Oculus visemes and VRM 1.0's 18
# expression presets; their names and order are in docs/protocol.md (the models' eca/agent/rig/names.py, which
# tests/test_protocol_vocabulary.py holds alike, since the protocol imports no model).
RIG_ARKIT, RIG_VISEMES, RIG_VRM = 52, 15, 18


@dataclass(frozen=True, kw_only=True)
class RigPose(Message):
    """The agent's composed face at `frame_ns` as the weights and angles the world's rigs take (the rig service,
    at its rate): for a client that drives an avatar of its own, in any engine, from the bus. Every list has a
    fixed length and order (docs/protocol.md), so a client indexes it without names."""

    TYPE = "rig"
    CATEGORY = "stream"
    frame_ns: int = bounded(lo=0, hi=2**63 - 1,
                            doc="the frame's time on the master clock: the monotonic clock the audio service's "
                                "clock anchors map the voice onto, so the face aligns with the voice")
    arkit: list[float] = bounded(lo=0.0, hi=1.0, min_len=RIG_ARKIT, max_len=RIG_ARKIT,
                                 doc="the 52 ARKit blendshape weights, in Unreal's EARFaceBlendShape order")
    head_deg: list[float] = bounded(lo=-180.0, hi=180.0, min_len=3, max_len=3,
                                    doc="head yaw (+ = the agent's right), pitch (+ = chin up), roll (+ = toward the "
                                        "right shoulder), degrees")
    eyes_deg: list[float] = bounded(lo=-90.0, hi=90.0, min_len=4, max_len=4,
                                    doc="left eye yaw, left eye pitch, right eye yaw, right eye pitch, in the head, "
                                        "degrees (yaw + = the agent's right, pitch + = up)")
    visemes: list[float] = bounded(lo=0.0, hi=1.0, min_len=RIG_VISEMES, max_len=RIG_VISEMES,
                                   doc="the 15 Oculus visemes (sil first), summing to 1")
    vrm: list[float] = bounded(lo=0.0, hi=1.0, min_len=RIG_VRM, max_len=RIG_VRM,
                               doc="VRM 1.0's 18 expression presets (happy ... neutral)")


MAX_AUDIO_BLOCK_BYTES = 65_536  # a voice or microphone block: 10-20 ms of mono 16-bit audio is far less


@dataclass(frozen=True, kw_only=True)
class VoiceBlock(Message):
    """A block of the agent's voice as the audio service hands it to its output, published for outputs in
    other processes (the web service's audio track): the samples that reach the output at `dac_time_ns`
    on the master clock. A block of pure silence is not sent: `first_sample` counts it, so the blocks lie on
    one track with silence in the gaps."""

    TYPE = "voice"
    CATEGORY = "stream"
    sample_rate: int = bounded(lo=8000, hi=192_000, doc="rate of the samples")
    first_sample: int = bounded(lo=0, hi=2**62, doc="index of its first sample since the output started")
    dac_time_ns: int = bounded(lo=0, hi=2**63 - 1, doc="when its first sample reaches the output (master clock)")
    pcm: bytes = bounded(max_len=MAX_AUDIO_BLOCK_BYTES, doc="mono PCM, signed 16-bit little-endian")
    request_id: str = bounded("", max_len=64, doc="the say request playing at its start; empty: silence")


@dataclass(frozen=True, kw_only=True)
class UserAudio(Message):
    """A block of the user's microphone as a front-end received it, for a dialogue manager's own speech
    recognition: 16 kHz mono by default, stamped with the monotonic time its first sample arrived."""

    TYPE = "user_audio"
    CATEGORY = "stream"
    sample_rate: int = bounded(16_000, lo=8000, hi=48_000, doc="rate of the samples")
    first_sample: int = bounded(lo=0, hi=2**62, doc="index of its first sample since the microphone connected")
    capture_time_ns: int = bounded(lo=0, hi=2**63 - 1, doc="when its first sample arrived (monotonic clock)")
    pcm: bytes = bounded(max_len=MAX_AUDIO_BLOCK_BYTES, doc="mono PCM, signed 16-bit little-endian")
    speaking: bool = bounded(False, doc="the voice-activity detector's verdict for this block")
    source_id: str = bounded("", max_len=64, doc="which connection it came from (a browser, a pipeline)")


# --- system ----------------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class Heartbeat(Message):
    TYPE = "heartbeat"
    CATEGORY = "sys"
    AGENT_SCOPE = "any"
    service: str = bounded(max_len=64, doc="the service's name")
    pid: int = bounded(lo=0, hi=2**31, doc="its process id")
    started_ns: int = bounded(lo=0, hi=2**63 - 1, doc="when it started (tells a restart)")
    bad_messages: int = bounded(0, lo=0, hi=2**63 - 1, doc="messages rejected so far")
    coalesced: int = bounded(0, lo=0, hi=2**63 - 1, doc="state updates skipped: a newer one came in the same batch")
    dropped: int = bounded(0, lo=0, hi=2**63 - 1, doc="messages or reports discarded at a bound (rate limit, queue)")


@dataclass(frozen=True, kw_only=True)
class Hello(Message):
    """The broker's answer to a subscription to `sys.<nonce>.hello`: proves the subscription is live.

    The subscriber picks a fresh nonce as the agent field, so only it receives the answer."""

    TYPE = "hello"
    CATEGORY = "sys"
    AGENT_SCOPE = "any"  # the subscriber's nonce, whatever it chose


@dataclass(frozen=True, kw_only=True)
class Error(Message):
    TYPE = "error"
    CATEGORY = "error"
    AGENT_SCOPE = "any"  # '*' when the offending message named no readable agent
    reason: str = bounded(max_len=2000, doc="what was wrong, naming the field")
    kind: str = bounded("invalid", max_len=64, doc="the class of problem (codec error kind, 'rejected')")
    topic: str = bounded("", max_len=256, doc="the topic of the offending message")
    request_id: str = bounded("", max_len=64, doc="its request id, when it had one")
    service: str = bounded("", max_len=64, doc="the service that rejected it")


ENVELOPE_FIELDS = frozenset(f.name for f in dataclasses.fields(Message))
ALL_MESSAGES: tuple[type[Message], ...] = tuple(_REGISTRY.values())
MESSAGE_TYPES: dict[str, type[Message]] = dict(_REGISTRY)
TERMINAL_SPEECH_EVENTS: tuple[type[Message], ...] = (SpeechFinished, SpeechInterrupted, SpeechFailed)
