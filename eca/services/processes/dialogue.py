"""The dialogue service: owns each agent's conversational state and the lifecycle of its say requests.

Clients (a dialogue manager, the CLI, script replay, the window's keys) send commands on `cmd.`;
this service validates them, keeps per-agent state (role, emotion, head, eye mode, gaze target) and
publishes every change on `state.` (kept by the broker's last-value cache). Say requests it accepts
go to the audio service on `play.`; the audio service's raw lifecycle (`audio.`) comes back here and
is re-published on `event.` exactly once per request, so each request ends in one terminal event
even when the audio service dies (this service then fails what was pending).

Role and speech: when an utterance starts, the role becomes talking (set_by "speech"); when it ends
the role returns to what it was, unless a command set the role meanwhile: the dialogue manager's
explicit command always wins. A user who starts speaking (barge-in) interrupts the agent's speech
and makes it listen.

Batches: every command in a batch is validated and applied in order, but what the batch changed goes
out once, at its end (`_flush`): first onto disk (services/processes/state_snapshot.py), then the events and
requests the batch produced, then each changed state (so a flood of commands costs one state message
per topic per batch), then an `ack` for each command it applied. So an acknowledged command is in
the state its subscribers see and in the snapshot a successor starts from, and the state survives any
restart: of this service (the snapshot and the broker's cache), of the broker (`on_new_broker`
publishes the state again), or of both at once.

Agents: the configured ones (`[agents] ids`) live as long as the instance; `create_agent` adds one at run time
(a conversation of its own, e.g. one web page's; at most `[conversations] max` at once) and `remove_agent`
removes it again. The list of live agents is a state of its own, `state.*.agents`, published after the new
agent's states, so whoever follows it finds them in the broker's cache; it is in the snapshot too, so a
restarted dialogue service takes the created agents over with the rest.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, cast

from eca.agent.face.emotions import canonical_emotion_name, load_emotion_table
from eca.agent.gaze.params import default_eye_mode
from eca.protocol.bus import Received
from eca.protocol.codec import encode
from eca.protocol.endpoints import BusConfig, BusConfigError
from eca.protocol.messages import (
    ALL_AGENTS,
    MAX_CREATED_AGENTS,
    MAX_PENDING_SAYS,
    RECENT_ENDINGS,
    TERMINAL_SPEECH_EVENTS,
    Ack,
    AgentsState,
    CreateAgent,
    EmotionState,
    EyesState,
    GazeTargetState,
    HeadState,
    Heartbeat,
    Interrupt,
    Message,
    MoveHead,
    PlaybackState,
    RemoveAgent,
    RoleState,
    Say,
    SetEmotion,
    SetEyes,
    SetGazeTarget,
    SetRole,
    SpeechChunk,
    SpeechFailed,
    SpeechFinished,
    SpeechInterrupted,
    SpeechStarted,
    SpeechState,
    UserSpeech,
)
from eca.services.processes.runtime import Rejected, Service, parse_service_args
from eca.services.processes.state_snapshot import StateSnapshot, snapshot_path

STATE_TYPES = (RoleState, EmotionState, HeadState, EyesState, GazeTargetState, SpeechState, PlaybackState)
OWN_STATE_TYPES = ("role", "emotion", "head", "eyes", "gaze_target", "speech")  # what this service publishes
ENDED_KEPT = 1024  # per agent: request ids that ended here, remembered so a repeat of their ending is ignored
ACKED_KEPT = 4096  # commands acknowledged lately, remembered so one sent again is acknowledged, not re-applied
AGENTS_TOPIC = f"state.{ALL_AGENTS}.{AgentsState.TYPE}"
DEFAULT_MAX_CREATED = 60  # [conversations] max when the config does not say
USER = "user"  # the person the agents talk to: never an agent id
REMOVED_REASON = "the agent was removed"
MAX_START_AHEAD_NS = 60_000_000_000  # a say's start_ns at most this far ahead: a scheduled utterance, not a timer


def conversation_settings(config: BusConfig) -> tuple[int, str]:
    """[conversations] max (how many agents may be created at run time at once) and template (the configured
    agent a created one copies when its create_agent names none; empty: the first configured agent)."""
    where = f"{config.config_path} [conversations]"
    table = config.raw.get("conversations", {})
    if not isinstance(table, dict):
        raise BusConfigError(f"{config.config_path}: 'conversations' must be a table")
    limit = table.get("max", DEFAULT_MAX_CREATED)
    if type(limit) is not int or not 0 <= limit <= MAX_CREATED_AGENTS:
        raise BusConfigError(f"{where}: 'max' must be an integer in 0..{MAX_CREATED_AGENTS}, got {limit!r}"[:300])
    template = table.get("template", "")
    if not isinstance(template, str) or (template and template not in config.agents):
        raise BusConfigError(f"{where}: 'template' must be one of the configured agents "
                             f"({', '.join(config.agents)}) or empty, got {template!r}"[:300])
    return limit, template or config.agents[0]


@dataclass
class PendingSay:
    request_id: str
    agent: str
    streamed: bool
    queued_ns: int
    audio_started_ns: int | None  # started_ns of the audio service instance it was handed to
    started: bool = False
    next_chunk: int = 0
    chunks_done: bool = False
    to: tuple[str, ...] = ()  # the say's addressees, for the talking role while it plays


@dataclass
class AgentState:
    role: RoleState
    emotion: EmotionState
    head: HeadState
    eyes: EyesState
    gaze_target: GazeTargetState
    role_before_speech: RoleState | None = None
    pending: dict[str, PendingSay] = field(default_factory=dict)
    ended: deque[str] = field(default_factory=lambda: deque(maxlen=ENDED_KEPT))  # recent requests that ended here
    # the latest endings in full (request id, event type, played_s, reason), listed in the speech state
    endings: deque[tuple[str, str, float, str]] = field(default_factory=lambda: deque(maxlen=RECENT_ENDINGS))

    def current(self) -> tuple[Message, ...]:
        return (self.role, self.emotion, self.head, self.eyes, self.gaze_target)


def default_state(agent: str) -> AgentState:
    return AgentState(
        role=RoleState(agent=agent, role="listening", speaker="user"),
        emotion=EmotionState(agent=agent, name="natural", intensity=1.0, transition_s=0.0),
        head=HeadState(agent=agent, duration_s=0.0),
        eyes=EyesState(agent=agent, mode=default_eye_mode()),  # type: ignore[arg-type]
        gaze_target=GazeTargetState(agent=agent, target="user"),
    )


class DialogueService(Service):
    name = "dialogue"
    tick_hz = 20.0

    def __init__(self, config: BusConfig, **kwargs: Any) -> None:
        super().__init__(config, **kwargs)
        self.configured: tuple[str, ...] = tuple(config.agents)
        self.max_created, self.template = conversation_settings(config)
        # the agents created at run time, in order of creation -> the configured agent each copies
        self.created: dict[str, str] = {}
        dialogue = config.raw.get("dialogue", {})
        self.say_start_timeout_ns = int(float(dialogue.get("say_start_timeout_s", 3.0)) * 1e9)
        self.emotions = load_emotion_table()
        self.agents: dict[str, AgentState] = {}
        self._adopted: dict[str, dict[str, Message]] = {}
        self._adopted_agents: AgentsState | None = None
        self.audio_started_ns: int | None = None
        self.audio_last_beat_ns: int | None = None
        self.broker_last_beat_ns: int | None = None
        self.snapshot = StateSnapshot(snapshot_path(config))
        # What the batch being handled produced, sent by _flush at its end: changed states by topic
        # (the latest wins), then other messages in order, then acknowledgements.
        self._changed: dict[str, Message] = {}
        self._outbox: list[tuple[Message, str | None]] = []
        self._acks: list[Ack] = []
        # topic -> this service's state as last published, encoded: what the snapshot writes and a new broker gets
        # again, byte for byte, without encoding every state once more for each batch that changes one
        self._published: dict[str, bytes] = {}
        self._ended_before: dict[str, list[str]] = {}  # from the snapshot: requests a predecessor ended
        self._acked: OrderedDict[tuple[str, str, str], None] = OrderedDict()  # (agent, command, request id)
        once = self._once
        handlers: tuple[tuple[type[Any], Callable[[Any], None]], ...] = (
            (SetRole, once(self.on_set_role)), (SetEmotion, once(self.on_set_emotion)),
            (MoveHead, once(self.on_move_head)), (SetEyes, once(self.on_set_eyes)),
            (SetGazeTarget, once(self.on_set_gaze_target)), (Say, self.on_say),
            (SpeechChunk, self.on_chunk), (Interrupt, self.on_interrupt), (UserSpeech, once(self.on_user_speech)),
            (SpeechStarted, self.on_audio_started), (SpeechFinished, self.on_audio_terminal),
            (SpeechInterrupted, self.on_audio_terminal), (SpeechFailed, self.on_audio_terminal),
            (Heartbeat, self.on_heartbeat), (PlaybackState, self.on_playback),
            (CreateAgent, once(self.on_create_agent)), (RemoveAgent, once(self.on_remove_agent)),
        )
        for cls, handler in handlers:
            self.handle(cls, handler)

    @classmethod
    def from_args(cls, config: BusConfig, argv: list[str], **kwargs: Any) -> DialogueService:
        parse_service_args("dialogue", argv, argparse.ArgumentParser(
            prog="python -m eca.services.processes.run dialogue", add_help=False, exit_on_error=False))
        try:
            return cls(config, **kwargs)
        except BusConfigError as exc:  # a bad [conversations] table: one line, as for the rest of the config
            print(f"[dialogue] ERROR {exc}", file=sys.stderr)
            raise SystemExit(2) from None

    @property
    def agent_ids(self) -> list[str]:
        """Every live agent: the configured ones, then those created at run time in order."""
        return [*self.configured, *self.created]

    def subscriptions(self) -> list[str]:
        # Every agent's commands: one for an unknown agent gets a clear error, a create_agent names a new one.
        # The audio service's lifecycle of every agent: one created a moment ago included, with no subscription
        # that could still be on its way. Every state, until setup: a predecessor's agents list names the
        # created agents whose states to take over, and all of them come from the cache at once.
        return ["sys.", "cmd.", "audio.", "state."]

    # --- output: once per batch, snapshot first -------------------------------------------------

    def publish_later(self, msg: Message, category: str | None = None) -> None:
        """Queue a message the batch produced; `_flush` sends it after the batch's states."""
        self._outbox.append((msg, category))

    def after_batch(self) -> None:
        self._flush()

    def _flush(self) -> None:
        """Send what the batch produced: (after writing the snapshot) events and requests, states, acks."""
        assert self.pub is not None
        if AGENTS_TOPIC in self._changed:
            # the list goes out after the states of the agents it adds: whoever follows it finds them cached
            self._changed[AGENTS_TOPIC] = self._changed.pop(AGENTS_TOPIC)
        prepared = []
        for topic, msg in self._changed.items():
            frame, payload, stamped = self.pub.prepare(msg)
            prepared.append((frame, payload))
            self._published[topic] = payload
            if msg.TYPE not in ("speech", AgentsState.TYPE):
                setattr(self.agents[msg.agent], msg.TYPE, stamped)
        self._changed.clear()
        if prepared or any(isinstance(m, TERMINAL_SPEECH_EVENTS) for m, _ in self._outbox):
            self._save_snapshot()
        outbox, acks = self._outbox, self._acks
        self._outbox, self._acks = [], []
        for msg, category in outbox:  # events first: a speech state listing an ending comes after its event
            self.publish(msg, category)
        for frame, payload in prepared:
            self.pub.send_raw(frame, payload)
        for ack in acks:
            self.publish(ack)

    def _save_snapshot(self) -> None:
        try:
            self.snapshot.save(self._published.values(), {a: list(s.ended) for a, s in self.agents.items()})
        except OSError as exc:  # a full disk must not stop the agent; the broker's cache still holds the state
            self.dropped += 1
            if self.dropped == 1:
                self.log.warning("cannot write the state snapshot %s: %s", self.snapshot.path, exc.strerror)

    def on_new_broker(self) -> None:
        """A new broker's cache is empty: publish every state again, byte for byte as first published (so
        subscribers that still have it see a repeat, and the broker orders it by its original t_ns)."""
        assert self.pub is not None
        for topic, payload in self._published.items():
            self.pub.send_raw(topic.encode(), payload)
        self.log.info("published the current state again (%d topics) for the new broker's cache",
                      len(self._published))

    def _ack(self, command: Message) -> None:
        """The one rule (docs/protocol.md section 6): every command this service applies is acknowledged, with
        the command's own request_id, empty when it has none (for an interrupt, the say it names; empty: all of
        them). A speech_chunk is no command of its own but part of its say: the speech state's next_chunk
        confirms it. A non-empty request id is remembered, so the same command sent again is acknowledged and
        not applied twice."""
        rid: str = command.request_id  # type: ignore[attr-defined]  # every command type has one
        self._acks.append(Ack(agent=command.agent, request_id=rid, command=command.TYPE))
        if rid:
            self._acked[(command.agent, command.TYPE, rid)] = None
            while len(self._acked) > ACKED_KEPT:
                self._acked.popitem(last=False)

    def _once(self, handler: Any) -> Any:
        """The handler of a command a client may send again when its acknowledgement does not come (it was
        lost with a broker: the zguide's Lazy Pirate): a repeat of a command already applied is
        acknowledged again, not applied again."""
        def handle(cmd: Any) -> None:
            if cmd.request_id and (cmd.agent, cmd.TYPE, cmd.request_id) in self._acked:
                self._acks.append(Ack(agent=cmd.agent, request_id=cmd.request_id, command=cmd.TYPE))
                return
            handler(cmd)
        return handle

    # --- start-up: adopt the current state from the last-value cache (a restart keeps it) --------

    def on_early(self, early: list[Received]) -> None:
        saved, ended, problem = self.snapshot.load()
        if problem:
            self.log.warning("state snapshot: %s", problem)
        candidates = [got.message for got in early if got.message is not None]
        # the audio service's playback comes from the cache only: the snapshot holds this service's own
        candidates += [m for m in saved if m.TYPE in (*OWN_STATE_TYPES, AgentsState.TYPE)]
        self._adopt_created([m for m in candidates if isinstance(m, AgentsState)])
        self._adopted = {a: {} for a in self.agent_ids}
        for msg in candidates:
            if isinstance(msg, STATE_TYPES) and msg.agent in self._adopted:
                held = self._adopted[msg.agent].get(msg.TYPE)
                if held is None or msg.t_ns >= held.t_ns:  # topic by topic, the newer of snapshot and cache
                    self._adopted[msg.agent][msg.TYPE] = msg
        self._ended_before = ended

    def _adopt_created(self, lists: list[AgentsState]) -> None:
        """The agents a predecessor created, from the newer of the snapshot's and the cache's agents list. One
        the config now names is a configured agent; one whose template is no longer configured copies the
        current template. The limit is for new ones: those already created stay, however many."""
        if not lists:
            return
        newest = max(lists, key=lambda m: m.t_ns)
        for agent, like in zip(newest.created, newest.like, strict=True):
            if agent not in self.configured and agent != USER:
                self.created[agent] = like if like in self.configured else self.template
        self._adopted_agents = newest
        if self.created:
            self.log.info("took over %d agent(s) created at run time: %s", len(self.created),
                          ", ".join(self.created))

    def setup(self) -> None:
        assert self.sub is not None and self.pub is not None
        for agent in self.agent_ids:
            state = default_state(agent)
            adopted = self._adopted[agent]
            state.role = cast(RoleState, adopted.get("role", state.role))
            state.emotion = cast(EmotionState, adopted.get("emotion", state.emotion))
            state.head = cast(HeadState, adopted.get("head", state.head))
            state.eyes = cast(EyesState, adopted.get("eyes", state.eyes))
            state.gaze_target = cast(GazeTargetState, adopted.get("gaze_target", state.gaze_target))
            state.ended.extend(self._ended_before.get(agent, []))
            for msg in adopted.values():
                if msg.TYPE in OWN_STATE_TYPES:
                    # the cache of a new broker may lack what the snapshot had: publish it again as it was
                    topic, payload = f"state.{agent}.{msg.TYPE}", encode(msg)
                    self._published[topic] = payload
                    self.pub.send_raw(topic.encode(), payload)
            speech = adopted.get("speech")
            if isinstance(speech, SpeechState):
                self._adopt(state, speech)
            if state.role.role == "talking" and state.role.set_by == "speech":
                # A previous instance was mid-speech; what the role was before is lost with it, so the
                # end of that speech (reported by the audio service) returns the agent to the default.
                state.role_before_speech = default_state(agent).role
            self.agents[agent] = state
            for msg in state.current():
                if msg.TYPE not in adopted:
                    self._set_state(agent, msg)
            if "speech" not in adopted:
                self._publish_speech(state)
            playback = adopted.get("playback")
            if isinstance(playback, PlaybackState) and state.pending:
                self._reconcile(agent, playback, adopting=True)
            if adopted:
                self.log.info("agent %s: adopted current state (%s) from the snapshot and the cache", agent,
                              ", ".join(sorted(adopted)))
        listed = self._adopted_agents
        if listed is not None and _same_body(listed, self._agents_state()):
            # as the predecessor published it, after the agents' own states
            payload = self._published[AGENTS_TOPIC] = encode(listed)
            self.pub.send_raw(AGENTS_TOPIC.encode(), payload)
        else:
            self._publish_agents()
        # From now on our own state echoes would come back on state.: we know them already. The audio
        # service's playback state stays: it tells which requests ended, also when their terminal event was
        # lost with a broker.
        for agent in self.agent_ids:
            self.sub.subscribe(f"state.{agent}.playback")
        self.sub.unsubscribe("state.")
        self._flush()

    def _adopt(self, state: AgentState, speech: SpeechState) -> None:
        """Take over the say requests a previous instance handed to the audio service, and the endings it
        listed (its speech state)."""
        now_ns = self.clock.now_ns()
        state.endings.extend(zip(speech.ended_ids, speech.ended_as, speech.ended_played_s, speech.ended_reasons,
                                 strict=True))
        for rid, streamed, next_chunk, chunks_done, started, audio_ns in zip(
            speech.request_ids, speech.streamed, speech.next_chunk, speech.chunks_done, speech.started,
            speech.audio_started_ns, strict=True,
        ):
            state.pending[rid] = PendingSay(rid, speech.agent, streamed, now_ns, audio_ns or None, started,
                                            next_chunk, chunks_done)
        if state.pending:
            self.log.info("agent %s: took over %d pending say request(s) from a previous instance",
                          speech.agent, len(state.pending))

    def _reconcile(self, agent: str, playback: PlaybackState, adopting: bool = False) -> None:
        """End the pending requests that the audio service instance they went to no longer holds and lists
        among its latest endings: their terminal event could not reach this service (it was restarting,
        or the broker was), and is still owed. When adopting a predecessor's requests, one neither held
        nor listed ended too long ago to tell how: it fails. (Otherwise such a request may simply not
        have reached the audio service yet.)"""
        state = self.agents[agent]
        held = set(playback.request_ids)
        for p in list(state.pending.values()):
            if p.audio_started_ns == playback.started_ns and p.request_id not in held:
                ending = playback.ending_of(p.request_id)
                if ending is not None:
                    self._end(state, p.request_id, ending)
        if adopting:
            self._fail_pending(
                lambda p: p.agent == agent and p.audio_started_ns == playback.started_ns and p.request_id not in held,
                "it ended while the dialogue service was restarting; how it ended was lost",
            )

    def on_playback(self, playback: PlaybackState) -> None:
        state = self.agents.get(playback.agent)
        if state is None:
            return  # an agent removed a moment ago (or never here): the audio service has not heard yet
        if state.pending:
            self._reconcile(playback.agent, playback)

    def _publish_speech(self, state: AgentState) -> None:
        """The agent's pending say requests as state.<agent>.speech, for a successor to take over."""
        pending = list(state.pending.values())
        agent = state.role.agent
        self._changed[f"state.{agent}.speech"] = (SpeechState(
            agent=state.role.agent,
            request_ids=[p.request_id for p in pending],
            streamed=[p.streamed for p in pending],
            next_chunk=[p.next_chunk for p in pending],
            chunks_done=[p.chunks_done for p in pending],
            started=[p.started for p in pending],
            audio_started_ns=[p.audio_started_ns or 0 for p in pending],
            ended_ids=[e[0] for e in state.endings],
            ended_as=[e[1] for e in state.endings],  # type: ignore[misc]
            ended_played_s=[e[2] for e in state.endings],
            ended_reasons=[e[3] for e in state.endings],
        ))

    def _agent(self, msg: Message) -> AgentState:
        state = self.agents.get(msg.agent)
        if state is None:
            created = f" and {len(self.created)} created at run time" if self.created else ""
            raise Rejected(f"unknown agent '{msg.agent}'; this instance animates {', '.join(self.configured)}"
                           f"{created}")
        return state

    def _agents_state(self) -> AgentsState:
        return AgentsState(agent=ALL_AGENTS, agents=self.agent_ids, created=list(self.created),
                           like=list(self.created.values()), max_created=self.max_created)

    def _publish_agents(self) -> None:
        self._changed[AGENTS_TOPIC] = self._agents_state()

    def _set_state(self, agent: str, msg: Message) -> None:
        """The agent's state of msg's type is msg from now on; it goes out at the end of the batch."""
        fresh = dataclasses.replace(msg, agent=agent, t_ns=0, seq=0, source="")
        setattr(self.agents[agent], msg.TYPE, fresh)
        self._changed[f"state.{agent}.{msg.TYPE}"] = fresh

    # --- commands --------------------------------------------------------------------------------

    def on_set_role(self, cmd: SetRole) -> None:
        self._agent(cmd)
        self._set_state(cmd.agent, cmd.as_state(set_by="command"))
        self.agents[cmd.agent].role_before_speech = None  # the manager's word stands after the speech
        self._ack(cmd)

    def on_set_emotion(self, cmd: SetEmotion) -> None:
        self._agent(cmd)
        name = canonical_emotion_name(cmd.name)
        if name not in self.emotions.names:
            raise Rejected(f"unknown emotion '{cmd.name}'; known: {', '.join(self.emotions.names)}",
                           cmd.request_id)
        self._set_state(cmd.agent, cmd.as_state(name=name))
        self._ack(cmd)

    def on_move_head(self, cmd: MoveHead) -> None:
        self._agent(cmd)
        self._set_state(cmd.agent, cmd.as_state())
        self._ack(cmd)

    def on_set_eyes(self, cmd: SetEyes) -> None:
        self._agent(cmd)
        self._set_state(cmd.agent, cmd.as_state())
        self._ack(cmd)

    def on_set_gaze_target(self, cmd: SetGazeTarget) -> None:
        self._agent(cmd)
        self._set_state(cmd.agent, cmd.as_state())
        self._ack(cmd)

    def on_say(self, cmd: Say) -> None:
        state = self._agent(cmd)
        if not cmd.request_id:
            raise Rejected("a say request needs a non-empty request_id")
        if cmd.request_id in state.pending or cmd.request_id in state.ended:
            # Sent again by a client that missed the acknowledgement: the request stands as it is (request
            # ids are unique per request, so this is no new request).
            self._ack(cmd)
            return
        sources = [cmd.audio_path is not None, cmd.pcm is not None, cmd.streamed]
        if sum(sources) > 1:
            raise Rejected("a say request takes one of audio_path, pcm or streamed=true, not several",
                           cmd.request_id)
        if not any(sources) and not (cmd.text and cmd.text.strip()):
            raise Rejected("a say request needs audio (audio_path, pcm or streamed=true) or, to be spoken by the "
                           "text-to-speech engine, a text", cmd.request_id)
        if cmd.audio_path is not None and cmd.sample_rate != 0:
            raise Rejected(f"sample_rate must be 0 with audio_path (the file gives its own rate), got "
                           f"{cmd.sample_rate}", cmd.request_id)
        if (cmd.pcm is not None or cmd.streamed) and cmd.sample_rate < 8000:
            raise Rejected(f"sample_rate {cmd.sample_rate} is too low for PCM (8000 or more)", cmd.request_id)
        if cmd.pcm is not None and len(cmd.pcm) % 2:
            raise Rejected("pcm must hold whole 16-bit samples (an even number of bytes)", cmd.request_id)
        # A configured agent talks with the other configured agents and the user; one created at run time has a
        # conversation of its own, with its user only.
        peers = [a for a in self.configured if a != cmd.agent] if cmd.agent in self.configured else []
        wrong = [p for p in cmd.to if p != USER and p not in peers]
        if wrong:
            raise Rejected(f"'to' names {', '.join(map(repr, wrong))}: a say is addressed to other agents of its "
                           f"conversation ({', '.join(peers) or 'none'}) or 'user'", cmd.request_id)
        if cmd.start_ns > self.clock.now_ns() + MAX_START_AHEAD_NS:
            raise Rejected(f"start_ns lies more than {MAX_START_AHEAD_NS // 1_000_000_000} s ahead of the master "
                           "clock (a monotonic time of the audio service's host, in ns)", cmd.request_id)
        if len(state.pending) >= MAX_PENDING_SAYS:
            raise Rejected(f"agent '{cmd.agent}' already has {MAX_PENDING_SAYS} say requests pending; "
                           "send this one when one of them has ended", cmd.request_id)
        state.pending[cmd.request_id] = PendingSay(cmd.request_id, cmd.agent, cmd.streamed,
                                                   self.clock.now_ns(), self.audio_started_ns,
                                                   to=tuple(dict.fromkeys(cmd.to)))
        self.publish_later(dataclasses.replace(cmd, t_ns=0), category="play")
        self._publish_speech(state)
        self._ack(cmd)

    def on_chunk(self, cmd: SpeechChunk) -> None:
        state = self._agent(cmd)
        pending = state.pending.get(cmd.request_id)
        if pending is None or not pending.streamed:
            raise Rejected(f"no streamed say request '{cmd.request_id}' is pending", cmd.request_id)
        if pending.chunks_done:
            raise Rejected(f"request '{cmd.request_id}' already had its last chunk", cmd.request_id)
        if cmd.index != pending.next_chunk:
            raise Rejected(f"chunk {cmd.index} of '{cmd.request_id}' out of order; expected "
                           f"{pending.next_chunk}", cmd.request_id)
        if len(cmd.pcm) % 2:
            raise Rejected("pcm must hold whole 16-bit samples (an even number of bytes)", cmd.request_id)
        pending.next_chunk += 1
        pending.chunks_done = cmd.last
        self.publish_later(dataclasses.replace(cmd, t_ns=0), category="play")
        self._publish_speech(state)

    def on_interrupt(self, cmd: Interrupt) -> None:
        state = self._agent(cmd)
        if cmd.request_id and cmd.request_id in state.ended:
            self._ack(cmd)  # it has ended already (perhaps by this very command, sent again)
            return
        if cmd.request_id and cmd.request_id not in state.pending:
            raise Rejected(f"no pending say request '{cmd.request_id}' to interrupt", cmd.request_id)
        self.publish_later(dataclasses.replace(cmd, t_ns=0), category="play")
        self._ack(cmd)

    def on_user_speech(self, cmd: UserSpeech) -> None:
        state = self._agent(cmd)
        if cmd.speaking:
            # Always: the audio service may be playing requests a previous instance of this service handed it.
            self.publish_later(Interrupt(agent=cmd.agent, reason="the user started speaking"), category="play")
            state.role_before_speech = None
            self._set_state(cmd.agent, RoleState(agent=cmd.agent, role="listening", speaker="user",
                                                 set_by="command"))
        # Re-published as an event, so the listeners' backchannels (gaze service) can answer the user's pauses.
        self.publish_later(dataclasses.replace(cmd, t_ns=0, seq=0, source="", request_id=""), category="event")
        self._ack(cmd)

    # --- the audio service's lifecycle, re-published once per request ------------------------------

    def on_audio_started(self, ev: SpeechStarted) -> None:
        state = self.agents.get(ev.agent)
        if state is None:
            return  # the audio service's news of an agent removed (or never here): nobody waits for it
        pending = state.pending.get(ev.request_id)
        if pending is None or pending.started:
            return  # already failed by us (audio lost), or a duplicate
        pending.started = True
        self.publish_later(dataclasses.replace(ev, t_ns=0, seq=0, source=""))
        self._publish_speech(state)
        if state.role.role != "talking" or state.role.set_by != "speech":
            state.role_before_speech = state.role
        if state.role.role != "talking" or state.role.set_by != "speech" or \
                state.role.addressees != list(pending.to):
            self._set_state(ev.agent, RoleState(agent=ev.agent, role="talking", speaker=ev.agent,
                                                set_by="speech", addressees=list(pending.to)))

    def on_audio_terminal(self, ev: SpeechFinished | SpeechInterrupted | SpeechFailed) -> None:
        state = self.agents.get(ev.agent)
        if state is not None:  # a removed agent's requests ended when it was removed
            self._end(state, ev.request_id, ev)

    # --- agents created and removed at run time ----------------------------------------------------

    def on_create_agent(self, cmd: CreateAgent) -> None:
        agent = cmd.agent
        if agent in self.agents:
            kind = "a configured agent" if agent in self.configured else "created already"
            raise Rejected(f"agent '{agent}' exists ({kind}); choose another id")
        if agent == USER:
            raise Rejected(f"'{USER}' is the person the agents talk to, not an agent id")
        like = cmd.like or self.template
        if like not in self.configured:
            raise Rejected(f"like: '{cmd.like}' is not an agent of the config ({', '.join(self.configured)}); a "
                           "created agent copies the settings of a configured one")
        if len(self.created) >= self.max_created:
            raise Rejected(f"busy: all {self.max_created} conversations are in use, try again later", kind="busy")
        assert self.sub is not None
        state = default_state(agent)
        self.agents[agent] = state
        self.created[agent] = like
        for msg in state.current():
            self._set_state(agent, msg)
        self._publish_speech(state)
        self._publish_agents()
        self.sub.subscribe(f"state.{agent}.playback")
        self._ack(cmd)
        self.log.info("created agent %s (like %s); %d of %d created", agent, like, len(self.created),
                      self.max_created)

    def on_remove_agent(self, cmd: RemoveAgent) -> None:
        agent = cmd.agent
        state = self._agent(cmd)
        if agent in self.configured:
            raise Rejected(f"agent '{agent}' is configured ([agents] ids): only agents created at run time can be "
                           "removed")
        assert self.sub is not None
        if state.pending:
            # stop its voice now; each pending request ends here, once (the audio service's own report of it
            # comes after the agent is gone and is no news)
            self.publish_later(Interrupt(agent=agent, reason=REMOVED_REASON), category="play")
        for rid in list(state.pending):
            self._end(state, rid, SpeechInterrupted(agent=agent, request_id=rid, reason=REMOVED_REASON))
        del self.agents[agent], self.created[agent]
        prefix = f"state.{agent}."
        for table in (self._changed, self._published):  # its states are no longer published, nor on disk
            for topic in [t for t in table if t.startswith(prefix)]:
                del table[topic]
        self._ended_before.pop(agent, None)
        self.sub.unsubscribe(f"state.{agent}.playback")
        self._publish_agents()
        self._ack(cmd)
        self.log.info("removed agent %s; %d of %d created", agent, len(self.created), self.max_created)

    def _end(self, state: AgentState, request_id: str, ev: Message) -> None:
        """Publish the one terminal event of a request (none if it already ended here)."""
        was_pending = state.pending.pop(request_id, None) is not None
        if not was_pending and request_id in state.ended:
            return  # already ended here (failed by us when the audio side was lost), or a duplicate
        # (one unknown here and not ended here was handed to the audio service by a previous instance of
        # this service whose speech state never reached the cache: its terminal event is still owed)
        state.ended.append(request_id)
        state.endings.append((request_id, ev.TYPE, float(getattr(ev, "played_s", 0.0)),
                              str(getattr(ev, "reason", ""))))
        self.publish_later(dataclasses.replace(ev, t_ns=0, seq=0, source=""))
        self._publish_speech(state)
        self._after_speech(state)

    def _after_speech(self, state: AgentState) -> None:
        if any(p.started for p in state.pending.values()):
            return
        if state.role.set_by == "speech" and state.role_before_speech is not None:
            previous = state.role_before_speech
            state.role_before_speech = None
            self._set_state(previous.agent, RoleState(agent=previous.agent, role=previous.role,
                                                      speaker=previous.speaker, set_by="speech"))

    def on_heartbeat(self, beat: Heartbeat) -> None:
        if beat.service == "broker":
            self.broker_last_beat_ns = self.clock.now_ns()
            return
        if beat.service != "audio":
            return
        if beat.started_ns != self.audio_started_ns:
            # Requests handed to another instance (before a restart of either service) will never play.
            known = self.audio_started_ns is not None
            self._fail_pending(
                lambda p: p.audio_started_ns != beat.started_ns and (known or p.audio_started_ns is not None),
                "the audio service restarted",
            )
        self.audio_started_ns = beat.started_ns
        self.audio_last_beat_ns = self.clock.now_ns()

    def on_tick(self, now_ns: int) -> None:
        self._check_audio(now_ns)
        self._flush()

    def _check_audio(self, now_ns: int) -> None:
        timeout_ns = int(self.config.heartbeat_timeout_s * 1e9)
        if self.broker_last_beat_ns is None or now_ns - self.broker_last_beat_ns > timeout_ns:
            # The bus itself is down (or not yet heard): the audio service's silence says nothing about
            # it, and its requests may well be playing. They wait for the broker to come back.
            return
        if self.audio_last_beat_ns is not None and now_ns - self.audio_last_beat_ns > timeout_ns:
            if now_ns - self.broker_last_beat_ns <= timeout_ns < now_ns - self.audio_last_beat_ns:
                self._fail_pending(lambda p: True, "the audio service stopped answering")
                self.audio_last_beat_ns = None
                self.audio_started_ns = None
        if self.audio_last_beat_ns is None:
            self._fail_pending(lambda p: now_ns - p.queued_ns > self.say_start_timeout_ns,
                               "no audio service answered")
            return
        # Sent before the first heartbeat of the audio service now running: it may have subscribed after
        # the request went out. Not started in time means it never arrived; make sure it never plays.
        stray = [p for state in self.agents.values() for p in state.pending.values()
                 if p.audio_started_ns is None and not p.started and now_ns - p.queued_ns > self.say_start_timeout_ns]
        for p in stray:
            self.publish_later(Interrupt(agent=p.agent, request_id=p.request_id, reason="no audio service answered"),
                               category="play")
        if stray:
            ids = {id(p) for p in stray}
            self._fail_pending(lambda p: id(p) in ids, "no audio service answered")

    def _fail_pending(self, which: Any, reason: str) -> None:
        for state in self.agents.values():
            doomed = [p for p in state.pending.values() if which(p)]
            for p in doomed:
                self._end(state, p.request_id, SpeechFailed(agent=p.agent, request_id=p.request_id, reason=reason))


def _same_body(a: Message, b: Message) -> bool:
    """Whether two messages say the same, whatever their envelopes."""
    skip = ("seq", "t_ns", "source")
    return type(a) is type(b) and {k: v for k, v in vars(a).items() if k not in skip} == \
        {k: v for k, v in vars(b).items() if k not in skip}
