"""The user's microphone from a browser: 16 kHz mono blocks, and when the user starts and stops speaking.

The decision is the WebRTC voice-activity detector's (the `webrtcvad` package: Google's GMM detector
from the WebRTC project), frame by 20 ms frame, smoothed the way a turn-taking front-end needs it: the
user is speaking after `start_frames` voiced frames among the last `window` (a cough or a click does not
barge in), and has stopped after `stop_s` without a voiced frame (a pause between words does not end
the turn). Every frame also goes out as audio, so a dialogue manager can run its own recognition on it.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import av
import numpy as np
import webrtcvad

from eca.services.processes.web.options import VadSettings

RATE = 16_000
FRAME_SAMPLES = 320  # 20 ms at 16 kHz: one of the frame lengths the detector takes


@dataclass(frozen=True)
class MicBlock:
    first_sample: int  # since this microphone connected, at 16 kHz
    capture_ns: int  # when its first sample arrived (monotonic clock)
    pcm: bytes  # 20 ms, mono int16 little-endian
    speaking: bool


class Microphone:
    """Turns the frames a browser sends (any rate and layout) into 20 ms blocks at 16 kHz and speech
    turns. `on_block` gets every block, `on_turn(True/False)` each change of the user's speaking."""

    def __init__(self, on_block: Callable[[MicBlock], None], on_turn: Callable[[bool], None],
                 settings: VadSettings | None = None) -> None:
        self.settings = (settings or VadSettings()).check()
        self._vad = webrtcvad.Vad(self.settings.aggressiveness)
        self._resampler = av.AudioResampler(format="s16", layout="mono", rate=RATE)
        self._pending = np.zeros(0, dtype=np.int16)
        self._pending_ns = 0
        self._recent: deque[bool] = deque(maxlen=self.settings.window)
        self._quiet_frames = 0
        self.speaking = False
        self.samples = 0  # 16 kHz samples turned into blocks so far
        self.on_block, self.on_turn = on_block, on_turn

    def push(self, frame: av.AudioFrame, arrived_ns: int) -> None:
        """One frame as received (it arrived at `arrived_ns`)."""
        for out in self._resampler.resample(frame):
            self.push_samples(out.to_ndarray().reshape(-1).astype(np.int16, copy=False), arrived_ns)

    def push_samples(self, samples: np.ndarray, arrived_ns: int) -> None:
        """16 kHz mono int16 samples that arrived at `arrived_ns` (the last of them)."""
        if not len(self._pending):
            # the first of these samples arrived as long before the last as they last
            self._pending_ns = arrived_ns - len(samples) * 1_000_000_000 // RATE
        self._pending = np.concatenate((self._pending, samples))
        while len(self._pending) >= FRAME_SAMPLES:
            chunk, self._pending = self._pending[:FRAME_SAMPLES], self._pending[FRAME_SAMPLES:]
            capture_ns = self._pending_ns
            self._pending_ns += FRAME_SAMPLES * 1_000_000_000 // RATE
            self._frame(chunk, capture_ns)

    def _frame(self, chunk: np.ndarray, capture_ns: int) -> None:
        pcm = chunk.astype("<i2", copy=False).tobytes()
        voiced = self._vad.is_speech(pcm, RATE)
        self._recent.append(voiced)
        self._quiet_frames = 0 if voiced else self._quiet_frames + 1
        s = self.settings
        if not self.speaking and sum(self._recent) >= s.start_frames:
            self.speaking = True
            self.on_turn(True)
        elif self.speaking and self._quiet_frames * FRAME_SAMPLES / RATE >= s.stop_s:
            self.speaking = False
            self._recent.clear()
            self.on_turn(False)
        self.on_block(MicBlock(self.samples, capture_ns, pcm, self.speaking))
        self.samples += FRAME_SAMPLES
