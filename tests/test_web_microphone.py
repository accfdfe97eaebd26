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
