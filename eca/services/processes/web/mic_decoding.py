"""A browser's microphone decoded on the event loop, as its packets arrive, instead of on a thread of its own.

aiortc gives every receiver a decoder thread: each frame goes to it through a queue and comes back to the event
loop through `run_coroutine_threadsafe`. For a microphone's 20 ms Opus frames that handover costs far more than
the decoding (libopus: about 30 µs a frame here): with a conversation per visitor, forty such threads took 14 % of
a core between them at N = 40 (bench/conversations.py, per-thread CPU from /proc), nearly all of it waking up and
taking the interpreter's lock from the two threads that send the voices and the faces, which it delayed too.

`decode_on_loop(receiver)` puts a stand-in where the receiver keeps its decoder queue, before the receiver
starts: a decoder for the codec then runs where the packet is handled (on the event loop), and its frames go
straight into the track's queue. The receiver's thread is still started, and waits for the stop alone, which the
stand-in hands it: the track then ends as before.

The decoder is aiortc's for the codec, but for Opus one that decodes to mono (`mic_decoder`): a microphone is one
voice, which the service takes as mono 16 kHz (web/microphone.py), and libopus decodes it to mono in a quarter
less time than to aiortc's stereo (19.5 against 25.7 us a 20 ms frame here), the downmix after it also less.
"""

from __future__ import annotations

import asyncio
import logging
import queue
from collections.abc import Callable
from typing import Any

from aiortc import RTCRtpReceiver
from aiortc.codecs import get_decoder
from aiortc.codecs.opus import OpusDecoder

log = logging.getLogger(__name__)

_QUEUE = "_RTCRtpReceiver__decoder_queue"  # aiortc 1.9-1.x keep the decoder's input here ...
_THREAD = "_RTCRtpReceiver__decoder_thread"  # ... and the thread that reads it, once receive() started it


class MonoOpusDecoder(OpusDecoder):
    """aiortc's Opus decoder, decoding to one channel (libopus downmixes a stereo stream itself)."""

    def __init__(self) -> None:
        super().__init__()
        self.codec.layout = "mono"


def mic_decoder(codec: Any) -> Any:
    """The decoder of a microphone's codec: mono for Opus, else aiortc's."""
    return MonoOpusDecoder() if codec.name.lower() == "opus" else get_decoder(codec)


class DecodeOnLoop:
    """Stands in for a receiver's decoder queue: `put` (from the receiver, on the event loop) decodes a frame at
    once and hands its frames to the track; `get` (the receiver's thread) returns only the stop."""

    def __init__(self, frames: asyncio.Queue[Any], make_decoder: Callable[[Any], Any] = mic_decoder) -> None:
        self._frames = frames
        self._make_decoder = make_decoder  # a codec's decoder (mic_decoder's, unless a caller has its own)
        self._stop: queue.SimpleQueue[None] = queue.SimpleQueue()
        self._decoder: Any = None
        self._codec_name: str | None = None
        self.decoded = 0  # frames decoded here
        self.failed = 0  # frames the decoder refused

    def put(self, task: tuple[Any, Any] | None) -> None:
        if task is None:
            self._stop.put(None)  # the receiver stops: its thread ends the track
            return
        codec, encoded_frame = task
        if not encoded_frame.data:
            # An RTP packet with no payload: FFmpeg takes an empty packet as the end of the stream and refuses
            # every frame after it, so one such packet from a page would end its microphone's decoding for good.
            self.failed += 1
            return
        if codec.name != self._codec_name:
            self._decoder, self._codec_name = self._make_decoder(codec), codec.name
        try:
            frames = self._decoder.decode(encoded_frame)
        except Exception as exc:  # a page's bytes: whatever the decoder makes of them, the frame goes
            # The frame is dropped, whatever the error: this runs inside the connection's packet handling, which an
            # exception would end. And the decoder is made anew for the next frame (a voice's decoder holds only a
            # few ms of state), in case the error left it refusing everything. Said for the first, then every
            # 1,000th (a page can send nothing but such).
            self.failed += 1
            self._codec_name = None
            if self.failed % 1000 == 1:
                log.warning("a microphone frame did not decode (%s: %s): dropped (%d so far)", type(exc).__name__,
                            exc, self.failed)
            return
        self.decoded += 1
        for frame in frames:
            self._frames.put_nowait(frame)

    def get(self) -> None:
        return self._stop.get()


def decode_on_loop(receiver: RTCRtpReceiver, make_decoder: Callable[[Any], Any] = mic_decoder) -> DecodeOnLoop | None:
    """Make `receiver` decode on the event loop (see the module), with `make_decoder`'s decoder for a codec; None,
    and aiortc's thread decodes as it always did, when the receiver has started already or this aiortc keeps its
    queue elsewhere."""
    track = receiver.track
    frames = getattr(track, "_queue", None)
    if (not isinstance(getattr(receiver, _QUEUE, None), queue.Queue) or getattr(receiver, _THREAD, 0) is not None
            or not isinstance(frames, asyncio.Queue)):
        log.warning("this aiortc's receiver is not the one expected: its frames are decoded on its own thread")
        return None
    stand_in = DecodeOnLoop(frames, make_decoder)
    setattr(receiver, _QUEUE, stand_in)
    return stand_in
