"""espeak-ng as a pipecat TTS service (services/pipecat/tts.py), in pipecat's own test harness: a text becomes
a reply of TTS frames at the pipeline's rate, framed by TTSStarted/TTSStopped; bad settings are refused."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

pytest.importorskip("pipecat.frames.frames", reason="pipecat is not installed: pip install 'eca[pipecat]'")

from pipecat.frames.frames import TTSAudioRawFrame, TTSSpeakFrame, TTSStartedFrame, TTSStoppedFrame  # noqa: E402
from pipecat.pipeline.worker import PipelineParams  # noqa: E402
from pipecat.tests.utils import SleepFrame, run_test  # noqa: E402

from eca.services.processes.audio.tts import espeak_available  # noqa: E402

pytestmark = [pytest.mark.filterwarnings("ignore::DeprecationWarning"),  # pipecat's own
              pytest.mark.skipif(not espeak_available(), reason="espeak-ng is not installed")]


def espeak_tts(**settings: object) -> object:
    # Imported in the test, where pipecat's deprecation notice for a TTS class it defines is filtered.
    from eca.services.pipecat import EspeakTTSService

    return EspeakTTSService(**settings)  # type: ignore[arg-type]


def test_a_text_becomes_one_reply_of_frames_at_the_pipelines_rate() -> None:
    tts = espeak_tts(frame_ms=20)
    down, _ = asyncio.run(run_test(tts, frames_to_send=[TTSSpeakFrame("Hello there."), SleepFrame(sleep=1.5)],
                                   pipeline_params=PipelineParams(audio_out_sample_rate=24_000)))
    kinds = [type(f) for f in down if isinstance(f, TTSStartedFrame | TTSAudioRawFrame | TTSStoppedFrame)]
    assert kinds[0] is TTSStartedFrame and kinds[-1] is TTSStoppedFrame
    audio = [f for f in down if isinstance(f, TTSAudioRawFrame)]
    assert kinds[1:-1] == [TTSAudioRawFrame] * len(audio) and len({f.context_id for f in audio}) == 1
    assert all(f.sample_rate == 24_000 and f.num_channels == 1 for f in audio)
    assert all(len(f.audio) == 24_000 * 20 // 1000 * 2 for f in audio[:-1])  # 20 ms each, the last the rest
    samples = np.frombuffer(b"".join(f.audio for f in audio), dtype="<i2")
    assert 0.5 < len(samples) / 24_000 < 3.0  # "Hello there." at 160 words per minute
    assert np.abs(samples).max() > 3000  # spoken, not silence


def test_bad_settings_are_refused_with_the_reason() -> None:
    with pytest.raises(ValueError, match="frame_ms"):
        espeak_tts(frame_ms=15)
    with pytest.raises(ValueError, match="words_per_minute"):
        espeak_tts(words_per_minute=20)
    with pytest.raises(ValueError, match="voice"):
        espeak_tts(voice="en us; rm")
