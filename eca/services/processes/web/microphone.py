"""The user's microphone from a browser: 16 kHz mono blocks, and when the user starts and stops speaking.

The decision is the WebRTC voice-activity detector's (the `webrtcvad` package: Google's GMM detector
from the WebRTC project), frame by 20 ms frame, smoothed the way a turn-taking front-end needs it: the
user is speaking after `start_frames` voiced frames among the last `window` (a cough or a click does not
barge in), and has stopped after `stop_s` without a voiced frame (a pause between words does not end
the turn). Every frame also goes out as audio, so a dialogue manager can run its own recognition on it.

A browser asked for Opus' discontinuous transmission (the service's answer says `usedtx=1`) sends no packet,
or one every 400 ms, while the user is silent. The frames' RTP timestamps say what was left out: that
silence is counted (the blocks' `first_sample` jumps over it, the detector takes it as unvoiced frames) but
not sent as blocks nor judged frame by frame, so a silent user costs almost nothing. A turn still ends on
time with no packet coming: `idle(now)`, called a few times a second, counts the time since the last frame
as silence (less an allowance for a late packet).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import av
import numpy as np
import webrtcvad

from eca.services.processes.web.options import VadSettings

RATE = 16_000
FRAME_SAMPLES = 320  # 20 ms at 16 kHz: one of the frame lengths the detector takes
FRAME_NS = 20_000_000
LATE_ALLOWANCE_NS = 100_000_000  # a frame this late is network jitter, not silence (idle)
RTP_WRAP = 1 << 32


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
        self.samples = 0  # 16 kHz samples turned into blocks (or counted as silence left out) so far
        self.skipped = 0  # of them, left out by the sender (discontinuous transmission)
        self._next_pts: int | None = None  # the RTP timestamp the next frame has if none is left out
        self._last_arrival_ns: int | None = None
        self.on_block, self.on_turn = on_block, on_turn

    def push(self, frame: av.AudioFrame, arrived_ns: int) -> None:
        """One frame as received (it arrived at `arrived_ns`)."""
        left_out = self._left_out(frame)
        if left_out:
            self.skip(left_out, arrived_ns)
        for out in self._resampler.resample(frame):
            self.push_samples(out.to_ndarray().reshape(-1).astype(np.int16, copy=False), arrived_ns)

    def _left_out(self, frame: av.AudioFrame) -> int:
        """The 16 kHz samples the sender left out before `frame`, from its RTP timestamp (its pts)."""
        if frame.pts is None:
            return 0
        expected, self._next_pts = self._next_pts, (frame.pts + frame.samples) % RTP_WRAP
        if expected is None:
            return 0
        missing = (frame.pts - expected) % RTP_WRAP
        if missing >= RTP_WRAP // 2 or missing * 100 < frame.sample_rate:
            return 0  # a frame again or out of order, or less than 10 ms: nothing left out
        return missing * RATE // frame.sample_rate

    def skip(self, count: int, arrived_ns: int) -> None:
        """`count` samples of silence the sender left out, before samples that arrived at `arrived_ns`: the block
        under way is completed with silence and goes out; whole frames after it are counted, not sent."""
        if len(self._pending):
            fill = min(count, FRAME_SAMPLES - len(self._pending))
            self.push_samples(np.zeros(fill, np.int16), arrived_ns)
            count -= fill
        frames, rest = divmod(count, FRAME_SAMPLES)
        if frames and self.speaking:
            # the turn ends at the frame where the silence reaches stop_s, as it would with every frame sent
            to_stop = max(1, math.ceil(self.settings.stop_s * RATE / FRAME_SAMPLES - 1e-9) - self._quiet_frames)
            if to_stop <= frames:
                self._quiet(to_stop)
                frames -= to_stop
        if frames:
            self._quiet(frames)
        if rest:
            self._pending = np.zeros(rest, np.int16)
            self._pending_ns = arrived_ns - rest * 1_000_000_000 // RATE

    def _quiet(self, frames: int) -> None:
        """`frames` silent frames left out by the sender: counted and judged, not sent."""
        self._recent.extend([False] * min(frames, self.settings.window))
        self._quiet_frames += frames
        self.samples += frames * FRAME_SAMPLES
        self.skipped += frames * FRAME_SAMPLES
        self._judge()

    def idle(self, now_ns: int) -> None:
        """No frame may have come for a while (the sender is silent): the user stops speaking once the time since
        the last voiced frame, the silence since the last frame included, reaches `stop_s`."""
        if not self.speaking or self._last_arrival_ns is None:
            return
        waited_ns = max(0, now_ns - self._last_arrival_ns - LATE_ALLOWANCE_NS)
        if self._quiet_frames * FRAME_NS + waited_ns >= self.settings.stop_s * 1e9:
            self.speaking = False
            self._recent.clear()
            self.on_turn(False)

    def push_samples(self, samples: np.ndarray, arrived_ns: int) -> None:
        """16 kHz mono int16 samples that arrived at `arrived_ns` (the last of them)."""
        self._last_arrival_ns = arrived_ns
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
        self._judge()
        self.on_block(MicBlock(self.samples, capture_ns, pcm, self.speaking))
        self.samples += FRAME_SAMPLES

    def _judge(self) -> None:
        s = self.settings
        if not self.speaking and sum(self._recent) >= s.start_frames:
            self.speaking = True
            self.on_turn(True)
        elif self.speaking and self._quiet_frames * FRAME_SAMPLES / RATE >= s.stop_s:
            self.speaking = False
            self._recent.clear()
            self.on_turn(False)
