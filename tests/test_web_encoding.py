"""The face encoded once per picture for every viewer of the same size and rate: what each viewer's track
sends, when it asks for a keyframe, and how long a stream lives."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Awaitable, Callable
from functools import partial
from typing import Any, TypeVar

import av
import numpy as np
from aiortc.mediastreams import MediaStreamError

from eca.agent.clock import VirtualClock
from eca.services.processes.web.encoding import EncodedStream, EncodedStreams, Vp8Encoder
from eca.services.processes.web.feeds import FrameFeed, Picture
from eca.services.processes.web.tracks import FaceTrack

PERIOD = 33_333_333  # 30 fps
T = TypeVar("T")


def picture(k: int, width: int = 64, height: int = 48) -> Picture:
    """Picture k of a moving gradient (every picture differs), at k periods of the clock."""
    y, x = np.mgrid[0:height, 0:width]
    yuv = np.full((height * 3 // 2, width), 128, np.uint8)
    yuv[:height] = (16 + (x * 3 + y * 2 + k * 9) % 200).astype(np.uint8)
    return Picture(k * PERIOD, yuv, width, height)


def run(main: Callable[[FrameFeed, VirtualClock], Awaitable[T]]) -> T:
    async def wrapped() -> T:
        return await asyncio.wait_for(main(FrameFeed(), VirtualClock(0)), 20.0)
    return asyncio.run(wrapped())


async def put(feed: FrameFeed, k: int, stream: EncodedStream, **size: int) -> None:
    """At picture k's time, put it and wait until the stream has encoded it."""
    assert isinstance(stream.clock, VirtualClock)
    stream.clock.set_ns(max(stream.clock.now_ns(), k * PERIOD))
    before = stream.encoded
    feed.put("ada", picture(k, **size))
    while stream.encoded == before:
        await asyncio.sleep(0.001)  # the encoder runs on an executor thread: poll its count


async def until(condition: Callable[[], bool], what: str) -> None:
    """Poll the stream's state (it moves on the loop and its executor thread) until `condition` holds."""
    while not condition():
        await asyncio.sleep(0.001)  # polling, bounded by run()'s timeout; `what` says what was awaited


def decode(packets: list[av.Packet[Any]]) -> list[av.VideoFrame]:
    decoder = av.CodecContext.create("libvpx", "r")
    return [f for p in packets for f in decoder.decode(p)]


def test_every_track_sends_each_picture_encoded_once() -> None:
    async def main(feed: FrameFeed, clock: VirtualClock) -> tuple[list[list[av.Packet[Any]]], int]:
        stream = EncodedStream(feed.next_after, "ada", 64, 48, 30.0, clock)
        stream.start()
        tracks = [FaceTrack(stream), FaceTrack(stream)]
        got: list[list[av.Packet[Any]]] = [[], []]
        for k in range(1, 7):
            await put(feed, k, stream)
            for track, packets in zip(tracks, got, strict=True):
                packets.append(await track.recv())
        stream.stop()
        return got, stream.encoded

    got, encoded = run(main)
    assert encoded == 6  # six pictures, two viewers: six encodes
    assert [bytes(p) for p in got[0]] == [bytes(p) for p in got[1]]
    assert [p.pts for p in got[0]] == [(k - 1) * PERIOD * 90_000 // 10**9 for k in range(1, 7)]  # from the first
    frames = decode(got[0])
    assert len(frames) == 6 and {(f.width, f.height) for f in frames} == {(64, 48)}
    shown = frames[-1].to_ndarray(format="yuv420p")[:48].astype(int)
    assert np.abs(shown - picture(6).yuv[:48].astype(int)).mean() < 6  # the picture, not another


def test_a_stream_at_a_lower_rate_skips_pictures_and_scales() -> None:
    async def main(feed: FrameFeed, clock: VirtualClock) -> list[int]:
        stream = EncodedStream(feed.next_after, "ada", 64, 48, 10.0, clock)
        stream.start()
        for k in range(1, 13):  # drawn at 30 fps, twice the size
            feed.put("ada", picture(k, 128, 96))
            # the stream has taken the picture (and encoded it) or let it pass: it waits on the feed again
            await until(lambda: "ada" in feed._waiters, f"the stream done with picture {k}")
        stream.stop()
        assert stream.latest is not None
        return [stream.latest.seq, stream.latest.frame_ns // PERIOD, stream.encoder.width]

    seq, last_k, width = run(main)
    assert (seq, last_k, width) == (4, 10, 64)  # pictures 1, 4, 7, 10: one in three, at 64x48


def test_a_track_that_missed_a_picture_asks_for_a_keyframe_and_sends_from_it() -> None:
    async def main(feed: FrameFeed, clock: VirtualClock) -> tuple[list[bool], list[int], int]:
        stream = EncodedStream(feed.next_after, "ada", 64, 48, 30.0, clock)
        stream.start()
        track = FaceTrack(stream)
        sent: list[av.Packet[Any]] = []
        await put(feed, 1, stream)
        sent.append(await track.recv())  # picture 1: the stream's first, a keyframe
        await put(feed, 2, stream)
        await put(feed, 3, stream)  # the track did not send 2: 3 cannot be decoded after 1
        waiting = asyncio.ensure_future(track.recv())
        await put(feed, 31, stream)  # asked for (and a second after the last keyframe): a keyframe
        sent.append(await waiting)
        await put(feed, 32, stream)
        sent.append(await track.recv())
        stream.stop()
        return [p.is_keyframe for p in sent], [round((p.pts or 0) / 3000) for p in sent], stream.keyframes

    keyframes, slots, count = run(main)
    assert slots == [0, 30, 31]  # pictures 1, 31 and 32
    assert keyframes == [True, True, False] and count == 2


def test_a_track_that_joins_a_running_stream_starts_at_a_keyframe() -> None:
    async def main(feed: FrameFeed, clock: VirtualClock) -> tuple[list[bool], int]:
        stream = EncodedStream(feed.next_after, "ada", 64, 48, 30.0, clock)
        stream.start()
        first = FaceTrack(stream)
        for k in range(1, 4):
            await put(feed, k, stream)
            await first.recv()
        late = FaceTrack(stream)
        waiting = asyncio.ensure_future(late.recv())  # picture 3 is no keyframe: the late track asks for one
        await until(lambda: stream._keyframe_wanted, "the late track's request for a keyframe")
        await put(feed, 31, stream)
        packets = [await waiting]
        await put(feed, 32, stream)
        packets.append(await late.recv())
        stream.stop()
        return [p.is_keyframe for p in packets], len(decode(packets))

    keyframes, decoded = run(main)
    assert keyframes == [True, False] and decoded == 2


def test_a_stream_lives_while_tracks_use_it() -> None:
    async def main(feed: FrameFeed, clock: VirtualClock) -> list[int]:
        streams = EncodedStreams(feed.next_after, clock)
        a = streams.use("ada", 64, 48, 30.0)
        b = streams.use("ada", 64, 48, 30.0)
        other = streams.use("ada", 32, 24, 30.0)
        counts = [len(streams.streams), a is b]
        tracks = [FaceTrack(s, on_stop=partial(streams.release, s)) for s in (a, b, other)]
        tracks[0].stop()
        tracks[0].stop()  # a second stop releases nothing more
        counts.append(len(streams.streams))
        tracks[1].stop()
        counts.append(len(streams.streams))
        tracks[2].stop()
        counts.append(len(streams.streams))
        await asyncio.sleep(0)
        return counts

    assert run(main) == [2, True, 2, 1, 0]


def test_the_drawing_thread_wakes_a_waiting_stream() -> None:
    async def main(feed: FrameFeed, clock: VirtualClock) -> int:
        stream = EncodedStream(feed.next_after, "ada", 64, 48, 30.0, clock)
        stream.start()
        track = FaceTrack(stream)
        threading.Timer(0.05, lambda: feed.put("ada", picture(3))).start()
        packet = await track.recv()
        stream.stop()
        return packet.size

    assert run(main) > 0


def test_keyframe_requests_flooding_in_get_one_keyframe_a_quarter_second() -> None:
    async def main(feed: FrameFeed, clock: VirtualClock) -> list[int]:
        stream = EncodedStream(feed.next_after, "ada", 64, 48, 30.0, clock)
        stream.start()
        keyframes_at = []
        for k in range(1, 31):  # a second of pictures, a keyframe asked for before each
            stream.request_keyframe()
            await put(feed, k, stream)
            assert stream.latest is not None
            if stream.latest.keyframe:
                keyframes_at.append(k)
        stream.stop()
        return keyframes_at

    assert run(main) == [1, 9, 17, 25]  # 0.25 s apart: one in 7.5 pictures, the rest not


def test_a_track_waiting_on_a_stream_that_stops_ends_instead_of_waiting_for_ever() -> None:
    async def main(feed: FrameFeed, clock: VirtualClock) -> bool:
        stream = EncodedStream(feed.next_after, "ada", 64, 48, 30.0, clock)
        stream.start()
        waiting = asyncio.ensure_future(FaceTrack(stream).recv())
        await asyncio.sleep(0)  # one turn of the loop: the track runs until it waits on the stream
        stream.stop()  # no picture ever came
        try:
            await waiting
        except MediaStreamError:
            return True
        return False

    assert run(main)


def face_like(k: int, width: int, height: int, background: tuple[int, int, int]) -> Picture:
    """Picture k of a drawn face's layout in yuv420p: a flat `background` (Y, U, V) around a busy oval that
    changes every picture (it keeps the rate control at a coarse quantiser, as a talking face does)."""
    y, x = np.mgrid[0:height, 0:width]
    oval = ((x - width / 2) / (width * 0.3)) ** 2 + ((y - height / 2) / (height * 0.4)) ** 2 < 1
    yuv = np.empty((height * 3 // 2, width), np.uint8)
    yuv[:height] = np.where(oval, 140 + 60 * np.sin(x * 0.21 + k * 0.7) * np.cos(y * 0.17 - k * 0.5), background[0])
    cy, cx = np.mgrid[0:height // 2, 0:width // 2]
    chroma_oval = oval[::2, ::2]
    u = np.where(chroma_oval, 100 + 20 * np.sin(cx * 0.3 + k), background[1])
    v = np.where(chroma_oval, 160 + 20 * np.cos(cy * 0.3 - k), background[2])
    yuv[height:height + height // 4] = u.reshape(height // 4, width)
    yuv[height + height // 4:] = v.reshape(height // 4, width)
    return Picture(k * PERIOD, yuv, width, height)


def test_a_tinted_background_keeps_its_colour_up_to_the_edges_through_keyframes() -> None:
    """The face's background (BT.601 of render.toml's (0.93, 0.95, 0.97): a few levels of chroma off grey)
    decodes as itself along all four edges of the picture, from the first keyframe on and after one asked
    for mid-stream. VP8 predicts the top and left edges' macroblocks from a fixed grey; libvpx's real-time
    mode lost the tint there (U and V decoded as 128) and the grey never refreshed."""
    width, height, background = 640, 480, (223, 131, 125)
    encoder = Vp8Encoder(width, height, 30.0)
    decoder = av.CodecContext.create("libvpx", "r")
    worst: list[int] = []
    for k in range(60):
        data, _ = encoder.encode(face_like(k, width, height, background), keyframe=k in (0, 40))
        frames = decoder.decode(av.Packet(data))
        assert len(frames) == 1  # one picture out for each picture in
        planes = frames[0].to_ndarray().astype(int)
        u = planes[height:height * 5 // 4].reshape(height // 2, width // 2)
        v = planes[height * 5 // 4:].reshape(height // 2, width // 2)
        luma = planes[:height]
        worst.append(max(int(np.abs(edge - want).max()) for plane, want in ((luma, background[0]),
                                                                           (u, background[1]), (v, background[2]))
                         for edge in (plane[0], plane[-1], plane[:, 0], plane[:, -1])))
    assert max(worst) <= 1, f"the edges' largest error in each picture: {worst}"
