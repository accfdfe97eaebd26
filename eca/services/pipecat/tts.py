"""espeak-ng as a pipecat TTS service: a voice with no key, no network and no model to download.

Each text is spoken by one espeak-ng process (eca's own engine wrapper, services/processes/audio/tts.py, with its time
limit and clear errors), run off the event loop; its samples are converted to the pipeline's output
rate and yielded as `TTSAudioRawFrame`s of `frame_ms` each, all at once, as a hosted TTS that streams
faster than real time does: the output transport paces them. pipecat's base class wraps them in
`TTSStartedFrame` / `TTSStoppedFrame` and handles interruptions (the frames of a cut reply are dropped).
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncGenerator
from typing import Any

import numpy as np
from pipecat.audio.utils import create_file_resampler
from pipecat.frames.frames import ErrorFrame, Frame, TTSAudioRawFrame
from pipecat.services.settings import TTSSettings
from pipecat.services.tts_service import TTSService

from eca.services.processes.audio.tts import EngineSettings, EspeakSpeech, SpeechSynthesisError


class EspeakTTSService(TTSService):
    """espeak-ng with `voice`, `words_per_minute` and `pitch` (espeak-ng's own -v, -s and -p)."""

    def __init__(self, *, voice: str = "en-us", words_per_minute: int = 160, pitch: int = 50, frame_ms: int = 20,
                 timeout_s: float = 30.0, **kwargs: Any) -> None:
        """`frame_ms`: the length of each audio frame pushed (10 ms steps); `timeout_s`: how long espeak-ng may
        take for one text. ValueError for settings out of range; `kwargs` go to pipecat's TTSService."""
        if not 10 <= frame_ms <= 1000 or frame_ms % 10:
            raise ValueError(f"frame_ms must be a multiple of 10 in 10..1000, got {frame_ms!r}")
        self._engine = EspeakSpeech(EngineSettings(voice=voice, words_per_minute=words_per_minute, pitch=pitch,
                                                   timeout_s=timeout_s).check("EspeakTTSService"))
        super().__init__(push_start_frame=True, push_stop_frames=True,
                         settings=TTSSettings(model=None, voice=voice, language=None), **kwargs)
        self._frame_ms = frame_ms
        self._resampler = create_file_resampler()

    def can_generate_metrics(self) -> bool:
        """pipecat's metrics (time to first byte, usage) are reported."""
        return True

    async def run_tts(self, text: str, context_id: str) -> AsyncGenerator[Frame | None, None]:
        """Speak `text` with espeak-ng (in a thread) and yield its audio as frames of `frame_ms` at the
        pipeline's rate; an ErrorFrame when espeak-ng fails."""
        try:
            samples, rate = await asyncio.to_thread(self._engine.speak, text)
        except SpeechSynthesisError as exc:
            yield ErrorFrame(error=str(exc))
            return
        await self.start_tts_usage_metrics(text)
        pcm = (np.clip(samples, -1.0, 1.0) * 32767.0).astype("<i2").tobytes()
        if rate != self.sample_rate:
            pcm = await self._resampler.resample(pcm, rate, self.sample_rate)
        step = self.sample_rate * self._frame_ms // 1000 * 2
        for start in range(0, len(pcm), step):
            yield TTSAudioRawFrame(audio=pcm[start:start + step], sample_rate=self.sample_rate, num_channels=1,
                                   context_id=context_id)
