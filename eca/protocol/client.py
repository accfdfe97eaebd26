"""The Python client for external dialogue managers: drive one agent and wait for what it does.

    with AgentClient(agent="ada") as ada:
        ada.set_emotion("happy", intensity=0.8)
        rid = ada.say(audio_path="hello.wav", text="Hello!")
        print(ada.wait_for_speech(rid, timeout_s=30))   # SpeechFinished / Interrupted / Failed

Every command is validated before it is sent (a `ProtocolError` names the bad field) and carries a
request id (a fresh one unless given). The dialogue service answers each with an `ack` once it has
applied it, after the state it caused, or with an `Error` carrying that id; `wait_applied` waits for
the one or raises `CommandRejected` for the other, so "applied" never means "the cache said so".

    with AgentClient(agent="ada") as ada:
        ada.wait_applied(ada.set_emotion("happy", 0.8))   # raises CommandRejected, or BusTimeout
        print(ada.state["emotion"])                        # the state it caused
"""

from __future__ import annotations

import logging
import secrets
import time
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from typing import Any, TypeVar

import zmq

from eca.protocol.bus import BusTimeout, LinkWatch, Publisher, Subscriber
from eca.protocol.endpoints import BusConfig, load_bus_config
from eca.protocol.messages import (
    TERMINAL_SPEECH_EVENTS,
    Ack,
    Bml,
    CreateAgent,
    Error,
    Interrupt,
    Message,
    MoveHead,
    RemoveAgent,
    Say,
    SetEmotion,
    SetEyes,
    SetGazeTarget,
    SetRole,
    SpeechChunk,
    SpeechState,
    UserSpeech,
)

M = TypeVar("M", bound=Message)
log = logging.getLogger("eca.client")


class CommandRejected(RuntimeError):
    def __init__(self, error: Error) -> None:
        super().__init__(error.reason)
        self.error = error


class AgentClient:
    def __init__(self, config: BusConfig | None = None, agent: str = "ada", source: str | None = None,
                 ctx: zmq.Context[zmq.Socket[bytes]] | None = None, timeout_s: float = 5.0) -> None:
        if not timeout_s > 0:
            raise ValueError(f"timeout_s must be positive, got {timeout_s}")
        self.config = config or load_bus_config()
        self.agent = agent
        self._ids = f"{source or 'client'}-{secrets.token_hex(3)}"
        self._sent = 0
        self._own_ctx = ctx is None
        self.ctx = ctx or zmq.Context()
        self.pub = Publisher(self.ctx, self.config, source or f"client-{secrets.token_hex(3)}")
        self.sub = Subscriber(self.ctx, self.config, [f"state.{agent}.", f"event.{agent}.", f"error.{agent}."])
        try:
            self.pub.wait_ready(timeout_s)
            early = self.sub.wait_ready(timeout_s)
        except BaseException:  # no broker: give the sockets (and our own context) back before raising
            self.close()
            raise
        self.link = LinkWatch(self.ctx, self.config)
        self._link_was_up = True
        self._inbox: deque[Message] = deque(m.message for m in early if m.message)
        self.state: dict[str, Message] = {}
        for msg in self._inbox:
            self._note(msg)

    # --- the link ---------------------------------------------------------------------------------

    def link_up(self) -> bool:
        """Whether the broker's heartbeats reach this client (none for [heartbeat] timeout_s: the link is down,
        a partition or a broker gone). A change is logged once. Commands sent meanwhile wait in this client's
        queue and go out when the link heals; send them with a request id and `wait_applied`."""
        up = self.link.up()
        if up != self._link_was_up:
            self._link_was_up = up
            if up:
                log.info("the link to the broker at %s is back", self.config.backend)
            else:
                log.warning("the link to the broker at %s is down: no heartbeat for %.1f s", self.config.backend,
                            self.link.silent_ns() / 1e9)
        return up

    # --- commands ---------------------------------------------------------------------------------

    def send(self, msg: Message) -> Message:
        return self.pub.publish(msg)

    def new_request_id(self) -> str:
        self._sent += 1
        return f"{self._ids}-{self._sent}"

    def _rid(self, request_id: str | None) -> str:
        return self.new_request_id() if request_id is None else request_id

    def command(self, cls: type[M], request_id: str | None = None, **fields: Any) -> Message:
        """Send a command of type `cls` with `fields` and a request id (a new one unless given)."""
        return self.send(cls(agent=self.agent, request_id=self._rid(request_id), **fields))  # type: ignore[call-arg]

    def create_agent(self, like: str = "", request_id: str | None = None) -> Message:
        """Create this client's agent at run time (docs/protocol.md "Conversations created at run time"), with the
        settings of the configured agent `like` (empty: the config's template)."""
        return self.command(CreateAgent, request_id, like=like)

    def remove_agent(self, request_id: str | None = None) -> Message:
        """Remove this client's agent, created at run time."""
        return self.command(RemoveAgent, request_id)

    def set_role(self, role: str, speaker: str = "", request_id: str | None = None) -> Message:
        return self.command(SetRole, request_id, role=role, speaker=speaker)

    def set_emotion(self, name: str, intensity: float = 1.0, transition_s: float = 0.5,
                    request_id: str | None = None) -> Message:
        return self.command(SetEmotion, request_id, name=name, intensity=intensity, transition_s=transition_s)

    def move_head(self, turn: float = 0.0, nod: float = 0.0, tilt: float = 0.0, duration_s: float = 0.5,
                  request_id: str | None = None) -> Message:
        return self.command(MoveHead, request_id, turn=turn, nod=nod, tilt=tilt, duration_s=duration_s)

    def set_eyes(self, mode: str, request_id: str | None = None) -> Message:
        return self.command(SetEyes, request_id, mode=mode)

    def set_gaze_target(self, yaw_deg: float, pitch_deg: float = 0.0, target: str = "",
                        request_id: str | None = None) -> Message:
        return self.command(SetGazeTarget, request_id, yaw_deg=yaw_deg, pitch_deg=pitch_deg, target=target)

    def say(self, audio_path: str | None = None, pcm: bytes | None = None, sample_rate: int = 0,
            text: str | None = None, request_id: str | None = None, to: Sequence[str] = (),
            start_ns: int = 0) -> str:
        """`to`: who it is said to (other agents of the instance, `user`); empty: everyone. `start_ns`: heard no
        earlier than this master-clock time."""
        rid = request_id or f"say-{secrets.token_hex(6)}"
        self.send(Say(agent=self.agent, request_id=rid, audio_path=audio_path, pcm=pcm, sample_rate=sample_rate,
                      text=text, to=list(to), start_ns=start_ns))
        return rid

    def bml(self, xml: str, request_id: str | None = None) -> Message:
        """A BML block for the agent's realizer (the bml service); its feedback comes as `bml_feedback` events."""
        return self.send(Bml(agent=self.agent, request_id=self._rid(request_id), xml=xml))

    def say_stream(self, chunks: Iterable[bytes], sample_rate: int, text: str | None = None,
                   request_id: str | None = None) -> str:
        """Stream PCM chunks (signed 16-bit mono) as a TTS engine produces them."""
        rid = request_id or f"say-{secrets.token_hex(6)}"
        self.send(Say(agent=self.agent, request_id=rid, streamed=True, sample_rate=sample_rate, text=text))
        previous: bytes | None = None
        index = 0
        for chunk in chunks:
            if previous is not None:
                self.send(SpeechChunk(agent=self.agent, request_id=rid, index=index, pcm=previous))
                index += 1
            previous = chunk
        self.send(SpeechChunk(agent=self.agent, request_id=rid, index=index, pcm=previous or b"", last=True))
        return rid

    def interrupt(self, request_id: str = "", reason: str = "command") -> Message:
        return self.send(Interrupt(agent=self.agent, request_id=request_id, reason=reason))

    def user_speaking(self, speaking: bool = True, request_id: str | None = None) -> Message:
        return self.send(UserSpeech(agent=self.agent, speaking=speaking, request_id=self._rid(request_id)))

    # --- waiting ---------------------------------------------------------------------------------

    def wait_for(self, predicate: Callable[[Message], bool], timeout_s: float) -> Message:
        """The first message (already received or arriving) that satisfies `predicate`."""
        for i, msg in enumerate(self._inbox):
            if predicate(msg):
                del self._inbox[i]
                return msg
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            got = self.sub.recv(left)
            if got is None or got.message is None:
                continue
            self._note(got.message)
            if predicate(got.message):
                return got.message
            self._inbox.append(got.message)
            if len(self._inbox) > 10_000:
                self._inbox.popleft()
        raise BusTimeout(f"nothing matching arrived within {timeout_s} s")

    def take_held(self) -> list[Message]:
        """The messages received while waiting that matched no wait (the newest 10,000), oldest first; the client
        holds none of them afterwards."""
        held = list(self._inbox)
        self._inbox.clear()
        return held

    def wait_applied(self, sent: Message, timeout_s: float = 5.0, resend_s: float = 0.5) -> Ack:
        """The acknowledgement of a command sent with a request id: the owning service applied it (and the
        state it caused has arrived before it). Raises CommandRejected when it was refused, BusTimeout
        when no answer came within `timeout_s` (the dialogue service may be down).

        While it waits it sends the command again, after `resend_s` and then at doubling intervals (the
        zguide's Lazy Pirate): a command or its acknowledgement can be lost while a broker restarts, and
        the dialogue service acknowledges a repeat of a command it applied without applying it twice."""
        request_id = getattr(sent, "request_id", "")
        command = sent.TYPE

        def match(m: Message) -> bool:
            if isinstance(m, Error):
                return bool(request_id) and m.request_id == request_id
            return isinstance(m, Ack) and m.request_id == request_id and m.command == command

        deadline = time.monotonic() + timeout_s
        interval = resend_s
        while True:
            left = deadline - time.monotonic()
            try:
                got = self.wait_for(match, max(0.0, min(left, interval)))
                break
            except BusTimeout:
                if time.monotonic() >= deadline:
                    why = "is the dialogue service running?" if self.link_up() else \
                        f"the link to the broker is down (no heartbeat for {self.link.silent_ns() / 1e9:.1f} s)"
                    raise BusTimeout(f"no acknowledgement of {command} within {timeout_s:g} s: {why}") from None
            if request_id:  # without an id a repeat could not be told from a new command
                self.pub.publish(sent)
            interval = min(2 * interval, 2.0)
        if isinstance(got, Error):
            raise CommandRejected(got)
        return got  # type: ignore[return-value]

    def expect_state(self, cls: type[M], check: Callable[[M], bool] = lambda m: True, timeout_s: float = 5.0,
                     request_id: str = "") -> M:
        """Wait for a state change of type `cls`; raise CommandRejected on an error for this agent."""
        def match(m: Message) -> bool:
            if isinstance(m, Error) and (not request_id or m.request_id == request_id):
                return True
            return isinstance(m, cls) and check(m)

        got = self.wait_for(match, timeout_s)
        if isinstance(got, Error):
            raise CommandRejected(got)
        return got  # type: ignore[return-value]

    def wait_for_speech(self, request_id: str, timeout_s: float = 60.0) -> Message:
        """The terminal lifecycle event of a say request (finished, interrupted or failed).

        When the event itself was lost (it was published while a broker restarted), the agent's speech
        state, which lists the latest endings and is cached, gives the same answer."""
        def match(m: Message) -> bool:
            if isinstance(m, Error) and m.request_id == request_id:
                return True
            if isinstance(m, SpeechState):
                return m.ending_of(request_id) is not None
            return isinstance(m, TERMINAL_SPEECH_EVENTS) and getattr(m, "request_id", None) == request_id

        speech = self.state.get("speech")
        if isinstance(speech, SpeechState) and (ended := speech.ending_of(request_id)) is not None:
            return ended
        got = self.wait_for(match, timeout_s)
        if isinstance(got, Error):
            raise CommandRejected(got)
        if isinstance(got, SpeechState):
            return got.ending_of(request_id)  # type: ignore[return-value]
        return got

    def _note(self, msg: Message) -> None:
        if msg.CATEGORY == "state":
            self.state[msg.TYPE] = msg

    def close(self) -> None:
        self.pub.close()
        self.sub.close()
        if hasattr(self, "link"):  # not there when the broker never answered
            self.link.close()
        if self._own_ctx:
            self.ctx.term()

    def __enter__(self) -> AgentClient:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
