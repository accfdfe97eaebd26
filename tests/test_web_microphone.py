"""The user's microphone: 20 ms blocks at 16 kHz, and speech turns from the WebRTC voice-activity detector."""

from __future__ import annotations

import subprocess

import av
import numpy as np
import pytest
import soundfile as sf

from eca.services.processes.audio.resample import resample
from eca.services.processes.web.microphone import FRAME_SAMPLES, RATE, Microphone
from eca.services.processes.web.options import VadSettings

SPEECH_AT_S = 1.0


@pytest.fixture(scope="module")
def speech(tmp_path_factory: pytest.TempPathFactory) -> np.ndarray:
    """One second of silence, a spoken sentence, two seconds of silence; 16 kHz int16."""
    wav = tmp_path_factory.mktemp("mic") / "speech.wav"
    subprocess.run(["espeak-ng", "-w", str(wav), "The agent listens while the user talks."], check=True)
    spoken, rate = sf.read(wav, dtype="float32")
    spoken = resample(spoken, rate, RATE)
    silence = np.zeros(RATE, np.float32)
    return (np.concatenate([silence, spoken, silence, silence]) * 32767 * 0.8).astype(np.int16)


def run(samples: np.ndarray, chunk: int = 441) -> tuple[list[tuple[bool, float]], list]:
    """Feed the samples in uneven chunks, as packets come; the turns (with their time) and the blocks."""
    turns: list[tuple[bool, float]] = []
    blocks: list = []
    mic = Microphone(blocks.append, lambda speaking: turns.append((speaking, mic.samples / RATE)))
    for start in range(0, len(samples), chunk):
        part = samples[start:start + chunk]
        mic.push_samples(part, (start + len(part)) * 1_000_000_000 // RATE)
    return turns, blocks


def test_speech_starts_a_turn_and_its_end_stops_it(speech: np.ndarray) -> None:
    turns, blocks = run(speech)
    assert [t[0] for t in turns] == [True, False]
    spoken_s = (len(speech) - 3 * RATE) / RATE
    assert SPEECH_AT_S + 0.05 < turns[0][1] < SPEECH_AT_S + 0.5  # heard soon after it began
    assert SPEECH_AT_S + spoken_s < turns[1][1] < SPEECH_AT_S + spoken_s + 1.2  # after the pause, not before
    assert any(b.speaking for b in blocks) and not blocks[0].speaking


def test_blocks_are_20_ms_and_continuous_with_their_arrival_times(speech: np.ndarray) -> None:
    _, blocks = run(speech)
    assert all(len(b.pcm) == 2 * FRAME_SAMPLES for b in blocks)
    assert [b.first_sample for b in blocks] == list(range(0, len(blocks) * FRAME_SAMPLES, FRAME_SAMPLES))
    joined = np.frombuffer(b"".join(b.pcm for b in blocks), "<i2")
    assert np.array_equal(joined, speech[:len(joined)])
    steps = np.diff([b.capture_ns for b in blocks])
    assert np.all(np.abs(steps - 20_000_000) <= 1_000_000)


def test_silence_and_a_click_start_no_turn() -> None:
    quiet = np.zeros(3 * RATE, np.int16)
    quiet[RATE:RATE + 80] = 20_000  # a 5 ms click
    turns, _ = run(quiet)
    assert turns == []


def test_frames_at_the_browsers_rate_are_taken_as_they_come(speech: np.ndarray) -> None:
    """Browsers send 48 kHz Opus, decoded to 48 kHz frames: they are resampled, then judged."""
    at_48k = resample(speech.astype(np.float32) / 32767, RATE, 48_000)
    turns: list[bool] = []
    mic = Microphone(lambda b: None, turns.append)
    pcm = (at_48k * 32767).astype(np.int16)
    for start in range(0, len(pcm) - 960, 960):
        frame = av.AudioFrame.from_ndarray(pcm[None, start:start + 960], format="s16", layout="mono")
        frame.sample_rate = 48_000
        mic.push(frame, start * 1_000_000_000 // 48_000)
    assert turns == [True, False]


@pytest.mark.parametrize("bad", [VadSettings(aggressiveness=4), VadSettings(start_frames=11),
                                 VadSettings(stop_s=0.0)])
def test_settings_out_of_range_are_refused(bad: VadSettings) -> None:
    with pytest.raises(ValueError):
        bad.check()



@pytest.mark.parametrize("rms", [20, 50, 100, 200])  # -64 .. -44 dBFS
def test_a_hissing_microphone_starts_no_turn(rms: int) -> None:
    noise = (np.random.default_rng(rms).standard_normal(3 * RATE) * rms).astype(np.int16)
    turns, blocks = run(noise)
    assert turns == [] and not any(b.speaking for b in blocks)


def frames_48k(samples_16k: np.ndarray) -> list[av.AudioFrame]:
    """The samples as a browser's decoded 20 ms frames at 48 kHz, each with its RTP timestamp (pts)."""
    pcm = (resample(samples_16k.astype(np.float32) / 32767, RATE, 48_000) * 32767).astype(np.int16)
    out = []
    for start in range(0, len(pcm) - 960, 960):
        frame = av.AudioFrame.from_ndarray(pcm[None, start:start + 960], format="s16", layout="mono")
        frame.sample_rate = 48_000
        frame.pts = (start + 1_234_567) % 2**32  # an RTP timestamp starts anywhere
        out.append(frame)
    return out


def dtx(frames: list[av.AudioFrame]) -> list[av.AudioFrame]:
    """What a sender with Opus' discontinuous transmission sends: silent frames only every 400 ms."""
    out, quiet = [], 0
    for frame in frames:
        quiet = quiet + 1 if not frame.to_ndarray().any() else 0
        if quiet % 20 in (0, 1):
            out.append(frame)
    return out


def test_silence_left_out_by_the_sender_is_counted_not_sent(speech: np.ndarray) -> None:
    every = frames_48k(speech)
    sent = dtx(every)
    assert len(sent) < 0.6 * len(every)  # the seconds of silence around the sentence mostly left out
    def listen(frames: list[av.AudioFrame]) -> tuple[list[tuple[bool, int]], list, Microphone]:
        turns: list[tuple[bool, int]] = []
        blocks: list = []
        mic = Microphone(blocks.append, lambda speaking: turns.append((speaking, mic.samples)))
        for frame in frames:
            mic.push(frame, frame.pts * 1_000_000_000 // 48_000)
        return turns, blocks, mic

    (turns, blocks, mic), (dtx_turns, dtx_blocks, dtx_mic) = listen(every), listen(sent)
    assert [t for t, _ in dtx_turns] == [t for t, _ in turns] == [True, False]
    # at about the same samples: what was left out is counted as silence. Not exactly: the detector adapts its
    # noise model to the frames it judges, and judges fewer of the silent ones (a pause between words too)
    assert abs(dtx_turns[0][1] - turns[0][1]) <= 2 * FRAME_SAMPLES
    assert abs(dtx_turns[1][1] - turns[1][1]) <= 0.45 * RATE
    # the same stream position (but for the silence after the last packet sent), most of the silence left out
    assert mic.samples - 20 * FRAME_SAMPLES <= dtx_mic.samples <= mic.samples
    assert dtx_mic.skipped > 2 * RATE and mic.skipped == 0
    assert len(dtx_blocks) < 0.6 * len(blocks)
    # every block sent is the block at that place of the whole stream
    whole = {b.first_sample: b.pcm for b in blocks}
    assert all(whole[b.first_sample] == b.pcm for b in dtx_blocks)


def test_a_turn_ends_on_time_when_the_sender_sends_nothing_at_all(speech: np.ndarray) -> None:
    turns: list[bool] = []
    mic = Microphone(lambda b: None, turns.append)
    stop_s = mic.settings.stop_s
    last_ns = 0
    for frame in frames_48k(speech):
        last_ns = frame.pts * 1_000_000_000 // 48_000
        mic.push(frame, last_ns)
        if mic.speaking and mic._quiet_frames == 0 and frame.pts - 1_234_567 > 1.5 * 48_000:
            break  # mid-sentence, on a voiced frame: then the sender goes quiet (no packet at all)
    assert turns == [True]
    mic.idle(last_ns + 50_000_000)
    assert turns == [True]  # a packet 50 ms late is jitter, not silence
    mic.idle(last_ns + round(stop_s * 1e9))
    assert turns == [True]  # not before stop_s and the allowance for a late packet
    mic.idle(last_ns + round(stop_s * 1e9) + 100_000_000 + 1)
    assert turns == [True, False]
    mic.idle(last_ns + 10 * round(stop_s * 1e9))
    assert turns == [True, False]  # once


def test_the_answer_asks_the_microphones_section_alone_for_dtx() -> None:
    from eca.services.processes.web.viewers import ask_dtx

    sdp = "\r\n".join([
        "v=0", "o=- 1 1 IN IP4 0.0.0.0", "s=-", "t=0 0",
        "m=audio 9 UDP/TLS/RTP/SAVPF 111 0", "a=mid:0", "a=rtpmap:111 opus/48000/2",
        "a=fmtp:111 minptime=10;useinbandfec=1", "a=rtpmap:0 PCMU/8000",
        "m=audio 9 UDP/TLS/RTP/SAVPF 96", "a=mid:1", "a=rtpmap:96 OPUS/48000/2",
        "m=audio 9 UDP/TLS/RTP/SAVPF 97", "a=mid:2", "a=rtpmap:97 opus/48000/2", ""])
    asked = ask_dtx(sdp, "0").split("\r\n")
    assert "a=fmtp:111 minptime=10;useinbandfec=1;usedtx=1" in asked and asked.count("a=rtpmap:0 PCMU/8000") == 1
    assert ask_dtx(ask_dtx(sdp, "0"), "0") == ask_dtx(sdp, "0")  # asked once
    lines = ask_dtx(sdp, "1").split("\r\n")
    assert lines[lines.index("a=rtpmap:96 OPUS/48000/2") + 1] == "a=fmtp:96 usedtx=1"  # a format line of its own
    assert "usedtx" not in "".join(ask_dtx(sdp, "1").split("m=")[3]) and "usedtx" not in "".join(lines[:9])
    assert ask_dtx(sdp, "7") == sdp  # no such section: unchanged


def test_a_microphone_decoded_on_the_loop_gives_mono_frames_drops_a_bad_one_and_hands_the_stop_on() -> None:
    """DecodeOnLoop (web/mic_decoding.py), in the place of a receiver's decoder queue: each encoded frame decoded
    at once into the track's queue, with its RTP timestamp, to one channel (a microphone is one voice); a frame
    libopus refuses dropped and counted, the next decoded; the receiver's stop handed to its thread's `get`."""
    import asyncio
    import queue
    import threading

    from aiortc.jitterbuffer import JitterFrame
    from aiortc.rtcrtpparameters import RTCRtpCodecParameters

    from eca.services.processes.web.mic_decoding import DecodeOnLoop
    from eca.services.processes.web.tracks import OpusFrames

    codec = RTCRtpCodecParameters(mimeType="audio/opus", clockRate=48_000, channels=2, payloadType=111)
    opus = OpusFrames()
    tone = (6000 * np.sin(2 * np.pi * 300 * np.arange(960 * 5) / 48_000)).astype(np.int16)
    packets = [bytes(p) for k in range(5) if (p := opus.encode(tone[k * 960:(k + 1) * 960], k * 960)) is not None]
    assert len(packets) == 5

    async def main() -> list[av.AudioFrame]:
        frames: asyncio.Queue[av.AudioFrame] = asyncio.Queue()
        stand_in = DecodeOnLoop(frames)
        stand_in.put((codec, JitterFrame(data=packets[0], timestamp=1000)))
        stand_in.put((codec, JitterFrame(data=b"\xff" * 3, timestamp=1960)))  # a code-63 packet with no count
        for k, data in enumerate(packets[1:], start=1):
            stand_in.put((codec, JitterFrame(data=data, timestamp=1000 + 960 * k)))
        assert (stand_in.decoded, stand_in.failed) == (5, 1)
        stopped: queue.SimpleQueue[object] = queue.SimpleQueue()
        thread = threading.Thread(target=lambda: stopped.put(stand_in.get()))
        thread.start()
        stand_in.put(None)
        thread.join(5.0)
        assert not thread.is_alive() and stopped.get_nowait() is None
        return [frames.get_nowait() for _ in range(frames.qsize())]

    got = asyncio.run(main())
    assert [f.pts for f in got] == [1000 + 960 * k for k in range(5)]
    assert all(f.sample_rate == 48_000 and f.samples == 960 and f.layout.name == "mono" for f in got)
    samples = got[-1].to_ndarray().reshape(-1)
    assert samples.shape == (960,) and np.abs(samples).max() > 3000  # the tone, not silence
    # the same frame through aiortc's own (stereo) decoder: the same voice in each channel
    from aiortc.codecs import get_decoder

    decoder = get_decoder(codec)  # made anew after the bad frame, as the stand-in's was
    stereo = [decoder.decode(JitterFrame(data=p, timestamp=960 * k))[0] for k, p in enumerate(packets[1:])]
    both = stereo[-1].to_ndarray().reshape(-1, 2)
    assert np.array_equal(both[:, 0], samples) and np.array_equal(both[:, 1], samples)


def test_a_microphone_decoded_on_the_loop_drops_whatever_bytes_a_page_sends() -> None:
    """Hostile or broken packets (seeded random bytes of 0-1,500, empty ones among them, and Opus TOC bytes with
    garbage after them): each dropped or decoded, none raising into the connection's packet handling, and a good
    frame still decodes after (an empty packet is FFmpeg's end of stream: once sent, every frame had failed)."""
    import asyncio

    from aiortc.jitterbuffer import JitterFrame
    from aiortc.rtcrtpparameters import RTCRtpCodecParameters

    from eca.services.processes.web.mic_decoding import DecodeOnLoop
    from eca.services.processes.web.tracks import OpusFrames

    codec = RTCRtpCodecParameters(mimeType="audio/opus", clockRate=48_000, channels=2, payloadType=111)
    rng = np.random.default_rng(11)
    good = OpusFrames().encode((3000 * np.sin(np.arange(960) / 7)).astype(np.int16), 0)
    assert good is not None

    async def main() -> tuple[int, int, int]:
        frames: asyncio.Queue[av.AudioFrame] = asyncio.Queue()
        stand_in = DecodeOnLoop(frames)
        payloads = [rng.bytes(int(n)) for n in rng.integers(0, 1500, 600)] + [b""]
        payloads += [bytes([toc]) + rng.bytes(int(rng.integers(0, 40))) for toc in range(256)]
        for k, data in enumerate(payloads):
            stand_in.put((codec, JitterFrame(data=data, timestamp=960 * k)))
        before = stand_in.decoded
        stand_in.put((codec, JitterFrame(data=bytes(good), timestamp=960 * len(payloads))))
        assert stand_in.decoded == before + 1
        return stand_in.decoded, stand_in.failed, len(payloads) + 1

    decoded, failed, sent = asyncio.run(main())
    assert decoded + failed == sent and failed > 0
