"""The player on a fake sink driven by a virtual clock: lifecycle, anchors, mouth timing, interruption,
failures, files and streamed PCM, and long files prepared slice by slice within a bounded read-ahead
(for a driven sink the preparer's steps run before each block, so all of it is deterministic)."""

from __future__ import annotations

import os
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.signal import lfilter

from eca.agent.clock import VirtualClock
from eca.agent.lipsync import MouthKey, MouthTrack, mouth_track
from eca.services.processes.audio import (
    FakeSink,
    Player,
    PlayerAnchor,
    PlayerFailed,
    PlayerFinished,
    PlayerInterrupted,
    PlayerMouthKeys,
    PlayerMouthReset,
    PlayerStarted,
)
from eca.services.processes.audio.config import AudioConfig
from eca.services.processes.audio.events import TERMINAL_EVENTS
from eca.services.processes.audio.resample import resample

SR = 48_000
BLOCK = 480
FRAME_NS = 1_000_000_000 // 60


class Rig:
    def __init__(self, latency_s: float = 0.0, config: AudioConfig | None = None) -> None:
        self.clock = VirtualClock(1_000_000_000)
        self.sink = FakeSink(self.clock, SR, BLOCK, latency_s=latency_s)
        self.events: list[object] = []
        self.player = Player(self.sink, self.events.append, agent_id="ada", clock=self.clock,
                             config=config).start()

    def of(self, kind: type, uid: str | None = None) -> list:
        return [e for e in self.events if isinstance(e, kind) and (uid is None or e.request_id == uid)]

    def lifecycle(self, uid: str) -> list[str]:
        kinds = (PlayerStarted, *TERMINAL_EVENTS)
        return [type(e).__name__ for e in self.events if isinstance(e, kinds) and e.request_id == uid]

    def run_until_idle(self, max_blocks: int = 100_000) -> None:
        for _ in range(max_blocks):
            if self.player.idle:
                return
            self.sink.advance(1)
        raise AssertionError("player never became idle")

    def keys(self, uid: str) -> tuple[MouthKey, ...]:
        return tuple(k for e in self.of(PlayerMouthKeys, uid) for k in e.keys)

    def check_keys_precede_their_sound(self) -> None:
        """No event that places a sample at the DAC (speech_started: sample 0; an anchor: its sample)
        comes before the key of the 10 ms block holding that sample."""
        keyed_to: dict[str, int] = defaultdict(lambda: -1)  # per utterance: first sample with no key out
        for e in self.events:
            if isinstance(e, PlayerMouthKeys):
                keyed_to[e.request_id] = e.keys[-1].sample_index + BLOCK
            elif isinstance(e, PlayerStarted):
                assert keyed_to[e.request_id] > 0, e
            elif isinstance(e, PlayerAnchor):
                assert e.sample_index < keyed_to[e.request_id], e


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
    names = [(type(e).__name__, e.request_id) for e in rig.events if not isinstance(e, PlayerAnchor | PlayerMouthKeys)]
    assert names == [
        ("PlayerStarted", "u1"), ("PlayerFinished", "u1"),
        ("PlayerStarted", "u2"), ("PlayerFinished", "u2"),
    ]
    rig.check_keys_precede_their_sound()
    f1, f2 = rig.of(PlayerFinished)
    assert f1.played_s == pytest.approx(0.25) and f2.played_s == pytest.approx(0.15)
    s1, s2 = rig.of(PlayerStarted)
    assert s1.dac_time_ns == 1_000_000_000
    assert s2.dac_time_ns == f1.dac_time_ns == s1.dac_time_ns + 250_000_000  # back to back, gap-free
    assert all(e.agent == "ada" for e in rig.events)


@pytest.mark.parametrize("latency_s", [0.0, 0.0237])
def test_a_say_with_a_start_time_is_heard_from_that_time_to_the_sample(latency_s: float) -> None:
    rig = Rig(latency_s=latency_s)
    start_ns = 1_000_000_000 + 123_456_789  # inside a block, after the first blocks of silence
    a = noise(0.1)
    rig.player.say_pcm("later", a, SR, start_ns=start_ns)
    rig.player.say_pcm("next", noise(0.05, seed=2), SR)  # queued behind it: after it, back to back
    rig.run_until_idle()
    (started, next_started) = rig.of(PlayerStarted)
    assert 0 <= started.dac_time_ns - start_ns < 1_000_000_000 // SR  # the first sample at its time
    assert next_started.dac_time_ns == started.dac_time_ns + 100_000_000
    first = -(-(start_ns - 1_000_000_000 - round(latency_s * 1e9)) * SR // 1_000_000_000)  # the sample index out
    out = rig.sink.output
    assert not out[:first].any() and np.array_equal(out[first:first + len(a)], a)
    rig.check_keys_precede_their_sound()


def test_a_start_time_already_past_plays_at_once() -> None:
    rig = Rig()
    rig.sink.advance(10)
    rig.player.say_pcm("late", noise(0.05), SR, start_ns=1)
    rig.run_until_idle()
    (started,) = rig.of(PlayerStarted)
    assert started.dac_time_ns == 1_000_000_000 + 10 * BLOCK * 1_000_000_000 // SR


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
    anchors = rig.of(PlayerAnchor, "u")
    t0 = rig.sink.block_time_ns(0) + rig.sink.latency_ns  # DAC time of the sink's first output sample
    out = rig.sink.output
    for a in anchors:
        assert a.sample_rate == SR
        position = round((a.dac_time_ns - t0) * SR / 1e9)  # output sample at the DAC at that time
        assert out[position] == x[a.sample_index]
    # >= 60 Hz over the whole time the utterance is at the DAC, and none once it has ended.
    start = rig.of(PlayerStarted, "u")[0].dac_time_ns
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
    keys = [k for e in rig.of(PlayerMouthKeys, "u") for k in e.keys]
    track = MouthTrack(SR, tuple(keys))
    anchor = rig.of(PlayerAnchor, "u")[5]

    def mouth_at(t_ns: int) -> dict[str, float]:  # what the renderer does at a frame's display time
        return track.weights_at(anchor.sample_index + (t_ns - anchor.dac_time_ns) * SR / 1e9)

    def dac_ns(sample: int) -> int:
        return anchor.dac_time_ns + round((sample - anchor.sample_index) * 1e9 / SR)

    played = rig.sink.output
    loud = np.flatnonzero(np.abs(played) > 0.05)
    t_on = rig.sink.block_time_ns(0) + rig.sink.latency_ns + round(loud[0] * 1e9 / SR)
    t_off = rig.sink.block_time_ns(0) + rig.sink.latency_ns + round((loud[-1] + 1) * 1e9 / SR)
    assert dac_ns(0) == rig.of(PlayerStarted, "u")[0].dac_time_ns
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
    (cut,) = rig.of(PlayerInterrupted, "long")
    assert cut.played_s == pytest.approx(37 * BLOCK / SR)
    assert cut.dac_time_ns == rig.sink.block_time_ns(37)
    assert rig.of(PlayerInterrupted, "queued")[0].played_s == 0.0
    assert rig.lifecycle("long") == ["PlayerStarted", "PlayerInterrupted"]
    assert rig.lifecycle("queued") == ["PlayerInterrupted"]
    resets = rig.of(PlayerMouthReset)
    assert [r.request_id for r in resets] == ["long"]
    assert rig.events.index(resets[0]) < rig.events.index(cut)
    rig.sink.advance(3)
    assert not rig.of(PlayerAnchor, "long") or rig.of(PlayerAnchor, "long")[-1].dac_time_ns < cut.dac_time_ns
    # A new request after that plays normally.
    fresh = noise(0.1, seed=9)
    rig.player.say_pcm("next", fresh, SR)
    start = len(rig.sink.output)
    rig.run_until_idle()
    assert rig.lifecycle("next") == ["PlayerStarted", "PlayerFinished"]
    assert np.array_equal(rig.sink.output[start : start + len(fresh)], fresh)


def test_interrupt_one_utterance_leaves_the_rest_of_the_queue() -> None:
    rig = Rig()
    rig.player.say_pcm("a", noise(0.2), SR)
    rig.player.say_pcm("b", noise(0.2), SR)
    rig.player.say_pcm("c", noise(0.2), SR)
    rig.sink.advance(2)
    assert rig.player.interrupt("b") == ["b"]
    rig.run_until_idle()
    assert rig.lifecycle("a") == ["PlayerStarted", "PlayerFinished"]
    assert rig.lifecycle("b") == ["PlayerInterrupted"]
    assert rig.lifecycle("c") == ["PlayerStarted", "PlayerFinished"]


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
    assert rig.lifecycle("missing") == ["PlayerFailed"]
    missing = rig.of(PlayerFailed, "missing")[0].reason
    assert str(tmp_path / "nope.wav") in missing and "not found" in missing
    assert rig.lifecycle("garbage") == ["PlayerFailed"]
    assert "garbage.wav" in rig.of(PlayerFailed, "garbage")[0].reason
    assert rig.lifecycle("nan") == ["PlayerFailed"]
    assert rig.lifecycle("before") == ["PlayerStarted", "PlayerFinished"]
    assert rig.lifecycle("after") == ["PlayerStarted", "PlayerFinished"]
    # Terminal events in queue order, the failures included.
    terminal = [e.request_id for e in rig.events if isinstance(e, TERMINAL_EVENTS)]
    assert terminal == ["before", "missing", "garbage", "nan", "after"]


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
    assert np.array_equal(rig.sink.output[: len(expected)], expected)
    assert not rig.sink.output[len(expected):].any()
    assert len(rig.of(PlayerMouthKeys, "f")) > 1  # keys go out slice by slice, as they are computed
    assert rig.keys("f") == mouth_track(expected, SR).keys
    rig.check_keys_precede_their_sound()
    assert rig.of(PlayerFinished, "f")[0].played_s == pytest.approx(len(expected) / SR)


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
    assert rig.lifecycle("s") == ["PlayerStarted", "PlayerFinished"]
    keys = tuple(k for e in rig.of(PlayerMouthKeys, "s") for k in e.keys)
    assert len(rig.of(PlayerMouthKeys, "s")) > 5  # many events: keys follow the chunks
    assert keys == mouth_track(expected, SR).keys
    rig.check_keys_precede_their_sound()


def test_late_chunks_wait_in_silence_and_feed_after_interrupt_is_ignored() -> None:
    rig = Rig()
    rig.player.say_stream("s", SR)
    rig.player.say_pcm("after", noise(0.05), SR)
    rig.sink.advance(5)
    assert rig.lifecycle("s") == []  # nothing yet: the queue waits for the stream
    assert not rig.sink.output.any()
    rig.player.feed("s", noise(0.05, seed=2))
    rig.sink.advance(10)
    assert rig.lifecycle("s") == ["PlayerStarted"]
    assert rig.lifecycle("after") == []
    rig.player.interrupt("s")
    rig.sink.advance(1)
    assert not rig.player.feed("s", noise(0.05))
    rig.run_until_idle()
    assert rig.lifecycle("s") == ["PlayerStarted", "PlayerInterrupted"]
    assert rig.of(PlayerInterrupted, "s")[0].played_s == pytest.approx(0.05)
    assert rig.lifecycle("after") == ["PlayerStarted", "PlayerFinished"]


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
    assert rig.lifecycle("rate") == ["PlayerFailed"]
    assert rig.lifecycle("ints") == ["PlayerFailed"]
    assert rig.lifecycle("st") == ["PlayerFailed"]
    assert rig.lifecycle("dup") == ["PlayerStarted", "PlayerFinished"]


def test_int16_pcm_is_scaled() -> None:
    rig = Rig()
    rig.player.say_pcm("i", np.array([16384, -16384] * 240, np.int16), SR)
    rig.run_until_idle()
    assert rig.sink.output[:4].tolist() == [0.5, -0.5, 0.5, -0.5]


def check_lifecycles(events: list[object], requested: list[str]) -> None:
    per: dict[str, list[str]] = defaultdict(list)
    for e in events:
        if isinstance(e, PlayerStarted | PlayerFinished | PlayerInterrupted | PlayerFailed):
            per[e.request_id].append(type(e).__name__)
    assert set(per) == set(requested)
    for uid in requested:
        seq = per[uid]
        assert seq in (["PlayerFailed"], ["PlayerInterrupted"], ["PlayerStarted", "PlayerFinished"],
                       ["PlayerStarted", "PlayerInterrupted"]), (uid, seq)


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
    assert [e.request_id for e in rig.events if isinstance(e, TERMINAL_EVENTS)] == requested  # queue order
    rig.check_keys_precede_their_sound()
    # Anchors and mouth events only for utterances that started, and none after their terminal event.
    ended: set[str] = set()
    for e in rig.events:
        if isinstance(e, TERMINAL_EVENTS):
            ended.add(e.request_id)
        elif isinstance(e, PlayerStarted):
            assert e.request_id not in ended


# --- long files: streamed from the preparer, a bounded read-ahead ahead of playback ---------------------


def open_files() -> set[str]:
    """Paths this process holds open (Linux)."""
    fds = Path("/proc/self/fd")
    if not fds.is_dir():
        pytest.skip("needs /proc/self/fd")
    held = set()
    for fd in fds.iterdir():
        try:
            held.add(os.readlink(fd))
        except OSError:
            pass  # closed between the listing and the look
    return held


def write_long_wav(path: Path, seconds: float, sr: int, seed: int = 0) -> np.ndarray:
    """A stereo 16-bit WAV of quiet noise with a slow loudness wobble; returns the mono float32 the
    player decodes from it (the channel mean)."""
    rng = np.random.default_rng(seed)
    n = round(seconds * sr)
    wobble = 0.5 + 0.4 * np.sin(2 * np.pi * 1.3 * np.arange(n) / sr)
    pcm = (rng.uniform(-0.2, 0.2, (n, 2)) * wobble[:, None] * 32767).astype(np.int16)
    sf.write(path, pcm, sr, subtype="PCM_16")
    decoded, _ = sf.read(path, dtype="float32", always_2d=True)
    return decoded.mean(axis=1)


def test_a_long_file_starts_at_once_keeps_a_bounded_read_ahead_and_plays_sample_exact(tmp_path: Path) -> None:
    config = AudioConfig(read_ahead_s=2.0, prepare_slice_s=0.25)
    rig = Rig(config=config)
    sr_in = 22_050
    path = tmp_path / "long.wav"
    mono = write_long_wav(path, 12.0, sr_in)
    expected = np.clip(resample(mono, sr_in, SR), -1.0, 1.0)
    bound_s = config.read_ahead_s + config.prepare_slice_s + BLOCK / SR  # one slice may overshoot

    rig.player.say_file("long", path)
    assert rig.player.prepared_ahead_s == 0.0  # the request itself did no audio work
    rig.sink.advance(1)
    assert rig.lifecycle("long") == ["PlayerStarted"]
    assert config.read_ahead_s <= rig.player.prepared_ahead_s + BLOCK / SR <= bound_s
    peak = 0.0
    while not rig.player.idle:
        rig.sink.advance(1)
        peak = max(peak, rig.player.prepared_ahead_s)
    assert peak <= bound_s  # never the whole file, at any point

    out = rig.sink.output
    assert np.array_equal(out[: len(expected)], expected)
    assert not out[len(expected):].any()
    assert rig.lifecycle("long") == ["PlayerStarted", "PlayerFinished"]
    assert rig.of(PlayerFinished, "long")[0].played_s == len(expected) / SR
    assert len(rig.of(PlayerMouthKeys, "long")) >= 12.0 / config.prepare_slice_s  # keys in pieces, as computed
    assert rig.keys("long") == mouth_track(expected, SR).keys
    rig.check_keys_precede_their_sound()


def test_a_600_s_file_is_cut_mid_way_once_and_let_go_of(tmp_path: Path) -> None:
    config = AudioConfig.load()  # the shipped read-ahead
    rig = Rig(config=config)
    path = tmp_path / "ten-minutes.wav"
    sr_in = 8000
    second = np.random.default_rng(7).integers(-3000, 3000, sr_in, dtype=np.int16)
    sf.write(path, np.tile(second, 600), sr_in, subtype="PCM_16")
    rig.player.say_file("long", path)
    after = noise(0.1)
    rig.player.say_pcm("next", after, SR)
    assert rig.player.prepared_ahead_s == 0.0
    rig.sink.advance(1)
    assert rig.player.prepared_ahead_s <= config.read_ahead_s + config.prepare_slice_s + BLOCK / SR  # of 600 s
    rig.sink.advance(299)  # 3 s played
    assert str(path) in open_files()
    assert rig.player.interrupt("long") == ["long"]
    assert np.array_equal(rig.sink.advance(1), after[:BLOCK])  # the very next block is the next request
    (cut,) = rig.of(PlayerInterrupted, "long")
    assert cut.played_s == 3.0
    assert rig.lifecycle("long") == ["PlayerStarted", "PlayerInterrupted"]
    rig.run_until_idle()
    assert rig.lifecycle("long") == ["PlayerStarted", "PlayerInterrupted"]  # once
    assert rig.lifecycle("next") == ["PlayerStarted", "PlayerFinished"]
    assert str(path) not in open_files()  # the preparer dropped the file at its next step


def test_a_file_cut_short_while_it_plays_fails_once_after_its_good_audio(tmp_path: Path) -> None:
    config = AudioConfig(read_ahead_s=1.0, prepare_slice_s=0.2)
    rig = Rig(config=config)
    sr_in = 16_000
    path = tmp_path / "shrinking.wav"
    sf.write(path, (noise(5.0, sr_in, seed=3) * 32767).astype(np.int16), sr_in, subtype="PCM_16")
    full = resample(sf.read(path, dtype="float32")[0], sr_in, SR)
    rig.player.say_file("f", path)
    rig.player.say_pcm("after", noise(0.1, seed=4), SR)
    rig.sink.advance(10)
    with open(path, "r+b") as fh:  # a writer cuts it to 2 s while it plays
        fh.truncate(44 + 2 * sr_in * 2)
    rig.run_until_idle()
    assert rig.lifecycle("f") == ["PlayerStarted", "PlayerFailed"]
    reason = rig.of(PlayerFailed, "f")[0].reason
    assert str(path) in reason and "ended after 2.0 s of the 5.0 s" in reason
    # What was decoded plays to the point of failure, then the mouth closes and the next request plays.
    (reset,) = rig.of(PlayerMouthReset, "f")
    start = rig.of(PlayerStarted, "f")[0]
    played = (reset.dac_time_ns - start.dac_time_ns) * SR // 1_000_000_000
    assert 2.0 - 0.02 <= played / SR <= 2.0
    out = rig.sink.output
    first = int(np.flatnonzero(out)[0])
    assert np.array_equal(out[first : first + played], full[:played])
    assert rig.lifecycle("after") == ["PlayerStarted", "PlayerFinished"]
    terminal = [e.request_id for e in rig.events if isinstance(e, TERMINAL_EVENTS)]
    assert terminal == ["f", "after"]


def test_a_preparer_that_falls_behind_leaves_silence_not_a_failure(tmp_path: Path) -> None:
    config = AudioConfig(read_ahead_s=0.5, prepare_slice_s=0.1)
    rig = Rig(config=config)
    sr_in = 24_000
    path = tmp_path / "speech.wav"
    x = tone(2.0, sr_in)
    sf.write(path, x, sr_in, subtype="FLOAT")
    rig.player.say_file("f", path)
    rig.sink.advance(1)
    rig.player.driven_slices_per_block = 0  # an overloaded machine: no preparation at all for a while
    stalled = rig.sink.advance(150)
    assert rig.lifecycle("f") == ["PlayerStarted"]  # still playing: waiting, not failed
    assert not stalled[-50 * BLOCK:].any()  # the read-ahead ran dry: silence
    rig.player.driven_slices_per_block = 1  # slower than real time: 0.1 s per 10 ms block is plenty
    rig.run_until_idle()
    assert rig.lifecycle("f") == ["PlayerStarted", "PlayerFinished"]
    expected = resample(x, sr_in, SR)
    assert rig.of(PlayerFinished, "f")[0].played_s == len(expected) / SR
    out = rig.sink.output
    assert np.array_equal(out[np.abs(out) > 0], expected[np.abs(expected) > 0])  # everything, in order
    rig.check_keys_precede_their_sound()


def test_the_read_ahead_is_shared_by_the_whole_queue(tmp_path: Path) -> None:
    config = AudioConfig(read_ahead_s=1.0, prepare_slice_s=0.2)
    rig = Rig(config=config)
    paths = []
    for i in range(3):
        paths.append(tmp_path / f"part{i}.wav")
        write_long_wav(paths[-1], 2.0, SR, seed=i)
    for i, path in enumerate(paths):
        rig.player.say_file(f"p{i}", path)
    peak = 0.0
    while not rig.player.idle:
        rig.sink.advance(1)
        peak = max(peak, rig.player.prepared_ahead_s)
    assert peak <= config.read_ahead_s + config.prepare_slice_s + BLOCK / SR
    expected = np.concatenate([sf.read(p, dtype="float32", always_2d=True)[0].mean(axis=1) for p in paths])
    assert np.array_equal(rig.sink.output[: len(expected)], expected)  # back to back, gap-free
    assert [e.request_id for e in rig.events if isinstance(e, TERMINAL_EVENTS)] == ["p0", "p1", "p2"]


def test_inline_pcm_is_left_to_the_preparer() -> None:
    rig = Rig()
    big = (noise(60.0, 16_000) * 32767).astype(np.int16)  # 1.9 MB, as the service passes it: int16
    rig.player.say_pcm("big", big, 16_000)
    assert rig.player.prepared_ahead_s == 0.0  # no conversion, resampling or lip-sync on the caller
    rig.sink.advance(1)
    assert 0 < rig.player.prepared_ahead_s <= rig.player.config.read_ahead_s + rig.player.config.prepare_slice_s
    rig.sink.advance(20)
    assert rig.player.interrupt() == ["big"]
    rig.sink.advance(1)
    assert rig.lifecycle("big") == ["PlayerStarted", "PlayerInterrupted"]
    assert rig.of(PlayerInterrupted, "big")[0].played_s == pytest.approx(21 * BLOCK / SR)
