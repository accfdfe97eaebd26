"""The bridges between the web service's bus loop and its WebRTC tracks, and the tracks' timing."""

from __future__ import annotations

import asyncio

import av
import numpy as np
import pytest

from eca.agent.clock import VirtualClock
from eca.services.processes.web.feeds import VoiceFeed
from eca.services.processes.web.tracks import VoiceTiming, VoiceTrack

RATE = 48_000
BLOCK = 480  # 10 ms
BLOCK_NS = 10_000_000


def blocks(feed: VoiceFeed, start_ns: int, count: int, first_value: int = 1) -> np.ndarray:
    """Add `count` consecutive 10 ms blocks whose samples count up; all the samples added."""
    samples = (np.arange(count * BLOCK) + first_value).astype(np.int16)
    for k in range(count):
        feed.add(start_ns + k * BLOCK_NS, samples[k * BLOCK:(k + 1) * BLOCK], RATE)
    return samples


def test_a_span_of_the_clock_gets_exactly_the_samples_played_then() -> None:
    feed = VoiceFeed(RATE)
    played = blocks(feed, 1_000_000_000, 10)
    # 20 ms from 5 ms into the first block: samples 240 .. 1199
    got = feed.take(1_005_000_000, 960)
    assert np.array_equal(got, played[240:1200])


def test_where_no_block_played_the_span_is_silence() -> None:
    feed = VoiceFeed(RATE)
    played = blocks(feed, 1_000_000_000, 2)  # 20 ms, then nothing (a block late or lost)
    got = feed.take(1_010_000_000, 960)
    assert np.array_equal(got[:480], played[480:]) and not got[480:].any()
    assert not feed.take(2_000_000_000, 960).any()


def test_the_feed_holds_a_bounded_span_and_lets_go_of_what_was_taken() -> None:
    feed = VoiceFeed(RATE, max_s=0.1)
    blocks(feed, 0, 50)  # 0.5 s offered, 0.1 s kept
    assert feed._held == round(0.1 * RATE)
    feed.take(490_000_000, 480)
    assert feed._held <= 2 * BLOCK


def test_a_block_at_another_rate_is_refused() -> None:
    with pytest.raises(ValueError, match="16000 Hz"):
        VoiceFeed(RATE).add(0, np.zeros(160, np.int16), 16_000)


def test_the_voice_track_sends_each_frame_when_it_is_due_with_the_samples_of_then() -> None:
    clock = VirtualClock(1_000_000_000)
    feed = VoiceFeed(RATE)
    played = blocks(feed, 1_000_000_000, 5)  # 50 ms

    async def main() -> list[np.ndarray]:
        track = VoiceTrack(feed, clock)
        out = []
        for _ in range(3):
            frame = await track.recv()
            out.append(frame.to_ndarray().reshape(-1))
            clock.advance_ns(20_000_000)
        return out

    frames = asyncio.run(main())
    assert np.array_equal(np.concatenate(frames[:2]), played[:1920])  # continuous, no gap, no repeat
    assert np.array_equal(frames[2][:480], played[1920:]) and not frames[2][480:].any()  # then silence


def test_a_voice_that_pauses_in_silence_sends_only_the_frames_that_sound_stamped_on_the_clock() -> None:
    clock = VirtualClock(1_000_000_000)
    feed = VoiceFeed(RATE)
    blocks(feed, 1_000_000_000, 5)  # 0-50 ms sounds
    blocks(feed, 1_200_000_000, 4, first_value=100)  # and 200-240 ms

    async def main() -> list[av.Packet]:
        track = VoiceTrack(feed, clock, pause_in_silence=True)
        out = [await track.recv()]
        clock.advance_ns(1_000_000_000)  # every later frame is due: none waits
        while len(out) < 5:
            out.append(await track.recv())
        assert track.skipped == 7  # 60-200 ms: seven silent frames, none sent
        return out

    packets = asyncio.run(main())
    assert all(isinstance(p, av.Packet) for p in packets)
    # RTP time (48 kHz) of each packet: the frame's place on the clock, the silence jumped over
    assert [p.pts for p in packets] == [0, 960, 1920, 9600, 10560]
    decoder = av.CodecContext.create("libopus", "r")
    decoded = [f.to_ndarray() for p in packets for f in decoder.decode(p)]
    assert len(decoded) == 5 and all(np.abs(d).max() > 0 for d in decoded)


class CountingFeed(VoiceFeed):
    """A voice feed that counts the spans the track takes from it."""

    def __init__(self) -> None:
        super().__init__(RATE)
        self.takes = 0

    def take(self, start_ns: int, count: int) -> np.ndarray:
        self.takes += 1
        return super().take(start_ns, count)


def test_a_voice_paused_in_silence_sleeps_until_the_feed_sounds_again_instead_of_waking_for_each_frame() -> None:
    clock = VirtualClock(1_000_000_000)
    feed = CountingFeed()
    blocks(feed, 1_000_000_000, 2)  # 0-20 ms sounds

    async def main() -> None:
        track = VoiceTrack(feed, clock, pause_in_silence=True)
        first = await track.recv()
        assert first.pts == 0
        taken = feed.takes
        later = asyncio.create_task(track.recv())
        clock.advance_ns(10_000_000_000)  # ten seconds of silence are due: 500 frames
        for _ in range(50):
            await asyncio.sleep(0)
        assert not later.done()
        assert feed.takes == taken  # not one silent frame taken, encoded or judged
        blocks(feed, 11_000_000_000, 2, first_value=7)  # the agent speaks again at 11 s
        packet = await asyncio.wait_for(later, 5.0)
        assert packet.pts == 500 * 960  # stamped at its place on the clock: the pause jumped over
        assert track.skipped == 499
        assert feed.takes == taken + 1

    asyncio.run(main())


def test_a_voice_that_pauses_needs_a_feed_that_says_when_it_sounds() -> None:
    class Silence:
        sample_rate = RATE

        def take(self, start_ns: int, count: int) -> np.ndarray:
            return np.zeros(count, np.int16)

    with pytest.raises(TypeError, match="says when it sounds"):
        VoiceTrack(Silence(), VirtualClock(0), pause_in_silence=True)


def test_the_web_service_s_event_loop_is_uvloop_s_and_runs_what_it_is_given() -> None:
    import uvloop

    from eca.services.processes.web.event_loop import EventLoopThread

    thread = EventLoopThread().start()
    try:
        assert isinstance(thread.loop, uvloop.Loop)

        async def answer() -> int:
            await asyncio.sleep(0.001)
            return 42

        assert thread.call(answer(), timeout_s=5.0) == 42
    finally:
        thread.stop()
    assert thread.loop.is_closed()


def test_a_voice_track_counts_how_late_it_hands_each_frame_over() -> None:
    clock = VirtualClock(1_000_000_000)
    feed = VoiceFeed(RATE)
    blocks(feed, 1_000_000_000, 10)  # 100 ms sounding
    timing = VoiceTiming()

    async def main() -> None:
        track = VoiceTrack(feed, clock, pause_in_silence=True, timing=timing)
        await track.recv()  # frame 0 on time
        clock.advance_ns(30_000_000)  # frame 1 (due at 20 ms) is taken at 30 ms: 10 ms late
        await track.recv()
        clock.advance_ns(50_000_000)  # frame 2 (due at 40 ms) at 80 ms: 40 ms late
        await track.recv()
        clock.advance_ns(20_000_000)  # frame 3 (due at 60 ms) at 100 ms: 40 ms late
        await track.recv()

    asyncio.run(main())
    assert (timing.frames, timing.late_20ms, timing.late_60ms, timing.max_late_ns) == (4, 2, 0, 40_000_000)


def test_the_voice_sounds_at_a_time_when_a_loud_sample_lies_within_the_window_around_it() -> None:
    """sounding() against the timeline worked out directly: 150 blocks of 10 ms (quiet or loud at random, with
    gaps where no block came), asked at times across all of it and past both ends."""
    rng = np.random.default_rng(7)
    feed = VoiceFeed(RATE)
    timeline = np.zeros(160 * BLOCK, dtype=np.int32)  # from 1 s; a gap is silence
    for k in range(150):
        if rng.random() < 0.15:
            continue  # no block here
        loud = rng.random() < 0.3
        samples = rng.integers(-40, 40, BLOCK).astype(np.int16)
        if loud:
            samples[rng.integers(0, BLOCK)] = 3000
        feed.add(1_000_000_000 + k * BLOCK_NS, samples, RATE)
        timeline[k * BLOCK:(k + 1) * BLOCK] = samples
    window_ns = 20_000_000
    for t_ns in rng.integers(990_000_000, 2_620_000_000, 400):
        lo = (int(t_ns) - window_ns // 2 - 1_000_000_000) * RATE // 1_000_000_000
        hi = (int(t_ns) + window_ns // 2 - 1_000_000_000) * RATE // 1_000_000_000 + 1
        expected = bool(np.abs(timeline[max(0, lo):max(0, hi)]).max(initial=0) > 64)
        assert feed.sounding(int(t_ns), window_ns) == expected, t_ns


def test_the_voice_encoder_sends_celt_packets_that_decode_to_the_voice() -> None:
    """OpusFrames: every packet in Opus' CELT-only mode (its TOC byte's configuration 16-31, RFC 6716 §3.1), and
    what a decoder makes of them is the voice sent: a tone comes back at its level and frequency, 2.5 ms late
    (the mode's lookahead)."""
    from eca.services.processes.web.tracks import OpusFrames

    rate, frame = OpusFrames.RATE, OpusFrames.RATE // 50
    t = np.arange(50 * frame) / rate
    sent = (8000 * np.sin(2 * np.pi * 440 * t)).astype(np.int16)
    opus = OpusFrames()
    decoder = av.CodecContext.create("libopus", "r")
    assert isinstance(decoder, av.AudioCodecContext)
    decoder.sample_rate, decoder.layout = rate, "mono"
    heard = []
    for k in range(50):
        packet = opus.encode(sent[k * frame:(k + 1) * frame], k * frame)
        assert packet is not None and packet.pts == k * frame
        data = bytes(packet)
        assert data[0] >> 3 >= 16, f"frame {k}: TOC configuration {data[0] >> 3} is not CELT-only"
        for decoded in decoder.decode(av.Packet(data)):
            heard.append(decoded.to_ndarray().reshape(-1))
    got = np.concatenate(heard).astype(np.float64)
    got = got if np.abs(got).max() > 2 else got * 32768  # float or int16 output, as the build decodes
    delay = 120  # 2.5 ms at 48 kHz
    a, b = sent[10 * frame:40 * frame].astype(np.float64), got[10 * frame + delay:40 * frame + delay]
    error = np.sqrt(np.mean((a - b) ** 2)) / np.sqrt(np.mean(a ** 2))
    assert error < 0.2, f"the decoded tone is {error:.0%} off the one sent"
