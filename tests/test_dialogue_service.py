"""The dialogue service on a real broker: validation, state, say lifecycle, speech-driven role."""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from contextlib import contextmanager

import pytest
import zmq

from eca.protocol.bus import BusTimeout, Publisher, Subscriber
from eca.protocol.client import AgentClient, CommandRejected
from eca.protocol.messages import (
    ALL_AGENTS,
    MAX_PENDING_SAYS,
    TERMINAL_SPEECH_EVENTS,
    EmotionState,
    Error,
    Heartbeat,
    Interrupt,
    PlaybackState,
    RoleState,
    Say,
    SpeechChunk,
    SpeechFailed,
    SpeechFinished,
    SpeechInterrupted,
    SpeechStarted,
    SpeechState,
)
from eca.services.processes.dialogue import DialogueService
from eca.services.processes.runtime import wait_until
from tests.support.bus import BrokerThread, ServiceThread, private_bus_config


@pytest.fixture
def dialogue(bus) -> Iterator[DialogueService]:
    service = DialogueService(bus)
    with ServiceThread(service):
        yield service


@contextmanager
def dialogue_known_to(audio: FakeAudio, bus) -> Iterator[DialogueService]:
    """A dialogue service that has had the (fake) audio service's heartbeat."""
    with ServiceThread(DialogueService(bus)) as thread:
        audio.introduce(thread.service)
        yield thread.service


@pytest.fixture
def audio(bus) -> Iterator[FakeAudio]:
    fake = FakeAudio(bus)
    yield fake
    fake.close()


@pytest.fixture
def client(bus, dialogue) -> Iterator[AgentClient]:
    with AgentClient(bus, agent="ada") as c:
        yield c


class FakeAudio:
    """Plays the audio service's part on the bus: sees `play.` requests, reports on `audio.`."""

    def __init__(self, config, started_ns: int = 1) -> None:
        self.ctx = zmq.Context()
        self.pub = Publisher(self.ctx, config, "audio")
        self.sub = Subscriber(self.ctx, config, ["play.ada."])
        self.pub.wait_ready()
        self.sub.wait_ready()
        self.started_ns = started_ns

    def beat(self) -> None:
        self.pub.publish(Heartbeat(agent=ALL_AGENTS, service="audio", pid=os.getpid(), started_ns=self.started_ns))

    def next_request(self, timeout_s: float = 5.0):
        got = self.sub.recv(timeout_s)
        assert got is not None and got.message is not None, "no request reached the audio side"
        return got.message

    def report(self, msg) -> None:
        self.pub.publish(msg, category="audio")

    def introduce(self, dialogue: DialogueService) -> None:
        """A heartbeat, and wait until the dialogue service knows this instance (requests it then
        accepts record it: the beat and a say come from different publishers, in either order)."""
        self.beat()
        assert wait_until(lambda: dialogue.audio_started_ns == self.started_ns, 5.0)

    def hold(self, *request_ids: str) -> None:
        """What the audio service publishes whenever the requests it holds change."""
        self.pub.publish(PlaybackState(agent="ada", request_ids=list(request_ids), started_ns=self.started_ns))

    def start_speech(self, client: AgentClient) -> str:
        """A say request the audio side takes up and starts; returns once the agent is talking."""
        self.beat()
        rid = client.say(audio_path="/a.wav")
        self.next_request()
        self.report(SpeechStarted(agent="ada", request_id=rid))
        client.expect_state(RoleState, lambda m: m.role == "talking")
        return rid

    def close(self) -> None:
        self.pub.close()
        self.sub.close()
        self.ctx.term()


def test_initial_state_is_published_and_cached(client: AgentClient) -> None:
    role = client.expect_state(RoleState)
    assert role.role == "listening" and role.source == "dialogue"
    assert client.expect_state(EmotionState).name == "natural"


def test_emotion_is_validated_and_published(client: AgentClient) -> None:
    client.set_emotion("Half_Angry", intensity=0.4, transition_s=1.0)
    state = client.expect_state(EmotionState, lambda m: m.intensity == 0.4)
    assert state.name == "half-angry" and state.transition_s == 1.0


def test_unknown_emotion_is_an_error_listing_the_known_ones_and_changes_nothing(client: AgentClient) -> None:
    client.set_emotion("happy", 0.3)
    client.expect_state(EmotionState, lambda m: m.name == "happy")
    client.set_emotion("grumpy", request_id="r1")
    with pytest.raises(CommandRejected) as info:
        client.expect_state(EmotionState, lambda m: m.name == "grumpy", request_id="r1")
    assert "grumpy" in str(info.value) and "frightened" in str(info.value)
    client.set_role("talking")
    client.expect_state(RoleState, lambda m: m.role == "talking")
    with AgentClient(client.config, agent="ada") as late:  # the cache still says happy
        assert late.expect_state(EmotionState).name == "happy"


def test_unknown_agent_is_rejected(bus, dialogue) -> None:
    with AgentClient(bus, agent="bob") as bob:
        bob.set_role("talking")
        err = bob.wait_for(lambda m: isinstance(m, Error), 5.0)
        assert "unknown agent 'bob'" in err.reason


def test_garbage_on_a_command_topic_is_reported_and_the_service_keeps_working(client: AgentClient) -> None:
    client.pub.send_raw(b"cmd.ada.set_emotion", b"\xc1\xff not msgpack")
    err = client.wait_for(lambda m: isinstance(m, Error), 5.0)
    assert err.kind == "not_msgpack" and err.topic == "cmd.ada.set_emotion"
    client.set_emotion("surprised")
    assert client.expect_state(EmotionState, lambda m: m.name == "surprised").name == "surprised"


def test_say_lifecycle_is_republished_once_and_role_follows_speech(bus, client: AgentClient) -> None:
    audio = FakeAudio(bus)
    try:
        audio.beat()
        rid = client.say(audio_path="/nonexistent/whatever.wav", text="hi")
        request = audio.next_request()
        assert isinstance(request, Say) and request.request_id == rid and request.source == "dialogue"
        audio.report(SpeechStarted(agent="ada", request_id=rid))
        audio.report(SpeechStarted(agent="ada", request_id=rid))  # a duplicate must not be re-published
        assert client.expect_state(RoleState, lambda m: m.role == "talking").set_by == "speech"
        audio.report(SpeechFinished(agent="ada", request_id=rid, played_s=1.25))
        audio.report(SpeechFinished(agent="ada", request_id=rid, played_s=1.25))
        done = client.wait_for_speech(rid, 5.0)
        assert isinstance(done, SpeechFinished) and done.played_s == 1.25
        client.expect_state(RoleState, lambda m: m.role == "listening" and m.set_by == "speech")
        rid2 = client.say(audio_path="/x.wav")
        audio.next_request()
        audio.report(SpeechFailed(agent="ada", request_id=rid2, reason="cannot read"))
        client.wait_for_speech(rid2, 5.0)
        terminals = [m for m in client._inbox if isinstance(m, SpeechFinished | SpeechFailed)]
        assert terminals == []  # the repeated finished event was not re-published
    finally:
        audio.close()


def test_manager_role_command_wins_over_speech(bus, client: AgentClient) -> None:
    audio = FakeAudio(bus)
    try:
        rid = audio.start_speech(client)
        client.set_role("silence")
        client.expect_state(RoleState, lambda m: m.role == "silence")
        audio.report(SpeechFinished(agent="ada", request_id=rid, played_s=0.5))
        client.wait_for_speech(rid, 5.0)
        client.set_emotion("happy")  # a later marker: any role change would come before it
        client.expect_state(EmotionState, lambda m: m.name == "happy")
        assert client.state["role"].role == "silence"
    finally:
        audio.close()


def test_say_without_any_audio_service_fails_once(bus, client: AgentClient) -> None:
    rid = client.say(audio_path="/a.wav")
    failed = client.wait_for_speech(rid, 10.0)
    assert isinstance(failed, SpeechFailed) and "no audio service" in failed.reason


def test_pending_requests_fail_when_the_audio_service_restarts(bus, client: AgentClient) -> None:
    audio = FakeAudio(bus, started_ns=1)
    try:
        audio.beat()
        rid = client.say(audio_path="/a.wav")
        audio.next_request()
        audio.report(SpeechStarted(agent="ada", request_id=rid))
        audio.started_ns = 2  # a new instance of the audio service
        audio.beat()
        failed = client.wait_for_speech(rid, 5.0)
        assert isinstance(failed, SpeechFailed) and "restarted" in failed.reason
        audio.report(SpeechFinished(agent="ada", request_id=rid, played_s=3.0))  # too late: ignored
        client.set_emotion("annoyed")
        client.expect_state(EmotionState, lambda m: m.name == "annoyed")
        assert not any(isinstance(m, SpeechFinished) for m in client._inbox)
    finally:
        audio.close()


def test_bad_say_requests_are_rejected(client: AgentClient) -> None:
    client.send(Say(agent="ada", request_id="both", audio_path="/a.wav", pcm=b"\0\0", sample_rate=16000))
    err = client.wait_for(lambda m: isinstance(m, Error), 5.0)
    assert "not several" in err.reason and err.request_id == "both"
    client.send(Say(agent="ada", request_id="nothing", text="   "))
    err = client.wait_for(lambda m: isinstance(m, Error), 5.0)
    assert "needs audio" in err.reason and err.request_id == "nothing"
    client.send(Say(agent="ada", request_id="odd", pcm=b"\0\0\0", sample_rate=16000))
    assert "even number" in client.wait_for(lambda m: isinstance(m, Error), 5.0).reason
    client.send(SpeechChunk(agent="ada", request_id="nobody", index=0, pcm=b""))
    assert "no streamed say request" in client.wait_for(lambda m: isinstance(m, Error), 5.0).reason
    client.send(Interrupt(agent="ada", request_id="nobody"))
    assert "no pending say request" in client.wait_for(lambda m: isinstance(m, Error), 5.0).reason


def test_a_say_is_addressed_to_other_agents_or_the_user_and_the_talking_role_says_to_whom() -> None:
    with private_bus_config(agents=["ada", "bob", "cy"]) as config, BrokerThread(config), \
            ServiceThread(DialogueService(config)), AgentClient(config, agent="ada") as client:
        audio = FakeAudio(config)
        try:
            for to, wrong in ((["ada"], "'ada'"), (["bob", "zed"], "'zed'")):
                rid = f"to-{wrong}"
                client.send(Say(agent="ada", request_id=rid, text="hello", to=to))
                err = client.wait_for(lambda m, rid=rid: isinstance(m, Error) and m.request_id == rid, 5.0)
                assert wrong in err.reason and "'bob', 'cy'" not in err.reason and "bob, cy" in err.reason
            audio.beat()
            rid = client.say(audio_path="/a.wav", to=["bob", "user"])
            audio.next_request()
            audio.report(SpeechStarted(agent="ada", request_id=rid))
            role = client.expect_state(RoleState, lambda m: m.role == "talking")
            assert role.addressees == ["bob", "user"] and role.set_by == "speech"
        finally:
            audio.close()


def test_barge_in_interrupts_and_makes_the_agent_listen(bus, client: AgentClient) -> None:
    audio = FakeAudio(bus)
    try:
        audio.start_speech(client)
        client.user_speaking(True)
        stop = audio.next_request()
        assert isinstance(stop, Interrupt) and "user" in stop.reason
        role = client.expect_state(RoleState, lambda m: m.role == "listening")
        assert role.speaker == "user"
    finally:
        audio.close()


def test_a_say_sent_before_the_audio_service_came_up_still_ends_once() -> None:
    # The audio service subscribed after the request went out, so it never saw it: the request must
    # not stay pending for ever just because that service is alive now.
    with private_bus_config(extra="[dialogue]\nsay_start_timeout_s = 0.4\n") as config, BrokerThread(config):
        service = DialogueService(config)
        with ServiceThread(service), AgentClient(config, agent="ada") as client:
            rid = client.say(audio_path="/a.wav")
            assert wait_until(lambda: rid in service.agents["ada"].pending, 5.0)
            audio = FakeAudio(config)
            try:
                ended = None
                deadline = time.monotonic() + 5.0
                while ended is None and time.monotonic() < deadline:
                    audio.beat()  # alive all along, so it is not the "stopped answering" path
                    try:
                        ended = client.wait_for_speech(rid, 0.1)
                    except BusTimeout:
                        pass
                assert isinstance(ended, SpeechFailed) and "no audio service" in ended.reason
                stop = audio.next_request()  # the audio side is told to drop it, should it have it after all
                assert isinstance(stop, Interrupt) and stop.request_id == rid
                client.wait_applied(client.set_emotion("annoyed"))  # a round trip after whatever else came
                assert not any(isinstance(m, TERMINAL_SPEECH_EVENTS) and m.request_id == rid
                               for m in client._inbox)  # exactly one terminal event
            finally:
                audio.close()


def test_eca_send_reports_the_state_its_command_caused_not_a_cached_one(
        bus, dialogue, capsys: pytest.CaptureFixture[str]) -> None:
    from eca.services.tools.cli import main

    where = ["send", "--config", str(bus.config_path), "--instance", bus.instance]
    assert main([*where, "emotion", "gleeful"]) == 1  # the cached "natural 1.0" is no answer to it
    assert "unknown emotion 'gleeful'" in capsys.readouterr().err
    assert main([*where, "emotion", "Half_Angry"]) == 0
    assert "name='half-angry'" in capsys.readouterr().out
    assert main([*where, "gaze", "--pitch", "10"]) == 0
    assert "pitch_deg=10.0" in capsys.readouterr().out


def test_garbage_under_a_non_ascii_agent_is_reported_under_star_and_the_service_lives(
        bus, client: AgentClient) -> None:
    ctx = zmq.Context()
    raw = Publisher(ctx, bus, "fuzz")
    errors = Subscriber(ctx, bus, ["error.*."])
    try:
        raw.wait_ready()
        errors.wait_ready()
        raw.send_raw("cmd.é.say".encode(), b"\xff\xff")  # 'é' is alphanumeric, but no agent id
        got = errors.recv(5.0)
        assert got is not None and isinstance(got.message, Error), got
        assert got.message.kind == "not_msgpack" and got.message.topic == "cmd.é.say"
        client.set_emotion("surprised")
        assert client.expect_state(EmotionState, lambda m: m.name == "surprised").name == "surprised"
    finally:
        raw.close()
        errors.close()
        ctx.term()


def test_an_agent_id_with_a_trailing_newline_is_not_an_agent_id() -> None:
    from eca.protocol.codec import ProtocolError, encode
    from eca.protocol.messages import SetEmotion

    with pytest.raises(ProtocolError, match="agent id"):
        encode(SetEmotion(agent="ada\n", name="happy"))


def test_a_restarted_dialogue_service_still_ends_the_speech_its_predecessor_started(bus) -> None:
    audio = FakeAudio(bus)
    try:
        with AgentClient(bus, agent="ada") as client:
            with ServiceThread(DialogueService(bus)):
                audio.beat()
                rid = client.say(audio_path="/a.wav")
                audio.next_request()
                audio.report(SpeechStarted(agent="ada", request_id=rid))
                client.expect_state(RoleState, lambda m: m.role == "talking" and m.set_by == "speech")
            with ServiceThread(DialogueService(bus)) as second:  # crashed and restarted mid-utterance
                assert second.service.agents["ada"].role.role == "talking"  # adopted from the cache
                audio.beat()
                audio.report(SpeechFinished(agent="ada", request_id=rid, played_s=2.0))
                done = client.wait_for_speech(rid, 5.0)
                assert isinstance(done, SpeechFinished) and done.played_s == 2.0
                client.expect_state(RoleState, lambda m: m.role == "listening" and m.set_by == "speech")
                client.user_speaking(True)  # barge-in reaches the audio side whatever this instance knows
                stop = audio.next_request()
                assert isinstance(stop, Interrupt) and stop.request_id == ""
    finally:
        audio.close()


def test_the_speech_state_lists_the_pending_requests_until_they_end(
    dialogue, client: AgentClient, audio: FakeAudio) -> None:
    assert client.expect_state(SpeechState).request_ids == []
    audio.introduce(dialogue)
    rid = client.say(audio_path="/a.wav")
    audio.next_request()
    listed = client.expect_state(SpeechState, lambda m: m.request_ids == [rid])
    assert listed.started == [False] and listed.audio_started_ns == [audio.started_ns]
    audio.report(SpeechStarted(agent="ada", request_id=rid))
    client.expect_state(SpeechState, lambda m: m.started == [True])
    audio.report(SpeechFinished(agent="ada", request_id=rid, played_s=1.0))
    client.expect_state(SpeechState, lambda m: m.request_ids == [])


def test_a_restarted_dialogue_service_takes_over_its_predecessors_requests(bus, audio: FakeAudio) -> None:
    with AgentClient(bus, agent="ada") as client:
        with dialogue_known_to(audio, bus):
            client.send(Say(agent="ada", request_id="tts", streamed=True, sample_rate=16000))
            audio.next_request()
            client.send(SpeechChunk(agent="ada", request_id="tts", index=0, pcm=b"\0\0"))
            audio.next_request()
            client.expect_state(SpeechState, lambda m: m.next_chunk == [1])
        with ServiceThread(DialogueService(bus)) as second:
            assert list(second.service.agents["ada"].pending) == ["tts"]
            audio.beat()
            client.send(SpeechChunk(agent="ada", request_id="tts", index=1, pcm=b"\0\0", last=True))
            chunk = audio.next_request()
            assert isinstance(chunk, SpeechChunk) and (chunk.index, chunk.last) == (1, True)
            client.interrupt("tts")  # by id: the new instance knows the request
            stop = audio.next_request()
            assert isinstance(stop, Interrupt) and stop.request_id == "tts"
            audio.report(SpeechInterrupted(agent="ada", request_id="tts", played_s=0.1, reason="command"))
            assert isinstance(client.wait_for_speech("tts", 5.0), SpeechInterrupted)
            client.expect_state(SpeechState, lambda m: m.request_ids == [])


def test_a_request_that_ended_while_no_dialogue_service_ran_fails_once(bus, audio: FakeAudio) -> None:
    with AgentClient(bus, agent="ada") as client:
        with dialogue_known_to(audio, bus):
            rid = client.say(audio_path="/a.wav")
            audio.next_request()
            audio.hold(rid)
            audio.report(SpeechStarted(agent="ada", request_id=rid))
            client.expect_state(RoleState, lambda m: m.role == "talking")
        # the speech ends while no dialogue service listens: its terminal event is lost
        audio.report(SpeechFinished(agent="ada", request_id=rid, played_s=1.0))
        audio.hold()
        client.expect_state(PlaybackState, lambda m: m.request_ids == [])  # the cache has it now
        with ServiceThread(DialogueService(bus)) as second:
            failed = client.wait_for_speech(rid, 5.0)
            assert isinstance(failed, SpeechFailed) and "while the dialogue service was restarting" in failed.reason
            client.expect_state(RoleState, lambda m: m.role == "listening" and m.set_by == "speech")
            assert second.service.agents["ada"].pending == {}
            client.set_emotion("annoyed")  # a later marker
            client.expect_state(EmotionState, lambda m: m.name == "annoyed")
            assert not any(isinstance(m, TERMINAL_SPEECH_EVENTS) and m.request_id == rid for m in client._inbox)


def test_requests_for_an_audio_instance_gone_fail_after_a_dialogue_restart(bus, audio: FakeAudio) -> None:
    with AgentClient(bus, agent="ada") as client:
        with dialogue_known_to(audio, bus):
            rid = client.say(audio_path="/a.wav")
            audio.next_request()
            client.expect_state(SpeechState, lambda m: m.request_ids == [rid])
        audio.started_ns = 2  # both restarted: the new audio instance never saw the request
        with ServiceThread(DialogueService(bus)):
            audio.beat()
            failed = client.wait_for_speech(rid, 5.0)
            assert isinstance(failed, SpeechFailed) and "restarted" in failed.reason


def test_a_say_beyond_the_pending_limit_is_rejected(dialogue, client: AgentClient, audio: FakeAudio) -> None:
    audio.introduce(dialogue)
    for k in range(MAX_PENDING_SAYS):
        client.send(Say(agent="ada", request_id=f"r{k}", audio_path="/a.wav"))
    client.expect_state(SpeechState, lambda m: len(m.request_ids) == MAX_PENDING_SAYS)
    client.send(Say(agent="ada", request_id="one-too-many", audio_path="/a.wav"))
    err = client.wait_for(lambda m: isinstance(m, Error), 5.0)
    assert err.request_id == "one-too-many" and f"already has {MAX_PENDING_SAYS}" in err.reason
