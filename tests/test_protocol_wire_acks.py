"""The acknowledgement rule of docs/protocol.md section 6, for every command type, on a real broker and the real
dialogue service: every command applied is acknowledged once, with its request_id as sent (empty when it had
none); a refused one gets an error instead and no ack; a speech_chunk is part of its say, not acknowledged.
And a say with an audio file and a sample rate is refused, as section 7 says."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator

import pytest
import zmq

from eca.protocol.bus import Publisher, Subscriber
from eca.protocol.client import AgentClient
from eca.protocol.messages import (
    ALL_AGENTS,
    MESSAGE_TYPES,
    Ack,
    CreateAgent,
    Error,
    Heartbeat,
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
    UserSpeech,
)
from eca.services.processes.dialogue import DialogueService
from eca.services.processes.runtime import wait_until
from tests.support.bus import ServiceThread

# The dialogue service's commands; `bml` is the bml service's (tests/test_bml_service.py holds its acks).
COMMANDS = {cls.TYPE for cls in MESSAGE_TYPES.values() if cls.CATEGORY == "cmd"} - {"bml"}


@pytest.fixture
def dialogue(bus) -> Iterator[DialogueService]:
    service = DialogueService(bus)
    with ServiceThread(service):
        yield service


@pytest.fixture
def audio_beats(bus, dialogue: DialogueService) -> Iterator[Callable[[], None]]:
    """Heartbeats of an audio service (no audio service runs: the say requests stay pending meanwhile)."""
    ctx = zmq.Context()
    pub = Publisher(ctx, bus, "audio")
    pub.wait_ready()

    def beat() -> None:
        pub.publish(Heartbeat(agent=ALL_AGENTS, service="audio", pid=os.getpid(), started_ns=5))
        assert wait_until(lambda: dialogue.audio_started_ns == 5, 5.0)

    try:
        yield beat
    finally:
        pub.close()
        ctx.term()


class Answers:
    """What the dialogue service answers to commands: acks and errors (of every agent), in order."""

    def __init__(self, config) -> None:
        self.ctx = zmq.Context()
        self.pub = Publisher(self.ctx, config, "answers")
        self.sub = Subscriber(self.ctx, config, ["event.", "error."])
        self.pub.wait_ready()
        self.sub.wait_ready()

    def after(self, msg: Message, marker_rid: str) -> list[Message]:
        """Send `msg`, then a marker command for ada with request id `marker_rid` (from the same publisher, so
        the dialogue service handles it later); the acks and errors that came before the marker's ack."""
        self.pub.publish(msg)
        self.pub.publish(SetRole(agent="ada", role="listening", request_id=marker_rid))
        got: list[Message] = []
        while True:
            received = self.sub.recv(5.0)
            assert received is not None, f"no answer to the marker after {msg.TYPE}"
            m = received.message
            if isinstance(m, Ack) and m.request_id == marker_rid and m.command == "set_role":
                return got
            if isinstance(m, Ack | Error):
                got.append(m)

    def close(self) -> None:
        self.pub.close()
        self.sub.close()
        self.ctx.term()


@pytest.fixture
def answers(bus, dialogue: DialogueService) -> Iterator[Answers]:
    a = Answers(bus)
    yield a
    a.close()


def acks(got: list[Message]) -> list[tuple[str, str]]:
    return [(m.command, m.request_id) for m in got if isinstance(m, Ack)]


def test_every_applied_command_is_acknowledged_with_its_request_id_as_sent(
        bus, dialogue: DialogueService, audio_beats: Callable[[], None], answers: Answers) -> None:
    audio_beats()  # the say requests stay pending (no audio service plays them): something to interrupt and feed
    assert acks(answers.after(Say(agent="ada", request_id="say-1", audio_path="/a.wav"), "p1")) == [("say", "say-1")]
    assert acks(answers.after(Say(agent="ada", request_id="say-2", streamed=True, sample_rate=16000), "p2")) == [
        ("say", "say-2")]
    commands: list[Callable[[str], Message]] = [
        lambda rid: SetRole(agent="ada", role="talking", request_id=rid),
        lambda rid: SetEmotion(agent="ada", name="happy", request_id=rid),
        lambda rid: MoveHead(agent="ada", turn=0.2, request_id=rid),
        lambda rid: SetEyes(agent="ada", mode="saccade", request_id=rid),
        lambda rid: SetGazeTarget(agent="ada", yaw_deg=5.0, request_id=rid),
        lambda rid: UserSpeech(agent="ada", speaking=False, request_id=rid),
        lambda rid: CreateAgent(agent="v1", request_id=rid),
        lambda rid: RemoveAgent(agent="v1", request_id=rid),
    ]
    covered = {"say", "speech_chunk", "interrupt"}
    for k, make in enumerate(commands * 2):
        rid = f"own-{k}" if k >= len(commands) else ""  # first without a request id, then with one
        sent = make(rid)
        covered.add(sent.TYPE)
        assert acks(answers.after(sent, f"m{k}")) == [(sent.TYPE, rid)], (sent.TYPE, rid)
    assert covered == COMMANDS, "a command type this test does not cover"
    # interrupt: its request_id names the say it stops, and the ack carries it; empty: all of them
    assert acks(answers.after(Interrupt(agent="ada", request_id="say-1"), "i1")) == [("interrupt", "say-1")]
    assert acks(answers.after(Interrupt(agent="ada"), "i2")) == [("interrupt", "")]
    # a speech_chunk is part of its say: the speech state counts it, nothing acknowledges it
    assert answers.after(SpeechChunk(agent="ada", request_id="say-2", index=0, pcm=b"\0\0"), "c1") == []
    assert dialogue.agents["ada"].pending["say-2"].next_chunk == 1
    # the same command again, its ack lost (say): acknowledged again, not applied twice (no "exists")
    for k in range(2):
        assert acks(answers.after(CreateAgent(agent="v2", request_id="c-1"), f"d{k}")) == [("create_agent", "c-1")]
    assert list(dialogue.created) == ["v2"]
    # a refused command is answered by an error with its request id, never an ack: a say without an id, a
    # configured agent removed, an unknown one commanded
    for k, refused in enumerate([Say(agent="ada", request_id="", audio_path="/a.wav"),
                                 RemoveAgent(agent="ada", request_id="x-1"),
                                 SetRole(agent="nobody", role="talking", request_id="x-2")]):
        got = answers.after(refused, f"e{k}")
        rid = getattr(refused, "request_id", "")
        assert acks(got) == [] and [(m.kind, m.request_id) for m in got] == [("rejected", rid)], got


def test_a_say_with_a_file_and_a_sample_rate_is_refused_and_changes_nothing(bus, dialogue: DialogueService) -> None:
    with AgentClient(bus, agent="ada") as client:
        ctx = zmq.Context()
        play = Subscriber(ctx, bus, ["play.ada."])
        try:
            play.wait_ready()
            client.send(Say(agent="ada", request_id="f-1", audio_path="/a.wav", sample_rate=16000))
            err = client.wait_for(lambda m: isinstance(m, Error | Ack), 5.0)
            assert isinstance(err, Error), err
            assert (err.kind, err.request_id, err.topic) == ("rejected", "f-1", "cmd.ada.say")
            assert "sample_rate" in err.reason and "audio_path" in err.reason
            # nothing applied: no request went to the audio service, none is pending, the id is still free
            assert "f-1" not in dialogue.agents["ada"].pending
            ack = client.wait_applied(client.send(Say(agent="ada", request_id="f-1", audio_path="/a.wav")))
            assert ack.request_id == "f-1"
            request = play.recv(5.0)
            assert request is not None and isinstance(request.message, Say) and request.message.sample_rate == 0
        finally:
            play.close()
            ctx.term()
