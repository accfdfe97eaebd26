"""One VP8 encode per picture, shared by every viewer of an agent at the same size and rate.

Each viewer's own encoder would encode the same picture once per viewer: the dearest part of a viewer
by far. Here an `EncodedStream` takes the pictures of one agent at one size and rate, encodes each once
(off the event loop) and keeps only the newest encoded picture; each viewer's track sends it, packetized
for its own connection. A picture a viewer missed breaks its decoder's chain until the next keyframe, so
such a viewer asks for one, as does a new viewer and any browser that reports a lost picture (PLI/FIR):
the stream's next picture is then a keyframe, for everyone. `EncodedStreams` keeps one stream per
(agent, size, rate) while tracks use it.
"""

from __future__ import annotations

import asyncio
import fractions
import logging
import statistics
import threading
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass

import av

from eca.agent.clock import Clock
from eca.services.processes.web.feeds import Picture

log = logging.getLogger("web")

VIDEO_RATE = 90_000  # RTP's video clock
BITS_PER_PIXEL = 0.055  # per picture: 500 kbit/s at 640x480, 30 fps (aiortc's own starting rate)
MIN_BITRATE, MAX_BITRATE = 150_000, 3_000_000
KEYFRAME_EVERY_S = 10.0  # a keyframe at least this often, should a browser's request for one be lost
KEYFRAME_GAP_S = 0.25  # at most one asked-for keyframe in this time: a browser flooding requests (PLI)
# costs every viewer a keyframe a frame otherwise

# libvpx's fastest setting that still picks each macroblock's mode by rate and distortion, chroma counted,
# and re-encodes a keyframe whose quantiser came out too coarse (Vp8Encoder says why it must). About 3x the
# CPU of real-time mode (5.7 against 1.6 ms a picture at 640x480 here), once per picture for all viewers.
ENCODE_SPEED: dict[str, str] = {"deadline": "good", "cpu-used": "3"}

PictureSource = Callable[[str, int, int | None], Awaitable[Picture]]  # FrameFeed.next_after's signature


@dataclass(frozen=True)
class EncodedPicture:
    """One picture of a stream, VP8-encoded: its number in the stream and the time it is shown (master
    clock, ns)."""

    seq: int
    frame_ns: int
    data: bytes
    keyframe: bool


class Vp8Encoder:
    """libvpx at a constant bit rate, modes chosen by rate and distortion (ENCODE_SPEED); every picture in,
    one encoded picture out.

    VP8 predicts the macroblocks along a picture's top and left edges from a fixed grey, so there all of a
    flat background's colour is residual, and the face's background is only a few levels of chroma from
    grey. Real-time mode (and "good" above cpu-used 3) judges a mode by its luma's variance alone, blind to
    chroma: it codes those edge blocks as intra blocks whose small chroma residual the quantiser drops, and
    codes keyframes at the coarse quantiser the rate control runs at. The edges decode grey, the blocks
    inward are predicted from them and still ones copy them on: a grey band along the top and left edges
    that never refreshes. Counting chroma, a still background stays a zero-motion copy of a keyframe that
    was given the bits to be right.
    """

    def __init__(self, width: int, height: int, fps: float) -> None:
        bitrate = round(min(MAX_BITRATE, max(MIN_BITRATE, BITS_PER_PIXEL * width * height * fps)))
        codec = av.CodecContext.create("libvpx", "w")
        codec.width, codec.height, codec.pix_fmt = width, height, "yuv420p"
        codec.bit_rate = bitrate
        codec.time_base = fractions.Fraction(1, VIDEO_RATE)
        codec.framerate = fractions.Fraction(round(fps * 1000), 1000)
        codec.gop_size = max(1, round(KEYFRAME_EVERY_S * fps))
        codec.qmin, codec.qmax = 2, 56
        codec.thread_count = 1
        codec.options = {
            **ENCODE_SPEED,
            "lag-in-frames": "0",  # a picture out for every picture in
            "noise-sensitivity": "0",  # a drawn face has no camera noise to filter
            "minrate": str(bitrate),  # minrate = maxrate = bit_rate: constant bit rate
            "maxrate": str(bitrate),
            "bufsize": str(bitrate),  # a one-second rate-control buffer
            "static-thresh": "1",
            "undershoot-pct": "100",
            "overshoot-pct": "15",
            "partitions": "0",
            "error-resilient": "1",  # a lost packet spoils less of what follows
        }
        self.codec = codec
        self.width, self.height = width, height

    def encode(self, picture: Picture, keyframe: bool) -> tuple[bytes, bool]:
        frame = av.VideoFrame.from_ndarray(picture.yuv, format="yuv420p")
        if (picture.width, picture.height) != (self.width, self.height):
            frame = frame.reformat(width=self.width, height=self.height)
        frame.pts = picture.frame_ns * VIDEO_RATE // 1_000_000_000
        frame.time_base = fractions.Fraction(1, VIDEO_RATE)
        frame.pict_type = av.video.frame.PictureType.I if keyframe else av.video.frame.PictureType.NONE
        packets = self.codec.encode(frame)
        return b"".join(bytes(p) for p in packets), any(p.is_keyframe for p in packets)


class EncodedStream:
    """One agent's pictures at one size and rate, encoded once for every track that sends them."""

    def __init__(self, source: PictureSource, agent: str, width: int, height: int, fps: float,
                 clock: Clock) -> None:
        self.source, self.agent, self.clock = source, agent, clock
        self.width, self.height, self.fps = width, height, fps
        self.period_ns = round(1e9 / fps)
        self.encoder = Vp8Encoder(width, height, fps)
        self.latest: EncodedPicture | None = None
        self.encoded = 0
        self.keyframes = 0
        self._encode_times: deque[int] = deque(maxlen=31)
        self._keyframe_wanted = True  # the first picture of a stream is one anyway
        self._last_keyframe_ns: int | None = None
        self._changed = asyncio.Event()
        self._lock = threading.Lock()  # the encoder runs on an executor thread, one picture at a time
        self._task: asyncio.Task[None] | None = None
        self.stopped = False

    def start(self) -> None:
        if self._task is None:
            self._task = asyncio.ensure_future(self._run())

    def stop(self) -> None:
        """Stop encoding; tracks waiting on this stream are told (they may have been moved to another)."""
        self.stopped = True
        self._changed.set()
        if self._task is not None:
            self._task.cancel()
            self._task = None

    @property
    def encode_ns(self) -> int:
        """How long a picture takes to encode, lately (the median; 0 before the first)."""
        return statistics.median_high(self._encode_times) if self._encode_times else 0

    def request_keyframe(self) -> None:
        self._keyframe_wanted = True

    async def next_after(self, seq: int) -> EncodedPicture | None:
        """The newest encoded picture after number `seq` (waits for one); None once the stream stopped."""
        while not self.stopped and (self.latest is None or self.latest.seq <= seq):
            self._changed.clear()
            await self._changed.wait()
        return None if self.stopped else self.latest

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        last_ns = self.clock.now_ns() - self.period_ns
        try:
            while True:
                # a picture most of a period after the last (a lower rate than the drawing's skips), or
                # one drawn early to show a command at once
                picture = await self.source(self.agent, last_ns + self.period_ns * 3 // 4, last_ns)
                last_ns = picture.frame_ns
                keyframe = self._keyframe_wanted and self._keyframe_allowed()
                if keyframe:
                    self._keyframe_wanted = False
                data, is_key = await loop.run_in_executor(None, self._encode, picture, keyframe)
                if not data:
                    continue
                self.encoded += 1
                if is_key:
                    self.keyframes += 1
                    self._last_keyframe_ns = self.clock.now_ns()
                self.latest = EncodedPicture(self.encoded, picture.frame_ns, data, is_key)
                self._changed.set()
        except asyncio.CancelledError:
            raise
        except Exception:  # a stream that stops must say why; its tracks wait, the service carries on
            log.exception("encoding %s at %dx%d stopped", self.agent, self.width, self.height)

    def _keyframe_allowed(self) -> bool:
        last = self._last_keyframe_ns
        return last is None or self.clock.now_ns() - last >= KEYFRAME_GAP_S * 1e9

    def _encode(self, picture: Picture, keyframe: bool) -> tuple[bytes, bool]:
        with self._lock:
            began = self.clock.now_ns()
            encoded = self.encoder.encode(picture, keyframe)
            self._encode_times.append(self.clock.now_ns() - began)
            return encoded


class EncodedStreams:
    """The encoded streams in use, one per (agent, width, height, fps), each kept while a track uses it."""

    def __init__(self, source: PictureSource, clock: Clock) -> None:
        self.source, self.clock = source, clock
        self.streams: dict[tuple[str, int, int, float], EncodedStream] = {}
        self._users: dict[tuple[str, int, int, float], int] = {}

    @property
    def encode_ns(self) -> int:
        """The longest of the streams' recent encode times (0 with none)."""
        return max((s.encode_ns for s in list(self.streams.values())), default=0)

    def use(self, agent: str, width: int, height: int, fps: float) -> EncodedStream:
        key = (agent, width, height, fps)
        stream = self.streams.get(key)
        if stream is None:
            stream = self.streams[key] = EncodedStream(self.source, agent, width, height, fps, self.clock)
            stream.start()
        self._users[key] = self._users.get(key, 0) + 1
        return stream

    def release(self, stream: EncodedStream) -> None:
        key = (stream.agent, stream.width, stream.height, stream.fps)
        if self.streams.get(key) is not stream:
            return
        self._users[key] -= 1
        if self._users[key] <= 0:
            stream.stop()
            del self.streams[key], self._users[key]
