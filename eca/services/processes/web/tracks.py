"""The WebRTC tracks a viewer receives: the agent's face (video) and voice (audio), on the master clock.

A browser lines video and audio up by each stream's sender reports, which map a frame's RTP timestamp
to the time the sender sent it. So both tracks send each frame at the time it is meant for: the face
track a picture as soon as it is drawn and encoded (stamped with that time), the voice track 20 ms of
samples when the first of them reaches the output (their DAC time on the master clock, which the audio
service stamps ahead of time, as a sound card's output buffer does). Timestamps (`pts`) are that same
clock, so the browser's own A/V synchronisation does the rest.
"""

from __future__ import annotations

import asyncio
import fractions
from collections.abc import Callable
from typing import Protocol, TypeVar, runtime_checkable

import av
import numpy as np
from aiortc import MediaStreamTrack
from aiortc.mediastreams import MediaStreamError
from av import AudioFrame

from eca.agent.clock import Clock
from eca.services.processes.web.encoding import VIDEO_RATE, EncodedStream

AUDIO_FRAME_S = 0.020  # Opus' packet time: one frame per packet
T = TypeVar("T")


class Samples(Protocol):
    """What a voice track reads: the samples of any span of the master clock (a VoiceFeed)."""

    sample_rate: int

    def take(self, start_ns: int, count: int) -> np.ndarray: ...


@runtime_checkable
class PausingSamples(Samples, Protocol):
    """Samples that also say when they next sound (a VoiceFeed): what a voice that pauses in silence reads."""

    async def wait_for_sound(self, after_ns: int) -> int: ...


class FaceTrack(MediaStreamTrack):
    """One viewer's copy of an encoded face stream: each encoded picture as it comes, stamped from the
    first one this track sent. A picture that cannot be decoded after what this track sent (it missed
    one) is not sent: the track asks the stream for a keyframe and sends from there."""

    kind = "video"

    def __init__(self, stream: EncodedStream, on_stop: Callable[[], None] | None = None) -> None:
        super().__init__()
        self.stream = stream
        self._on_stop = on_stop
        self._sent_seq = -1
        self._first_ns: int | None = None
        self.sent = 0

    async def recv(self) -> av.Packet:
        seen = self._sent_seq
        while True:
            picture = await self.stream.next_after(seen)
            if picture is None:
                raise MediaStreamError("the face's stream stopped")
            if picture.keyframe or (self._sent_seq >= 0 and picture.seq == self._sent_seq + 1):
                break
            self.stream.request_keyframe()
            seen = picture.seq
        self._sent_seq = picture.seq
        if self._first_ns is None:
            self._first_ns = picture.frame_ns
        packet = av.Packet(picture.data)
        packet.is_keyframe = picture.keyframe
        packet.pts = (picture.frame_ns - self._first_ns) * VIDEO_RATE // 1_000_000_000
        packet.time_base = fractions.Fraction(1, VIDEO_RATE)
        self.sent += 1
        return packet

    def stop(self) -> None:
        super().stop()
        if self._on_stop is not None:
            on_stop, self._on_stop = self._on_stop, None
            on_stop()


class OpusFrames:
    """A mono Opus encoder for 20 ms frames at 48 kHz (what the voice's RTP clock counts): one packet per frame,
    stamped by the caller, so a track that skips frames keeps its timestamps on the master clock.

    Opus' restricted low-delay mode (CELT only) at 32 kb/s: it encodes a 20 ms frame of speech in about half the
    time of its VoIP mode (measured on espeak-ng speech: 71-77 µs against 164-180, in packets of about the same
    size: 132 bytes on average against 154 at VoIP's default rate), and its lookahead is 2.5 ms instead of 6.5.
    Every conversation that speaks pays this 50 times a second; a browser decodes either mode."""

    RATE = 48_000
    BIT_RATE = 32_000

    def __init__(self) -> None:
        codec = av.CodecContext.create("libopus", "w")
        assert isinstance(codec, av.AudioCodecContext)
        codec.sample_rate = self.RATE
        codec.layout = "mono"
        codec.format = "s16"
        codec.time_base = fractions.Fraction(1, self.RATE)
        codec.bit_rate = self.BIT_RATE
        codec.options = {"application": "lowdelay"}
        self.codec = codec
        self.time_base = fractions.Fraction(1, self.RATE)

    def encode(self, samples: np.ndarray, pts: int) -> av.Packet | None:
        """The packet of one frame of int16 samples whose first is sample `pts` of the RTP clock."""
        frame = AudioFrame.from_ndarray(samples.reshape(1, -1), format="s16", layout="mono")
        frame.sample_rate = self.RATE
        frame.pts = pts
        frame.time_base = self.time_base
        packets = self.codec.encode(frame)
        if not packets:
            return None
        packet = av.Packet(bytes(packets[-1]))
        packet.pts = pts
        packet.time_base = self.time_base
        return packet


class VoiceTiming:
    """How late the voice tracks of a service hand their frames over, against each frame's time on the master clock:
    the frames, those later than 20 and 60 ms, and the latest (its health says so: a load balancer, an operator, a
    bench can tell an overloaded service from a slow network). On the event loop's thread only."""

    def __init__(self) -> None:
        self.frames = 0
        self.late_20ms = 0
        self.late_60ms = 0
        self.max_late_ns = 0

    def record(self, late_ns: int) -> None:
        self.frames += 1
        if late_ns > 20_000_000:
            self.late_20ms += 1
            if late_ns > 60_000_000:
                self.late_60ms += 1
        self.max_late_ns = max(self.max_late_ns, late_ns)


class VoiceTrack(MediaStreamTrack):
    """One agent's voice in 20 ms frames, each sent when its first sample reaches the output.

    `pause_in_silence`: a frame of pure silence is not sent at all (the voice's RTP timestamps jump over it, as
    with Opus' discontinuous transmission; a browser's jitter buffer plays the pause as silence), so a
    listening agent costs its connection no encoding, encryption nor packets, and no wake-ups either: the
    track sleeps until its feed sounds again (VoiceFeed.wait_for_sound). The track then encodes its own
    packets (mono Opus) and stamps each with its frame's place on the master clock. For a page that draws the
    face itself: its frames follow the voice's clock, which the jump keeps; a server-drawn face's browser lines
    video up with a continuous voice."""

    kind = "audio"

    def __init__(self, feed: Samples | PausingSamples, clock: Clock, pause_in_silence: bool = False,
                 timing: VoiceTiming | None = None, sleep_in_pauses: bool = True) -> None:
        super().__init__()
        self.feed, self.clock = feed, clock
        self.timing = timing  # where each frame's lateness is counted
        # a paused voice sleeps until the feed next sounds instead of waking for every silent frame (what a
        # conversation per viewer saves); `sleep_in_pauses` False keeps it looking at each frame's time
        self._pausing: PausingSamples | None = None
        if pause_in_silence and sleep_in_pauses:
            if not isinstance(feed, PausingSamples):
                raise TypeError(f"a voice that pauses in silence reads a feed that says when it sounds, not {feed!r}")
            self._pausing = feed
        self.rate = feed.sample_rate
        self.samples_per_frame = round(self.rate * AUDIO_FRAME_S)
        self._start_ns: int | None = None
        self._frames = 0
        if pause_in_silence and self.rate != OpusFrames.RATE:
            raise ValueError(f"a voice that pauses in silence is encoded at {OpusFrames.RATE} Hz, not {self.rate}")
        self._opus = OpusFrames() if pause_in_silence else None
        self.skipped = 0  # silent frames not sent

    def frame_start_ns(self, k: int) -> int:
        assert self._start_ns is not None
        return self._start_ns + k * self.samples_per_frame * 1_000_000_000 // self.rate

    async def recv(self) -> AudioFrame | av.Packet:
        if self._start_ns is None:
            self._start_ns = self.clock.now_ns()
        while True:
            k = self._frames
            start_ns = self.frame_start_ns(k)
            if self._pausing is not None:
                sound_ns = await self._pausing.wait_for_sound(start_ns)
                # the frame holding the first sample that sounds; the frames before it are silent, never sent
                first = (sound_ns - self._start_ns) * self.rate // (self.samples_per_frame * 1_000_000_000)
                if first > k:
                    self.skipped += first - k
                    self._frames = first
                    continue
            wait_ns = start_ns - self.clock.now_ns()
            if wait_ns > 0:
                await asyncio.sleep(wait_ns / 1e9)  # pacing to the master clock, not synchronisation
            samples = self.feed.take(start_ns, self.samples_per_frame)
            self._frames += 1
            late_ns = self.clock.now_ns() - start_ns
            if self._opus is None:
                frame = AudioFrame.from_ndarray(samples.reshape(1, -1), format="s16", layout="mono")
                frame.sample_rate = self.rate
                frame.pts = k * self.samples_per_frame
                frame.time_base = fractions.Fraction(1, self.rate)
                return self._sent(frame, late_ns)
            if not samples.any():
                self.skipped += 1
                continue
            packet = self._opus.encode(samples, k * self.samples_per_frame)
            if packet is not None:
                return self._sent(packet, late_ns)

    def _sent(self, frame: T, late_ns: int) -> T:
        """`frame`, handed over `late_ns` after its time (counted in `timing`)."""
        if self.timing is not None:
            self.timing.record(late_ns)
        return frame
