"""The WebRTC tracks a viewer receives: the agent's face (video) and voice (audio), on the master clock.

A browser lines video and audio up by each stream's sender reports, which map a frame's RTP timestamp
to the time the sender sent it. So both tracks send each frame at the time it is meant for: the face
track a picture as soon as it is drawn (composed for that very frame slot), the voice track 20 ms of
samples when the first of them reaches the output (their DAC time on the master clock, which the audio
service stamps ahead of time, as a sound card's output buffer does). Timestamps (`pts`) are that same
clock, so the browser's own A/V synchronisation does the rest.
"""

from __future__ import annotations

import asyncio
import fractions

from aiortc import MediaStreamTrack
from av import AudioFrame, VideoFrame

from agent.clock import Clock
from services.processes.web.feeds import FrameFeed, VoiceFeed

VIDEO_RATE = 90_000  # RTP's video clock
AUDIO_FRAME_S = 0.020  # Opus' packet time: one frame per packet


class FaceTrack(MediaStreamTrack):
    """One agent's face at `fps` at most, at `width` x `height` (scaled if drawn at another size)."""

    kind = "video"

    def __init__(self, feed: FrameFeed, agent: str, width: int, height: int, fps: float, epoch_ns: int) -> None:
        super().__init__()
        self.feed, self.agent = feed, agent
        self.width, self.height = width, height
        self.period_ns = round(1e9 / fps)
        self.epoch_ns = epoch_ns
        self._last_ns = epoch_ns - self.period_ns * 3 // 4  # the first picture is at the epoch or later: pts >= 0
        self.sent = 0

    async def recv(self) -> VideoFrame:
        # a picture at least most of a period after the last one: a lower rate than the drawing's skips
        picture = await self.feed.next_after(self.agent, self._last_ns + self.period_ns * 3 // 4)
        self._last_ns = picture.frame_ns
        frame = VideoFrame.from_ndarray(picture.yuv, format="yuv420p")
        if (picture.width, picture.height) != (self.width, self.height):
            frame = frame.reformat(width=self.width, height=self.height)
        frame.pts = (picture.frame_ns - self.epoch_ns) * VIDEO_RATE // 1_000_000_000
        frame.time_base = fractions.Fraction(1, VIDEO_RATE)
        self.sent += 1
        return frame


class VoiceTrack(MediaStreamTrack):
    """One agent's voice in 20 ms frames, each sent when its first sample reaches the output."""

    kind = "audio"

    def __init__(self, feed: VoiceFeed, clock: Clock) -> None:
        super().__init__()
        self.feed, self.clock = feed, clock
        self.rate = feed.sample_rate
        self.samples_per_frame = round(self.rate * AUDIO_FRAME_S)
        self._start_ns: int | None = None
        self._frames = 0

    def frame_start_ns(self, k: int) -> int:
        assert self._start_ns is not None
        return self._start_ns + k * self.samples_per_frame * 1_000_000_000 // self.rate

    async def recv(self) -> AudioFrame:
        if self._start_ns is None:
            self._start_ns = self.clock.now_ns()
        start_ns = self.frame_start_ns(self._frames)
        wait_ns = start_ns - self.clock.now_ns()
        if wait_ns > 0:
            await asyncio.sleep(wait_ns / 1e9)  # pacing to the master clock, not synchronisation
        samples = self.feed.take(start_ns, self.samples_per_frame)
        frame = AudioFrame.from_ndarray(samples.reshape(1, -1), format="s16", layout="mono")
        frame.sample_rate = self.rate
        frame.pts = self._frames * self.samples_per_frame
        frame.time_base = fractions.Fraction(1, self.rate)
        self._frames += 1
        return frame
