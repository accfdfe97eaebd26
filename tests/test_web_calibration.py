"""The web service's calibration mode (services/processes/web/calibration.py): flashes (a patch over the drawn
face) and clicks at the whole seconds of the master clock, sent by the face's and the voice's own tracks,
and the offer flag that asks for them.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from agent.clock import NS_PER_S, VirtualClock
from services.processes.web.calibration import (
    BLACK_LUMA,
    CLICK_S,
    NEUTRAL_CHROMA,
    PATCH,
    WHITE_LUMA,
    ClickFeed,
    FlashFeed,
    click_track,
)
from services.processes.web.encoding import VIDEO_RATE
from services.processes.web.feeds import Picture
from services.processes.web.options import WebOptions
from services.processes.web.service import WebService
from tests.support.bus import BrokerThread, ServiceThread, private_bus_config
from tests.support.web_client import SMALL, Client, post

RATE = 48_000
FRAME_NS = 20_000_000  # the voice track's 20 ms


def video_frames(clock: VirtualClock, fps: float, seconds: float, start_ns: int) -> list[tuple[int, bool]]:
    """(slot time, white) of each picture a flash feed gives a stream for `seconds` from `start_ns`, the
    clock moved on a frame at a time so that each is due when asked for."""
    clock.set_ns(start_ns)
    feed = FlashFeed(clock, 64, 48, fps)

    async def main() -> list[tuple[int, bool]]:
        out = []
        last_ns = start_ns - round(NS_PER_S / fps) * 3 // 4  # as a stream asks: most of a period after the last
        for i in range(1, round(seconds * fps) + 1):
            picture = await feed.next_after("calibration", last_ns + round(NS_PER_S / fps) * 3 // 4)
            last_ns = picture.frame_ns
            out.append((picture.frame_ns, bool(picture.yuv[0, 0] > 128)))
            clock.set_ns(start_ns + round(i * NS_PER_S / fps))
        return out

    return asyncio.run(main())


def test_the_flash_is_white_exactly_at_each_whole_second_and_black_between() -> None:
    clock = VirtualClock()
    frames = video_frames(clock, 30.0, 3.0, start_ns=7 * NS_PER_S - 100_000_000)
    white = [t for t, w in frames if w]
    assert white == [7 * NS_PER_S, 8 * NS_PER_S, 9 * NS_PER_S]
    assert len(frames) == 90 and sum(1 for _, w in frames if not w) == 87
    slots = [t for t, _ in frames]
    assert all(abs(b - a - 33_333_333) <= 1 for a, b in zip(slots, slots[1:], strict=False))  # each slot once


def test_at_a_rate_that_misses_the_second_the_nearest_slot_flashes_once_a_second() -> None:
    clock = VirtualClock()
    fps = 24.5  # slots at k / 24.5 s: most whole seconds fall between two
    frames = video_frames(clock, fps, 4.0, start_ns=3 * NS_PER_S - 50_000_000)
    white = [t for t, w in frames if w]
    assert len(white) == 4
    half_period = NS_PER_S / fps / 2
    for second, t in zip(range(3, 7), white, strict=True):
        # within half a frame; at 3 and 5 s two slots are equally near: the earlier flashes
        assert -half_period - 1 <= t - second * NS_PER_S < half_period  # (slot times floored to the ns)


def test_a_track_that_falls_behind_skips_to_the_current_slot() -> None:
    clock = VirtualClock(5 * NS_PER_S)
    feed = FlashFeed(clock, 64, 48, 30.0)
    clock.advance_ns(NS_PER_S + 10_000_000)  # a second late: the slot at 6 s has passed 10 ms ago
    picture = asyncio.run(feed.next_after("calibration", 5 * NS_PER_S))
    assert picture.frame_ns == 6 * NS_PER_S and picture.yuv[0, 0] > 128


def planes(yuv: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    flat = yuv.reshape(-1)
    chroma = (width // 2) * (height // 2)
    return (flat[:width * height].reshape(height, width),
            flat[width * height:width * height + chroma].reshape(height // 2, width // 2),
            flat[width * height + chroma:].reshape(height // 2, width // 2))


@pytest.mark.parametrize("flash", [True, False])
def test_the_patch_lies_over_the_face_as_last_drawn_and_leaves_the_rest_of_it_alone(flash: bool) -> None:
    width, height = 64, 54  # a height that is not a multiple of 4: the chroma planes do not fill whole rows
    rng = np.random.default_rng(7)
    yuv = rng.integers(30, 200, (height * 3 // 2, width), dtype=np.uint8)  # neither white nor black anywhere
    face = Picture(123, yuv, width, height)
    kept = face.yuv.copy()
    slot_ns = 5 * NS_PER_S + (0 if flash else NS_PER_S // 25)  # at 25 fps: the whole second's slot, the next
    feed = FlashFeed(VirtualClock(slot_ns), 320, 240, 25.0, backdrop=lambda: face)  # face drawn at another size
    picture = asyncio.run(feed.next_after("calibration", 4 * NS_PER_S))
    assert (picture.width, picture.height) == (width, height)  # the encoder scales it to the stream's
    assert picture.frame_ns == slot_ns
    inside = planes(picture.yuv, width, height)[0] == (WHITE_LUMA if flash else BLACK_LUMA)
    rows, cols = np.nonzero(inside.any(axis=1))[0], np.nonzero(inside.any(axis=0))[0]
    # one rectangle at PATCH, in whole chroma samples (even bounds), to within a sample
    assert inside[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1].all() and inside.sum() == len(rows) * len(cols)
    for first, last, f0, f1, size in ((rows[0], rows[-1], PATCH[1], PATCH[3], height),
                                      (cols[0], cols[-1], PATCH[0], PATCH[2], width)):
        assert first % 2 == 0 and (last + 1) % 2 == 0
        assert abs(first - f0 * size) <= 1 and abs(last + 1 - f1 * size) <= 1
    y, u, v = planes(picture.yuv, width, height)
    face_y, face_u, face_v = planes(face.yuv, width, height)
    assert np.array_equal(y[~inside], face_y[~inside])
    for plane, original in ((u, face_u), (v, face_v)):
        assert np.all(plane[inside[::2, ::2]] == NEUTRAL_CHROMA)
        assert np.array_equal(plane[~inside[::2, ::2]], original[~inside[::2, ::2]])
    assert np.array_equal(face.yuv, kept)  # the face's own picture, which its viewers are sent, is untouched


def click_samples(clock: VirtualClock, start_ns: int, frames: int) -> np.ndarray:
    """The samples a click track sends in `frames` 20 ms frames from `start_ns`, each asked for when due."""
    clock.set_ns(start_ns)
    track = click_track(clock)

    async def main() -> np.ndarray:
        out = []
        for k in range(frames):
            frame = await track.recv()
            assert frame.sample_rate == RATE and frame.pts == k * 960
            out.append(frame.to_ndarray().reshape(-1))
            clock.advance_ns(FRAME_NS)
        return np.concatenate(out)

    return asyncio.run(main())


@pytest.mark.parametrize("start_ns", [1_980_000_007, 1_995_000_000, 2_000_000_000])
def test_the_click_starts_at_the_sample_of_each_whole_second(start_ns: int) -> None:
    clock = VirtualClock()
    samples = click_samples(clock, start_ns, frames=60)  # 1.2 s: one whole second, maybe two
    click = ClickFeed(RATE).click
    seconds = [s for s in range(1, 5) if start_ns <= s * NS_PER_S < start_ns + 60 * FRAME_NS]
    expected = np.zeros_like(samples)
    for second in seconds:
        first = round((second * NS_PER_S - start_ns) * RATE / NS_PER_S)
        expected[first:first + len(click)] = click[:len(expected) - first]
    assert np.array_equal(samples, expected)
    assert len(click) == round(CLICK_S * RATE) and np.abs(click).max() > 10_000


def test_a_flash_and_its_click_are_at_the_same_master_clock_time() -> None:
    clock = VirtualClock()
    start_ns = 11 * NS_PER_S - 40_000_000
    white = [t for t, w in video_frames(clock, 30.0, 0.1, start_ns) if w]
    samples = click_samples(VirtualClock(), start_ns, frames=5)
    first_click_ns = start_ns + int(np.nonzero(samples)[0][0]) * NS_PER_S // RATE
    assert white == [11 * NS_PER_S]
    # the click's first sample is the first at or after the second (the sine starts at zero: sample 1)
    assert 0 < first_click_ns - white[0] <= 2 * NS_PER_S // RATE


# --- the offer flag, end to end ------------------------------------------------------------------


@pytest.fixture
def web() -> Iterator[WebService]:
    with private_bus_config() as config, BrokerThread(config):
        service = WebService(config, WebOptions(port=0, **SMALL))
        with ServiceThread(service):
            yield service


def patch_of(frame: Any) -> np.ndarray:
    gray = frame.to_ndarray(format="gray")
    h, w = gray.shape
    return gray[round(PATCH[1] * h) + 2:round(PATCH[3] * h) - 2, round(PATCH[0] * w) + 2:round(PATCH[2] * w) - 2]


def rest_of(frame: Any) -> np.ndarray:
    gray = frame.to_ndarray(format="gray")
    h, w = gray.shape
    return gray[round(PATCH[3] * h):, :]  # below the patch


def is_white(frame: Any) -> bool:
    return float(patch_of(frame).mean()) > 128


def base(service: WebService) -> str:
    return f"http://127.0.0.1:{service.port}/"


@pytest.mark.gl
def test_an_offer_asking_for_calibration_gets_flashes_and_clicks_a_second_apart(web: WebService) -> None:
    async def main() -> tuple[list[Any], list[Any]]:
        client = Client(base(web), ["ada"])
        body = await client.offer_body()
        body["calibration"] = True
        status, answer = await post(base(web) + "offer", body)
        assert status == 200, answer
        await client.accept(answer)
        try:
            video, audio = await asyncio.gather(client.frames("ada", "video", 3.5),
                                                client.frames("ada", "audio", 3.5))
            return video, audio
        finally:
            await client.pc.close()

    video, audio = asyncio.run(main())
    flashes = [f.pts for f in video if is_white(f)]
    assert len(flashes) >= 2 and len(video) - len(flashes) > 20
    assert all(abs(b - a - VIDEO_RATE) <= 1 for a, b in zip(flashes, flashes[1:], strict=False))  # 1 s of RTP clock
    # under the patch, the agent's face as drawn for the service's own viewers: far from flat
    assert all(float(rest_of(f).std()) > 10 for f in video[len(video) // 2:])
    loud = [f.pts for f in audio if np.abs(f.to_ndarray()).max() > 3_000]
    clicks = [b for a, b in zip([None, *loud], loud, strict=False) if a is None or b - a > 960 * 5]
    assert len(clicks) >= 2
    assert all(abs(b - a - RATE) <= 960 for a, b in zip(clicks, clicks[1:], strict=False))  # a second apart


@pytest.mark.gl
@pytest.mark.parametrize("value", ["yes", 1, None])
def test_a_calibration_flag_that_is_not_a_boolean_is_refused(web: WebService, value: Any) -> None:
    async def main() -> tuple[int, Any]:
        client = Client(base(web), ["ada"])
        body = await client.offer_body()
        body["calibration"] = value
        try:
            return await post(base(web) + "offer", body)
        finally:
            await client.pc.close()

    status, answer = asyncio.run(main())
    assert status == 400 and "'calibration' must be true or false" in answer["error"]
    assert not web.viewers.open


def test_the_flag_reaches_the_view_request() -> None:
    from services.processes.web.server import parse_offer

    body = {"type": "offer", "sdp": "v=0", "streams": [{"mid": "0", "agent": "ada", "kind": "video"}]}
    _, plain = parse_offer(body, WebOptions(), ("ada",))
    _, calibrating = parse_offer({**body, "calibration": True}, WebOptions(), ("ada",))
    assert not plain.calibration and calibrating.calibration

