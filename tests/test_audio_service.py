"""The audio service on the bus, behind the dialogue service: lifecycle, clock, mouth, barge-in."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from eca.protocol.client import AgentClient
from eca.protocol.messages import (
    ClockAnchor,
    MouthKeys,
    PlaybackState,
    RoleState,
    SpeechFailed,
    SpeechFinished,
    SpeechInterrupted,
    SpeechStarted,
    SpeechState,
)
from eca.services.processes.audio.service import AudioService
from eca.services.processes.audio.sinks import NullSink
from eca.services.processes.dialogue import DialogueService
from tests.support.bus import BrokerThread, ServiceThread, private_bus_config

RATE = 16_000


def tone(seconds: float, amplitude: float = 0.5) -> bytes:
    t = np.arange(int(seconds * RATE)) / RATE
    wave = amplitude * np.sin(2 * np.pi * 220 * t) * (1 + 0.5 * np.sin(2 * np.pi * 3 * t))
    return (np.clip(wave, -1, 1) * 32767).astype("<i2").tobytes()


@pytest.fixture
def client() -> Iterator[AgentClient]:
    with private_bus_config() as config, BrokerThread(config):
        audio = AudioService(config, sink_factory=lambda: NullSink(48_000, 480))
        with ServiceThread(DialogueService(config)), ServiceThread(audio):
            with AgentClient(config, agent="ada") as c:
                c.sub.subscribe("stream.ada.")
                yield c


def collect_until_terminal(client: AgentClient, rid: str, timeout_s: float = 10.0) -> list:
    seen = []
    while True:
        msg = client.wait_for(lambda m: getattr(m, "request_id", None) == rid or isinstance(m, RoleState),
                              timeout_s)
        seen.append(msg)
        if isinstance(msg, SpeechFinished | SpeechInterrupted | SpeechFailed):
            return seen


def test_inline_pcm_plays_with_anchors_mouth_and_one_terminal_event(client: AgentClient) -> None:
    rid = client.say(pcm=tone(0.6), sample_rate=RATE)
    seen = collect_until_terminal(client, rid)
    kinds = [type(m).__name__ for m in seen]
    assert kinds.count("SpeechStarted") == 1 and kinds[-1] == "SpeechFinished"
    assert kinds.index("MouthKeys") < kinds.index("SpeechStarted")  # known ahead: keys come first
    finished = seen[-1]
    assert finished.played_s == pytest.approx(0.6, abs=0.011)
    anchors = [m for m in seen if isinstance(m, ClockAnchor)]
    assert len(anchors) >= 0.6 * 60 * 0.8  # about 60 Hz or more while playing
    # anchors follow the samples played: sample index and DAC time advance together at the rate
    a, b = anchors[1], anchors[-1]
    rate = (b.sample_index - a.sample_index) / ((b.dac_time_ns - a.dac_time_ns) / 1e9)
    assert rate == pytest.approx(48_000, rel=0.02)
    keys = [m for m in seen if isinstance(m, MouthKeys)]
    opened = max(max(m.weights.get("say_ah", [0.0])) for m in keys)
    assert opened > 0.2  # a loud tone opens the jaw
    roles = [m.role for m in seen if isinstance(m, RoleState) and m.set_by == "speech"]
    assert roles[:1] == ["talking"]


def test_interruption_stops_the_voice_reports_played_time_and_closes_the_mouth(client: AgentClient) -> None:
    rid = client.say(pcm=tone(5.0), sample_rate=RATE)
    client.wait_for(lambda m: isinstance(m, SpeechStarted) and m.request_id == rid, 10.0)
    client.wait_for(lambda m: isinstance(m, ClockAnchor) and m.sample_index > 48_000 * 0.3, 10.0)
    client.interrupt(reason="stop now")
    reset = client.wait_for(lambda m: isinstance(m, MouthKeys) and m.reset, 5.0)
    assert reset.request_id == rid
    done = client.wait_for_speech(rid, 5.0)
    assert isinstance(done, SpeechInterrupted) and done.reason == "stop now"
    assert 0.3 <= done.played_s < 2.0
    client.expect_state(RoleState, lambda m: m.role == "listening" and m.set_by == "speech")
    rid2 = client.say(pcm=tone(0.2), sample_rate=RATE)  # plays normally afterwards
    assert isinstance(client.wait_for_speech(rid2, 10.0), SpeechFinished)


def test_a_missing_file_fails_that_request_only(client: AgentClient) -> None:
    bad = client.say(audio_path="/no/such/file.wav")
    good = client.say(pcm=tone(0.2), sample_rate=RATE)
    failed = client.wait_for_speech(bad, 10.0)
    assert isinstance(failed, SpeechFailed) and "file.wav" in failed.reason
    assert isinstance(client.wait_for_speech(good, 10.0), SpeechFinished)


def test_a_bad_file_fails_with_one_plain_sentence_naming_it(client: AgentClient, tmp_path: Path) -> None:
    empty = tmp_path / "empty.wav"
    empty.touch()
    failed = client.wait_for_speech(client.say(audio_path=str(empty)), 10.0)
    assert isinstance(failed, SpeechFailed)
    assert failed.reason == f"audio file '{empty}' is empty (0 bytes)"


def test_streamed_chunks_play_gap_free(client: AgentClient) -> None:
    pcm = tone(0.5)
    chunks = [pcm[i:i + 3200] for i in range(0, len(pcm), 3200)]
    rid = client.say_stream(chunks, sample_rate=RATE)
    done = client.wait_for_speech(rid, 10.0)
    assert isinstance(done, SpeechFinished) and done.played_s == pytest.approx(0.5, abs=0.011)


def test_barge_in_stops_the_voice_and_makes_the_agent_listen(client: AgentClient) -> None:
    rid = client.say(pcm=tone(5.0), sample_rate=RATE)
    client.wait_for(lambda m: isinstance(m, SpeechStarted), 10.0)
    client.user_speaking(True)
    done = client.wait_for_speech(rid, 5.0)
    assert isinstance(done, SpeechInterrupted) and "user" in done.reason
    role = client.expect_state(RoleState, lambda m: m.role == "listening" and m.speaker == "user")
    assert role.set_by == "command"


def test_an_unexpected_player_error_still_ends_the_request(client: AgentClient, monkeypatch) -> None:
    from eca.services.processes.audio.player import Player

    def broken(self, utterance_id, samples, sample_rate, start_ns=0):  # noqa: ANN001, ARG001
        raise RuntimeError("device went away")

    monkeypatch.setattr(Player, "say_pcm", broken)
    rid = client.say(pcm=tone(0.2), sample_rate=RATE)
    failed = client.wait_for_speech(rid, 10.0)
    assert isinstance(failed, SpeechFailed) and "device went away" in failed.reason


def test_a_request_the_player_refuses_ends_with_speech_failed_and_leaves_no_pending(
    client: AgentClient, monkeypatch
) -> None:
    from eca.services.processes.audio.player import Player

    def refuse(self, utterance_id, samples, sample_rate, start_ns=0):  # noqa: ANN001, ARG001
        raise ValueError(f"utterance {utterance_id!r} is already in flight")

    monkeypatch.setattr(Player, "say_pcm", refuse)
    rid = client.say(pcm=tone(0.2), sample_rate=RATE)
    failed = client.wait_for_speech(rid, 10.0)  # an error answer instead would raise here
    assert isinstance(failed, SpeechFailed) and "refused it" in failed.reason and "in flight" in failed.reason
    listed = client.expect_state(SpeechState, lambda m: rid in m.request_ids)
    client.expect_state(SpeechState, lambda m: m.request_ids == [] and m.seq > listed.seq)  # nothing pending


def test_the_playback_state_holds_a_request_from_acceptance_to_its_end(client: AgentClient) -> None:
    first = client.expect_state(PlaybackState)
    assert first.request_ids == [] and first.source == "audio" and first.started_ns > 0
    rid = client.say(pcm=tone(0.3), sample_rate=RATE)
    held = client.expect_state(PlaybackState, lambda m: m.request_ids == [rid])
    assert held.started_ns == first.started_ns
    assert isinstance(client.wait_for_speech(rid, 10.0), SpeechFinished)
    client.expect_state(PlaybackState, lambda m: m.request_ids == [] and m.seq > held.seq)


def test_the_playback_state_remembers_how_requests_ended_and_is_back_for_a_new_broker() -> None:
    """A terminal event lost with a broker is not lost for good: the audio service's playback state lists
    the latest endings, and it publishes that state again for a broker that restarted."""
    with private_bus_config() as config:
        first_broker = BrokerThread(config).__enter__()
        audio = AudioService(config, sink_factory=lambda: NullSink(48_000, 480))
        with ServiceThread(DialogueService(config)), ServiceThread(audio), AgentClient(config) as client:
            rid = client.say(pcm=tone(0.2), sample_rate=RATE)
            assert isinstance(client.wait_for_speech(rid, 10.0), SpeechFinished)
            playback = client.expect_state(PlaybackState, lambda m: rid in m.ended_ids)
            assert isinstance(playback.ending_of(rid), SpeechFinished)
            assert playback.ending_of(rid).played_s == pytest.approx(0.2, abs=0.011)
            first_broker.__exit__(None, None, None)
            with BrokerThread(config):  # an empty cache, until the owners publish their state again
                found = None
                deadline = time.monotonic() + 10.0
                while time.monotonic() < deadline and not (isinstance(found, PlaybackState) and rid in found.ended_ids):
                    with AgentClient(config) as fresh:
                        found = fresh.state.get("playback")
                assert isinstance(found, PlaybackState) and rid in found.ended_ids, found
