"""The agent's voice as a stream: every block the output takes that sounds, as the player reports it (fake sink,
virtual clock: exactly the samples played, in order, on the sink's DAC times, silence the gaps that
`first_sample` leaves) and as the audio service publishes it on `stream.<agent>.voice` (null sink paced by the
monotonic clock, a subscriber that reassembles the track)."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest
from scipy import stats

from eca.agent.clock import VirtualClock
from eca.agent.config import ConfigError, load_toml
from eca.protocol.bus import Subscriber
from eca.protocol.client import AgentClient
from eca.protocol.messages import ClockAnchor, Message, SpeechFinished, SpeechInterrupted, VoiceBlock
from eca.services.processes.audio import (
    FakeSink,
    Player,
    PlayerFinished,
    PlayerInterrupted,
    PlayerStarted,
    PlayerVoiceBlock,
)
from eca.services.processes.audio.config import AudioConfig
from eca.services.processes.audio.player import pcm16_bytes
from eca.services.processes.audio.resample import resample
from eca.services.processes.audio.service import AudioService
from eca.services.processes.audio.sinks import NullSink
from eca.services.processes.dialogue import DialogueService
from tests.support.bus import BrokerThread, ServiceThread, private_bus_config

SR = 48_000
BLOCK = 480


class Rig:
    def __init__(self, sr: int = SR, block: int = BLOCK, latency_s: float = 0.0, publish_voice: bool = True) -> None:
        self.clock = VirtualClock(1_000_000_000)
        self.sink = FakeSink(self.clock, sr, block, latency_s=latency_s)
        self.events: list[object] = []
        self.player = Player(self.sink, self.events.append, agent_id="ada", clock=self.clock,
                             publish_voice=publish_voice).start()

    def voice(self) -> list[PlayerVoiceBlock]:
        return [e for e in self.events if isinstance(e, PlayerVoiceBlock)]

    def run_until_idle(self, max_blocks: int = 10_000) -> None:
        for _ in range(max_blocks):
            if self.player.idle:
                return
            self.sink.advance(1)
        raise AssertionError("player never became idle")


def noise(seconds: float, sr: int = SR, seed: int = 0) -> np.ndarray:
    return (0.3 * np.random.default_rng(seed).uniform(-1, 1, round(seconds * sr))).astype(np.float32)


def track_of(blocks: list[PlayerVoiceBlock] | list[VoiceBlock], samples: int) -> bytes:
    """The track the blocks make: each at its `first_sample`, silence where none is."""
    out = bytearray(2 * samples)
    for b in blocks:
        end = min(samples, b.first_sample + len(b.pcm) // 2)
        out[2 * b.first_sample : 2 * end] = b.pcm[: 2 * (end - b.first_sample)]
    return bytes(out)


def test_pcm16_bytes_scales_rounds_and_clips() -> None:
    x = np.array([0.5, -0.5, 1.0, -1.0, 0.0, 1 / 32768, 0.49 / 32768, 2.0, -2.0], np.float32)
    assert np.frombuffer(pcm16_bytes(x), "<i2").tolist() == [16384, -16384, 32767, -32768, 0, 1, 0, 32767, -32768]


@pytest.mark.parametrize(("sr", "block", "latency_s"), [(48_000, 480, 0.0237), (44_100, 512, 0.0)])
def test_voice_blocks_are_the_sink_output_in_order_on_its_dac_times(sr: int, block: int, latency_s: float) -> None:
    rig = Rig(sr, block, latency_s)
    a, b, c = noise(0.1234, sr), noise(0.0777, sr, seed=1), noise(0.05, sr, seed=2)
    rig.player.say_pcm("a", a, sr)
    rig.player.say_pcm("b", b, sr)  # back to back: it starts inside a block of a
    rig.sink.advance(40)  # a, b, then silence
    rig.player.say_stream("c", sr)
    rig.sink.advance(5)  # c waits in silence for its chunk
    rig.player.feed("c", c, last=True)
    rig.run_until_idle()
    rig.sink.advance(3)

    out = rig.sink.output
    c_start = 45 * block
    assert np.array_equal(out[c_start : c_start + len(c)], c)  # where c plays, as the layout below assumes
    spans = {"a": (0, len(a)), "b": (len(a), len(a) + len(b)), "c": (c_start, c_start + len(c))}

    voice = rig.voice()
    played = rig.sink.blocks_played
    sounding = [k for k in range(played) if out[k * block : (k + 1) * block].any()]
    assert 0 < len(sounding) < played  # the layout has silence between b and c, and after c
    assert [v.first_sample // block for v in voice] == sounding  # every block that sounds, once, in order
    assert track_of(voice, played * block) == pcm16_bytes(out)  # what the sink played, silence in the gaps
    for v in voice:
        k = v.first_sample // block
        assert v.agent == "ada" and v.sample_rate == sr and len(v.pcm) == 2 * block
        assert v.first_sample == k * block
        assert v.dac_time_ns == rig.sink.block_time_ns(k) + rig.sink.latency_ns
        start = v.first_sample
        expected_uid = next((uid for uid, (lo, hi) in spans.items() if lo <= start < hi), "")
        assert v.request_id == expected_uid, k
    steps = np.diff([v.dac_time_ns for v in voice if v.request_id == "a"])
    exact = block * 1e9 / sr
    assert np.all(np.abs(steps - exact) < 1.0)  # the block length, to the ns rounding of the stamps
    assert next(v for v in voice if v.first_sample == len(a) // block * block).request_id == "a"  # where b begins
    for uid in ("a", "c"):  # those that start on a block boundary: their first block is their start
        started = next(e for e in rig.events if isinstance(e, PlayerStarted) and e.request_id == uid)
        first = next(v for v in voice if v.request_id == uid)
        assert rig.events.index(started) < rig.events.index(first)
        assert started.dac_time_ns == first.dac_time_ns


def test_int16_pcm_comes_back_bit_exact() -> None:
    rig = Rig()
    pcm = (noise(0.2) * 32767).astype(np.int16)
    pcm[:4] = [32767, -32768, 1, -1]
    rig.player.say_pcm("i", pcm, SR)
    rig.run_until_idle()
    track = b"".join(v.pcm for v in rig.voice())
    assert track[: 2 * len(pcm)] == pcm.astype("<i2").tobytes()


def test_after_a_barge_in_no_block_comes_from_the_block_where_the_voice_stopped() -> None:
    rig = Rig()
    x = noise(2.0)
    rig.player.say_pcm("long", x, SR)
    rig.player.say_pcm("queued", noise(1.0, seed=1), SR)
    rig.sink.advance(37)
    assert rig.player.interrupt() == ["long", "queued"]
    rig.sink.advance(5)
    y = noise(0.05, seed=2)
    rig.player.say_pcm("after", y, SR)
    rig.run_until_idle()
    voice = rig.voice()
    assert [v.request_id for v in voice] == ["long"] * 37 + ["after"] * 5
    assert b"".join(v.pcm for v in voice[:37]) == pcm16_bytes(x[: 37 * BLOCK])
    assert voice[37].first_sample == 42 * BLOCK  # the five silent blocks: a gap, no block
    assert b"".join(v.pcm for v in voice[37:])[: 2 * len(y)] == pcm16_bytes(y)
    (cut,) = [e for e in rig.events if isinstance(e, PlayerInterrupted) and e.request_id == "long"]
    assert cut.dac_time_ns == rig.sink.block_time_ns(37)  # the voice stops where the gap begins


def test_interrupting_one_utterance_goes_straight_to_the_next_in_the_blocks() -> None:
    rig = Rig()
    y = noise(0.5, seed=3)
    rig.player.say_pcm("a", noise(1.0), SR)
    rig.player.say_pcm("b", y, SR)
    rig.sink.advance(10)
    assert rig.player.interrupt("a") == ["a"]
    rig.sink.advance(3)
    voice = rig.voice()
    assert [v.request_id for v in voice] == ["a"] * 10 + ["b"] * 3
    assert b"".join(v.pcm for v in voice[10:]) == pcm16_bytes(y[: 3 * BLOCK])


def test_without_publish_voice_no_block_is_reported() -> None:
    rig = Rig(publish_voice=False)
    rig.player.say_pcm("u", noise(0.1), SR)
    rig.run_until_idle()
    rig.sink.advance(5)
    assert rig.voice() == []
    assert [type(e).__name__ for e in rig.events if isinstance(e, PlayerStarted | PlayerFinished)] == \
        ["PlayerStarted", "PlayerFinished"]


def test_publish_voice_is_configured_in_the_output_table() -> None:
    assert AudioConfig.load().publish_voice is True  # the shipped setting
    data = load_toml("audio")
    del data["output"]
    assert AudioConfig.from_dict(data).publish_voice is True  # the default
    data["output"] = {"publish_voice": False}
    assert AudioConfig.from_dict(data).publish_voice is False
    data["output"] = {"publish_voice": "yes"}
    with pytest.raises(ConfigError, match="publish_voice"):
        AudioConfig.from_dict(data)
    data["output"] = {"publish_voice": True}
    data["device"]["block_frames"] = 40_000  # more than one voice message can carry
    with pytest.raises(ConfigError, match="block_frames"):
        AudioConfig.from_dict(data)
    data["output"] = {"publish_voice": False}
    assert AudioConfig.from_dict(data).block_frames == 40_000


# --- on the bus: the audio service with a null sink, a subscriber reassembling the track -------------------

RATE = 16_000  # the say requests' rate: the service converts them to the device rate


def tone(seconds: float) -> bytes:
    t = np.arange(round(seconds * RATE)) / RATE
    wave = 0.5 * np.sin(2 * np.pi * 220 * t) * (1 + 0.5 * np.sin(2 * np.pi * 3 * t))
    return (np.clip(wave, -1, 1) * 32767).astype("<i2").tobytes()


def at_device_rate(pcm: bytes) -> bytes:
    """What the player makes of a say request's PCM (the same conversion and resampler), as int16 bytes."""
    x = np.frombuffer(pcm, "<i2").astype(np.float32) / 32768.0
    return pcm16_bytes(np.clip(resample(x, RATE, SR), -1.0, 1.0).astype(np.float32))


class VoiceListener:
    """A subscriber of the agent's voice (and, on the same socket, its clock anchors, which the audio service
    publishes in order with the voice)."""

    def __init__(self, sub: Subscriber) -> None:
        self.sub = sub
        self.blocks: list[VoiceBlock] = []
        self.received_ns: list[int] = []  # when each block arrived
        self.others: list[Message] = []

    def until(self, done: Callable[[list[VoiceBlock]], bool], timeout_s: float) -> list[VoiceBlock]:
        """Receive until `done(blocks so far)`; returns all blocks received."""
        deadline = time.monotonic() + timeout_s
        while not done(self.blocks):
            left = deadline - time.monotonic()
            assert left > 0, f"{len(self.blocks)} voice blocks, the condition not met within {timeout_s} s"
            got = self.sub.recv(left)
            if got is None or got.message is None:
                continue
            if isinstance(got.message, VoiceBlock):
                self.blocks.append(got.message)
                self.received_ns.append(time.monotonic_ns())
            else:
                self.others.append(got.message)
        return self.blocks


def check_one_track(blocks: list[VoiceBlock]) -> None:
    """Consecutive blocks (the voice of one say) continue each other: first sample and DAC time advance by the
    block length, and each sounds."""
    for prev, block in zip(blocks, blocks[1:], strict=False):
        n = len(prev.pcm) // 2
        assert block.first_sample == prev.first_sample + n, "a dropped or repeated block"
        assert block.dac_time_ns - prev.dac_time_ns == n * 1_000_000_000 // SR
        assert block.sample_rate == SR and block.agent == "ada" and block.source == "audio"
    assert all(any(b.pcm) for b in blocks)


def said(rid: str) -> Callable[[list[VoiceBlock]], bool]:
    return lambda blocks: any(b.request_id == rid for b in blocks)


@pytest.fixture
def bus(request: pytest.FixtureRequest) -> Iterator[tuple[AgentClient, VoiceListener]]:
    publish_voice = getattr(request, "param", True)
    with private_bus_config() as config, BrokerThread(config):
        audio = AudioService(config, sink_factory=lambda: NullSink(SR, BLOCK))
        audio.audio_config = dataclasses.replace(audio.audio_config, publish_voice=publish_voice)
        with ServiceThread(DialogueService(config)), ServiceThread(audio):
            with AgentClient(config, agent="ada") as client:
                sub = Subscriber(client.ctx, config, ["stream.ada.voice", "stream.ada.clock_anchor"])
                try:
                    sub.wait_ready(5.0)
                    yield client, VoiceListener(sub)
                finally:
                    sub.close()


def test_the_service_publishes_the_voice_at_the_block_rate_and_a_say_sample_exact(bus) -> None:
    client, voice = bus
    # the output has been taking silent blocks since the service started: none of them comes
    pcm = tone(0.6123)
    expected = at_device_rate(pcm)
    n_blocks = -(-len(expected) // (2 * BLOCK))
    rid = client.say(pcm=pcm, sample_rate=RATE)
    voice.until(lambda blocks: len(blocks) >= n_blocks, 10.0)  # read as they come: their arrival times count
    done = client.wait_for_speech(rid, 10.0)
    marker = client.say(pcm=tone(0.05), sample_rate=RATE)  # after the say and the silence that follows it
    blocks = voice.until(said(marker), 10.0)
    ids = [b.request_id for b in blocks]
    start = ids.index(rid)
    blocks, after = blocks[:ids.index(marker)], blocks[ids.index(marker)]
    assert start == 0, "a block came before the say: silence was sent"
    check_one_track(blocks)
    track = b"".join(b.pcm for b in blocks[start:])
    assert track[: len(expected)] == expected  # every sample of the say, once, in order
    assert not any(track[len(expected):])  # the rest of its last block is silence
    assert ids[start:len(blocks)] == [rid] * n_blocks  # then no block until the next say
    assert after.first_sample >= blocks[-1].first_sample + BLOCK  # any silence between is a gap in the count
    assert isinstance(done, SpeechFinished) and round(done.played_s * SR) == len(expected) // 2
    # The track comes at the block rate (100 per second), live: blocks arrive as fast as their DAC times advance
    # (a Theil-Sen slope, which a stall of a loaded machine does not tilt), shortly after them (a null sink
    # takes each block at its DAC time; the publisher and the service loop pass it on within milliseconds).
    received_s = np.array(voice.received_ns[:n_blocks]) / 1e9
    dac_s = np.array([b.dac_time_ns for b in blocks[:n_blocks]]) / 1e9
    assert stats.theilslopes(received_s, dac_s)[0] == pytest.approx(1.0, abs=0.1)
    assert 0.0 < np.median(received_s - dac_s) < 0.2
    # The clock anchors put the say's samples on the blocks' time line: sample k at the DAC with the block's.
    anchors = [m for m in voice.others if isinstance(m, ClockAnchor) and m.request_id == rid]
    assert anchors and all(
        a.dac_time_ns == blocks[start].dac_time_ns + a.sample_index * 1_000_000_000 // SR for a in anchors)


def test_an_interruption_on_the_bus_leaves_silence_from_where_the_voice_stopped(bus) -> None:
    client, voice = bus
    pcm = tone(5.0)
    rid = client.say(pcm=pcm, sample_rate=RATE)
    voice.until(lambda blocks: sum(b.request_id == rid for b in blocks) >= 30, 10.0)
    client.interrupt(reason="barge-in")
    done = client.wait_for_speech(rid, 5.0)
    assert isinstance(done, SpeechInterrupted)
    marker = client.say(pcm=tone(0.05), sample_rate=RATE)
    blocks = voice.until(said(marker), 10.0)
    blocks = blocks[:[b.request_id for b in blocks].index(marker)]
    check_one_track(blocks)
    played = round(done.played_s * SR)
    assert [b.request_id for b in blocks] == [rid] * (played // BLOCK)  # no block from where the voice stopped
    track = b"".join(b.pcm for b in blocks)
    assert track[: 2 * played] == at_device_rate(pcm)[: 2 * played]


@pytest.mark.parametrize("bus", [False], indirect=True)
def test_with_publish_voice_off_the_service_publishes_no_voice(bus) -> None:
    client, voice = bus
    rid = client.say(pcm=tone(0.3), sample_rate=RATE)
    assert isinstance(client.wait_for_speech(rid, 10.0), SpeechFinished)
    # The anchors come on the voice's socket from the same publisher, in order: voice published before the
    # last of them would be here.
    deadline = time.monotonic() + 5.0
    while not any(isinstance(m, ClockAnchor) and m.sample_index > 0.25 * SR for m in voice.others):
        got = voice.sub.recv(max(0.0, deadline - time.monotonic()))
        assert got is not None, "no clock anchors arrived"
        assert not isinstance(got.message, VoiceBlock)
        voice.others.append(got.message)
