"""The player on a fake sink driven by a virtual clock: lifecycle, anchors, mouth timing, interruption,
failures, files and streamed PCM."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.signal import lfilter

from agent.clock import VirtualClock
from agent.lipsync import MouthTrack, mouth_track
from services.audio import (
    ClockAnchor,
    FakeSink,
    MouthKeys,
    MouthReset,
    Player,
    SpeechFailed,
    SpeechFinished,
    SpeechInterrupted,
    SpeechStarted,
)
from services.audio.events import TERMINAL_EVENTS
from services.audio.resample import resample

SR = 48_000
BLOCK = 480
FRAME_NS = 1_000_000_000 // 60


class Rig:
    def __init__(self, latency_s: float = 0.0) -> None:
        self.clock = VirtualClock(1_000_000_000)
        self.sink = FakeSink(self.clock, SR, BLOCK, latency_s=latency_s)
        self.events: list[object] = []
        self.player = Player(self.sink, self.events.append, agent_id="ada", clock=self.clock).start()

    def of(self, kind: type, uid: str | None = None) -> list:
        return [e for e in self.events if isinstance(e, kind) and (uid is None or e.utterance_id == uid)]

    def lifecycle(self, uid: str) -> list[str]:
        kinds = (SpeechStarted, *TERMINAL_EVENTS)
        return [type(e).__name__ for e in self.events if isinstance(e, kinds) and e.utterance_id == uid]

    def run_until_idle(self, max_blocks: int = 10_000) -> None:
        for _ in range(max_blocks):
            if self.player.idle:
                return
            self.sink.advance(1)
        raise AssertionError("player never became idle")


def noise(seconds: float, sr: int = SR, seed: int = 0, amp: float = 0.3) -> np.ndarray:
    return (amp * np.random.default_rng(seed).uniform(-1, 1, round(seconds * sr))).astype(np.float32)


def tone(seconds: float, sr: int = SR, amp: float = 0.4) -> np.ndarray:
    """An open vowel (F1 750 Hz, F2 1200 Hz) from a pulse train through two resonators."""
    source = np.zeros(round(seconds * sr))
    source[:: round(sr / 120)] = 1.0
    y = lfilter([1.0], [1.0, -0.9], source)
    for fc, bw in ((750.0, 80.0), (1200.0, 100.0)):
        r = np.exp(-np.pi * bw / sr)
        y = lfilter([1.0 - r], [1.0, -2.0 * r * np.cos(2.0 * np.pi * fc / sr), r * r], y)
    return (amp * y / np.max(np.abs(y))).astype(np.float32)


def test_queue_plays_in_order_with_one_terminal_event_each() -> None:
    rig = Rig()
    rig.player.say_pcm("u1", noise(0.25), SR)
    rig.player.say_pcm("u2", noise(0.15, seed=1), SR)
    rig.run_until_idle()
    names = [(type(e).__name__, e.utterance_id) for e in rig.events if not isinstance(e, ClockAnchor)]
    assert names == [
        ("MouthKeys", "u1"), ("MouthKeys", "u2"),
        ("SpeechStarted", "u1"), ("SpeechFinished", "u1"),
        ("SpeechStarted", "u2"), ("SpeechFinished", "u2"),
    ]
    f1, f2 = rig.of(SpeechFinished)
    assert f1.played_s == pytest.approx(0.25) and f2.played_s == pytest.approx(0.15)
    s1, s2 = rig.of(SpeechStarted)
    assert s1.dac_time_ns == 1_000_000_000
    assert s2.dac_time_ns == f1.dac_time_ns == s1.dac_time_ns + 250_000_000  # back to back, gap-free
    assert all(e.agent_id == "ada" for e in rig.events)


def test_output_is_exactly_the_utterances_back_to_back() -> None:
    rig = Rig()
    a, b = noise(0.1234), noise(0.0777, seed=5)
    rig.player.say_pcm("a", a, SR)
    rig.player.say_pcm("b", b, SR)
    rig.run_until_idle()
    out = rig.sink.output
    n = len(a) + len(b)
    assert np.array_equal(out[:n], np.concatenate([a, b]))
    assert not out[n:].any()


def test_clock_anchors_match_the_samples_at_the_dac() -> None:
    rig = Rig(latency_s=0.0237)
    x = noise(0.6, seed=2)
    rig.player.say_pcm("u", x, SR)
    rig.sink.advance(3)  # the utterance starts mid-stream, not at the sink's first block
    rig.run_until_idle()
    rig.sink.advance(5)
    anchors = rig.of(ClockAnchor, "u")
    t0 = rig.sink.block_time_ns(0) + rig.sink.latency_ns  # DAC time of the sink's first output sample
    out = rig.sink.output
    for a in anchors:
        assert a.sample_rate == SR
        position = round((a.dac_time_ns - t0) * SR / 1e9)  # output sample at the DAC at that time
        assert out[position] == x[a.sample_index]
    # >= 60 Hz over the whole time the utterance is at the DAC, and none once it has ended.
    start = rig.of(SpeechStarted, "u")[0].dac_time_ns
    times = np.array([a.dac_time_ns for a in anchors])
    assert np.diff(times).max() <= FRAME_NS
    assert times[0] - start <= FRAME_NS
    assert len(anchors) >= 0.6 * 60


def test_mouth_follows_the_sound_at_the_dac_within_one_video_frame() -> None:
    rig = Rig(latency_s=0.015)
    sr_in = 22_050
    x = np.concatenate([np.zeros(round(0.3037 * sr_in), np.float32), tone(0.5, sr_in),
                        np.zeros(round(0.3 * sr_in), np.float32)])
    rig.player.say_pcm("u", x, sr_in)
    rig.run_until_idle()
    keys = [k for e in rig.of(MouthKeys, "u") for k in e.keys]
    track = MouthTrack(SR, tuple(keys))
    anchor = rig.of(ClockAnchor, "u")[5]

    def mouth_at(t_ns: int) -> dict[str, float]:  # what the renderer does at a frame's display time
        return track.weights_at(anchor.sample_index + (t_ns - anchor.dac_time_ns) * SR / 1e9)

    def dac_ns(sample: int) -> int:
        return anchor.dac_time_ns + round((sample - anchor.sample_index) * 1e9 / SR)

    played = rig.sink.output
    loud = np.flatnonzero(np.abs(played) > 0.05)
    t_on = rig.sink.block_time_ns(0) + rig.sink.latency_ns + round(loud[0] * 1e9 / SR)
    t_off = rig.sink.block_time_ns(0) + rig.sink.latency_ns + round((loud[-1] + 1) * 1e9 / SR)
    assert dac_ns(0) == rig.of(SpeechStarted, "u")[0].dac_time_ns
    steady = mouth_at((t_on + t_off) // 2)["say_ah"]
    assert steady > 0.5
    assert mouth_at(t_on - 2 * FRAME_NS)["say_ah"] == 0.0
    assert mouth_at(t_on + FRAME_NS)["say_ah"] >= 0.5 * steady
    assert mouth_at(t_off + FRAME_NS)["say_ah"] <= 0.15 * steady


def test_interrupt_stops_within_one_block_and_reports_played_time() -> None:
    rig = Rig()
    rig.player.say_pcm("long", noise(2.0), SR)
    rig.player.say_pcm("queued", noise(1.0, seed=1), SR)
    rig.sink.advance(37)
    assert rig.player.interrupt() == ["long", "queued"]
    after = rig.sink.advance(1)
    assert not after.any()  # the very next block is silent
    (cut,) = rig.of(SpeechInterrupted, "long")
    assert cut.played_s == pytest.approx(37 * BLOCK / SR)
    assert cut.dac_time_ns == rig.sink.block_time_ns(37)
    assert rig.of(SpeechInterrupted, "queued")[0].played_s == 0.0
    assert rig.lifecycle("long") == ["SpeechStarted", "SpeechInterrupted"]
    assert rig.lifecycle("queued") == ["SpeechInterrupted"]
    resets = rig.of(MouthReset)
    assert [r.utterance_id for r in resets] == ["long"]
    assert rig.events.index(resets[0]) < rig.events.index(cut)
    rig.sink.advance(3)
    assert not rig.of(ClockAnchor, "long") or rig.of(ClockAnchor, "long")[-1].dac_time_ns < cut.dac_time_ns
    # A new request after that plays normally.
    fresh = noise(0.1, seed=9)
    rig.player.say_pcm("next", fresh, SR)
    start = len(rig.sink.output)
    rig.run_until_idle()
    assert rig.lifecycle("next") == ["SpeechStarted", "SpeechFinished"]
    assert np.array_equal(rig.sink.output[start : start + len(fresh)], fresh)


def test_interrupt_one_utterance_leaves_the_rest_of_the_queue() -> None:
    rig = Rig()
    rig.player.say_pcm("a", noise(0.2), SR)
    rig.player.say_pcm("b", noise(0.2), SR)
    rig.player.say_pcm("c", noise(0.2), SR)
    rig.sink.advance(2)
    assert rig.player.interrupt("b") == ["b"]
    rig.run_until_idle()
    assert rig.lifecycle("a") == ["SpeechStarted", "SpeechFinished"]
    assert rig.lifecycle("b") == ["SpeechInterrupted"]
    assert rig.lifecycle("c") == ["SpeechStarted", "SpeechFinished"]


def test_missing_or_unreadable_file_fails_that_request_only(tmp_path: Path) -> None:
    rig = Rig()
    garbage = tmp_path / "garbage.wav"
    garbage.write_bytes(b"RIFF not really a wave file")
    rig.player.say_pcm("before", noise(0.1), SR)
    rig.player.say_file("missing", tmp_path / "nope.wav")
    rig.player.say_file("garbage", garbage)
    rig.player.say_pcm("nan", np.array([0.0, np.nan], np.float32), SR)
    rig.player.say_pcm("after", noise(0.1), SR)
    rig.run_until_idle()
    assert rig.lifecycle("missing") == ["SpeechFailed"]
    assert "not found" in rig.of(SpeechFailed, "missing")[0].reason
    assert rig.lifecycle("garbage") == ["SpeechFailed"]
    assert rig.lifecycle("nan") == ["SpeechFailed"]
    assert rig.lifecycle("before") == ["SpeechStarted", "SpeechFinished"]
    assert rig.lifecycle("after") == ["SpeechStarted", "SpeechFinished"]


def test_wav_file_is_converted_to_the_device_rate_and_keys_come_first(tmp_path: Path) -> None:
    rig = Rig()
    sr_in = 22_050
    x = tone(0.4, sr_in)
    stereo = np.stack([x, x], axis=1)
    path = tmp_path / "speech.wav"
    sf.write(path, stereo, sr_in, subtype="FLOAT")
    rig.player.say_file("f", path)
    rig.run_until_idle()
    expected = resample(x, sr_in, SR)
    assert np.allclose(rig.sink.output[: len(expected)], expected, atol=1e-6)
    keys_event = rig.of(MouthKeys, "f")
    assert len(keys_event) == 1  # the whole track, computed ahead of playback
    assert rig.events.index(keys_event[0]) < rig.events.index(rig.of(SpeechStarted, "f")[0])
    assert keys_event[0].keys == mouth_track(expected, SR).keys
    assert rig.of(SpeechFinished, "f")[0].played_s == pytest.approx(len(expected) / SR)


def test_streamed_chunks_play_gap_free_with_keys_as_they_arrive() -> None:
    rig = Rig()
    sr_in = 24_000
    x = tone(0.8, sr_in)
    rig.player.say_stream("s", sr_in)
    rng = np.random.default_rng(4)
    pos = 0
    key_events_seen = 0
    while pos < len(x):
        n = int(rng.integers(200, 3000))
        chunk = x[pos : pos + n]
        pos += n
        assert rig.player.feed("s", chunk, last=pos >= len(x))
        rig.sink.advance(1)  # the TTS stays ahead of playback
        key_events_seen += 1
    rig.run_until_idle()
    expected = resample(x, sr_in, SR)
    out = rig.sink.output
    first = int(np.flatnonzero(out)[0])
    assert np.array_equal(out[first : first + len(expected)], expected)
    assert rig.lifecycle("s") == ["SpeechStarted", "SpeechFinished"]
    keys = tuple(k for e in rig.of(MouthKeys, "s") for k in e.keys)
    assert len(rig.of(MouthKeys, "s")) > 5  # many events: keys follow the chunks
    assert keys == mouth_track(expected, SR).keys


def test_late_chunks_wait_in_silence_and_feed_after_interrupt_is_ignored() -> None:
    rig = Rig()
    rig.player.say_stream("s", SR)
    rig.player.say_pcm("after", noise(0.05), SR)
    rig.sink.advance(5)
    assert rig.lifecycle("s") == []  # nothing yet: the queue waits for the stream
    assert not rig.sink.output.any()
    rig.player.feed("s", noise(0.05, seed=2))
    rig.sink.advance(10)
    assert rig.lifecycle("s") == ["SpeechStarted"]
    assert rig.lifecycle("after") == []
    rig.player.interrupt("s")
    rig.sink.advance(1)
    assert not rig.player.feed("s", noise(0.05))
    rig.run_until_idle()
    assert rig.lifecycle("s") == ["SpeechStarted", "SpeechInterrupted"]
    assert rig.of(SpeechInterrupted, "s")[0].played_s == pytest.approx(0.05)
    assert rig.lifecycle("after") == ["SpeechStarted", "SpeechFinished"]


def test_bad_requests() -> None:
    rig = Rig()
    rig.player.say_pcm("dup", noise(0.1), SR)
    with pytest.raises(ValueError, match="already in flight"):
        rig.player.say_pcm("dup", noise(0.1), SR)
    rig.player.say_pcm("rate", noise(0.1), 100)
    rig.player.say_pcm("ints", np.zeros(10, np.int32), SR)
    rig.player.say_stream("st", SR)
    rig.player.feed("st", np.zeros((2, 2, 2), np.float32))
    assert not rig.player.feed("st", noise(0.1))  # a failed stream takes no more chunks
    rig.run_until_idle()
    assert rig.lifecycle("rate") == ["SpeechFailed"]
    assert rig.lifecycle("ints") == ["SpeechFailed"]
    assert rig.lifecycle("st") == ["SpeechFailed"]
    assert rig.lifecycle("dup") == ["SpeechStarted", "SpeechFinished"]


def test_int16_pcm_is_scaled() -> None:
    rig = Rig()
    rig.player.say_pcm("i", np.array([16384, -16384] * 240, np.int16), SR)
    rig.run_until_idle()
    assert rig.sink.output[:4].tolist() == [0.5, -0.5, 0.5, -0.5]


def check_lifecycles(events: list[object], requested: list[str]) -> None:
    per: dict[str, list[str]] = defaultdict(list)
    for e in events:
        if isinstance(e, SpeechStarted | SpeechFinished | SpeechInterrupted | SpeechFailed):
            per[e.utterance_id].append(type(e).__name__)
    assert set(per) == set(requested)
    for uid in requested:
        seq = per[uid]
        assert seq in (["SpeechFailed"], ["SpeechInterrupted"], ["SpeechStarted", "SpeechFinished"],
                       ["SpeechStarted", "SpeechInterrupted"]), (uid, seq)


ops = st.lists(
    st.one_of(
        st.tuples(st.just("pcm"), st.integers(0, 30)),  # length in blocks (0: an empty utterance)
        st.tuples(st.just("missing"), st.just(0)),
        st.tuples(st.just("stream"), st.integers(1, 20)),
        st.tuples(st.just("feed"), st.integers(0, 8)),
        st.tuples(st.just("end"), st.just(0)),
        st.tuples(st.just("interrupt_all"), st.just(0)),
        st.tuples(st.just("interrupt_one"), st.integers(0, 50)),
        st.tuples(st.just("advance"), st.integers(1, 25)),
    ),
    max_size=30,
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(ops)
def test_random_requests_each_end_in_exactly_one_terminal_event(sequence: list[tuple[str, int]]) -> None:
    rig = Rig()
    requested: list[str] = []
    streams: list[str] = []
    for i, (op, arg) in enumerate(sequence):
        uid = f"u{i}"
        if op == "pcm":
            rig.player.say_pcm(uid, noise(arg * BLOCK / SR, seed=i), SR)
            requested.append(uid)
        elif op == "missing":
            rig.player.say_file(uid, "/nonexistent/file.wav")
            requested.append(uid)
        elif op == "stream":
            rig.player.say_stream(uid, 16_000)
            requested.append(uid)
            streams.append(uid)
        elif op == "feed" and streams:
            rig.player.feed(streams[arg % len(streams)], noise(0.01 * arg, sr=16_000, seed=i))
        elif op == "end" and streams:
            rig.player.feed(streams.pop(0), np.zeros(0, np.float32), last=True)
        elif op == "interrupt_all":
            rig.player.interrupt()
        elif op == "interrupt_one" and requested:
            rig.player.interrupt(requested[arg % len(requested)])
        elif op == "advance":
            rig.sink.advance(arg)
    for uid in streams:  # every open stream ends at some point
        rig.player.feed(uid, np.zeros(0, np.float32), last=True)
    rig.run_until_idle()
    rig.sink.advance(2)
    check_lifecycles(rig.events, requested)
    # Anchors and mouth events only for utterances that started, and none after their terminal event.
    ended: set[str] = set()
    for e in rig.events:
        if isinstance(e, TERMINAL_EVENTS):
            ended.add(e.utterance_id)
        elif isinstance(e, SpeechStarted):
            assert e.utterance_id not in ended
