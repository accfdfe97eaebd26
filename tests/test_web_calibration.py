"""The web service's calibration mode (services/processes/web/calibration.py): a patch on the agent's own
pictures that flashes white on the one for each whole second, a click added to the agent's voice at each
whole second, and the offer flag that asks for them.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from eca.agent.clock import NS_PER_S, VirtualClock
from eca.services.processes.scene.schedule import FrameSchedule
from eca.services.processes.web.calibration import (
    BLACK_LUMA,
    CLICK_S,
    NEUTRAL_CHROMA,
    PATCH,
    WHITE_LUMA,
    ClickFeed,
    FlashFeed,
)
from eca.services.processes.web.encoding import VIDEO_RATE
from eca.services.processes.web.feeds import FrameFeed, Picture, VoiceFeed
from eca.services.processes.web.options import WebOptions
from eca.services.processes.web.service import WebService
from eca.services.processes.web.tracks import Samples, VoiceTrack
from tests.support.bus import BrokerThread, ServiceThread, private_bus_config
from tests.support.web_client import SMALL, Client, post

RATE = 48_000
FRAME_NS = 20_000_000  # the voice track's 20 ms
W, H = 64, 48


def face_picture(frame_ns: int, early: bool = False, seed: int = 0) -> Picture:
    """A stand-in for a drawn face: noise that is neither white nor black anywhere."""
    yuv = np.random.default_rng(seed).integers(30, 200, (H * 3 // 2, W), dtype=np.uint8)
    return Picture(frame_ns, yuv, W, H, early)


def marked(times: list[tuple[int, bool]], fps: float) -> list[Picture]:
    """What a flash feed makes of faces drawn at `times` ((frame time, drawn early)), taken as a stream
    takes them."""
    faces = FrameFeed()
    feed = FlashFeed(faces)
    period_ns = round(NS_PER_S / fps)

    async def main() -> list[Picture]:
        out = []
        last_ns = times[0][0] - period_ns
        for i, (t_ns, early) in enumerate(times):
            faces.put("ada", face_picture(t_ns, early, seed=i))
            picture = await asyncio.wait_for(feed.next_after("ada", last_ns + period_ns * 3 // 4, last_ns), 1.0)
            last_ns = picture.frame_ns
            out.append(picture)
        return out

    return asyncio.run(main())


def is_white_picture(picture: Picture) -> bool:
    return bool(picture.yuv[0, 0] == WHITE_LUMA)


@pytest.mark.parametrize("fps", [30.0, 25.0, 15.0])
def test_the_picture_for_each_whole_second_flashes_and_the_others_do_not(fps: float) -> None:
    clock = VirtualClock(7 * NS_PER_S - 200_000_000)
    schedule = FrameSchedule(clock, fps, t0_ns=0)  # the web service's frames: on the master clock's grid
    times = [(schedule.slot_ns(schedule.slot + k), False) for k in range(round(3.0 * fps))]
    out = marked(times, fps)
    assert [p.frame_ns for p in out] == [t for t, _ in times]  # the face's pictures, at the face's times
    assert [p.frame_ns for p in out if is_white_picture(p)] == [7 * NS_PER_S, 8 * NS_PER_S, 9 * NS_PER_S]
    assert all(p.yuv[0, 0] == BLACK_LUMA for p in out if not is_white_picture(p))


def test_a_picture_drawn_early_does_not_flash_and_a_second_without_its_picture_has_none() -> None:
    times = [(5 * NS_PER_S, False), (5 * NS_PER_S + 21_000_000, True),  # a command, drawn early
             (5 * NS_PER_S + 66_666_666, False), (5 * NS_PER_S + 966_666_666, False),
             (6 * NS_PER_S + 5_000_000, True),  # 6 s drawn early: no flash for it
             (6 * NS_PER_S + 33_333_333, False), (7 * NS_PER_S, False)]
    out = marked(times, 30.0)
    assert [is_white_picture(p) for p in out] == [True, False, False, False, False, False, True]
    assert out[1].early and not out[0].early  # an early picture stays one: every viewer takes it


def planes(yuv: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    flat = yuv.reshape(-1)
    chroma = (width // 2) * (height // 2)
    return (flat[:width * height].reshape(height, width),
            flat[width * height:width * height + chroma].reshape(height // 2, width // 2),
            flat[width * height + chroma:].reshape(height // 2, width // 2))


@pytest.mark.parametrize("flash", [True, False])
def test_the_patch_lies_over_the_face_and_leaves_the_rest_of_it_and_the_face_itself_alone(flash: bool) -> None:
    width, height = 64, 54  # a height that is not a multiple of 4: the chroma planes do not fill whole rows
    rng = np.random.default_rng(7)
    yuv = rng.integers(30, 200, (height * 3 // 2, width), dtype=np.uint8)  # neither white nor black anywhere
    t_ns = 5 * NS_PER_S + (0 if flash else NS_PER_S // 2)
    face = Picture(t_ns, yuv, width, height)
    kept = face.yuv.copy()
    faces = FrameFeed()
    faces.put("ada", face)
    picture = asyncio.run(FlashFeed(faces).next_after("ada", t_ns - NS_PER_S // 25))
    assert (picture.width, picture.height, picture.frame_ns) == (width, height, t_ns)
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


def track_samples(feed: Samples, clock: VirtualClock, start_ns: int, frames: int) -> np.ndarray:
    """The samples a voice track on `feed` sends in `frames` 20 ms frames from `start_ns`, each asked for when due."""
    clock.set_ns(start_ns)
    track = VoiceTrack(feed, clock)

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
    feed = ClickFeed(sample_rate=RATE)
    samples = track_samples(feed, VirtualClock(), start_ns, frames=60)  # 1.2 s: one whole second, maybe two
    click = feed.click
    seconds = [s for s in range(1, 5) if start_ns <= s * NS_PER_S < start_ns + 60 * FRAME_NS]
    expected = np.zeros_like(samples)
    for second in seconds:
        first = round((second * NS_PER_S - start_ns) * RATE / NS_PER_S)
        expected[first:first + len(click)] = click[:len(expected) - first]
    assert np.array_equal(samples, expected)
    assert len(click) == round(CLICK_S * RATE) and np.abs(click).max() > 10_000


def test_the_clicks_are_added_to_the_agents_voice_and_a_loud_sum_is_clipped() -> None:
    voice = VoiceFeed(RATE)
    start_ns = 3 * NS_PER_S - 5_000_000  # a span with the click at 3 s, 5 ms (240 samples) in
    count = 2 * 960
    tone = np.round(20_000 * np.sin(np.arange(count) * 0.05)).astype(np.int16)
    voice.add(start_ns, tone, RATE)
    clicks = ClickFeed(None, RATE).take(start_ns, count)
    mixed = ClickFeed(voice, RATE).take(start_ns, count)
    expected = np.clip(tone.astype(np.int32) + clicks, -32768, 32767)
    assert np.array_equal(mixed, expected) and mixed.dtype == np.int16
    assert np.count_nonzero(clicks[:240]) == 0 and np.count_nonzero(clicks[241:720])  # the click is there
    assert mixed.max() == 32767 or mixed.min() == -32768  # 20 000 + 16 383 would wrap without the clip
    with pytest.raises(ValueError, match="16000 Hz"):
        ClickFeed(VoiceFeed(16_000), RATE)


def test_a_flash_and_its_click_are_at_the_same_master_clock_time() -> None:
    faces = FrameFeed()
    faces.put("ada", face_picture(11 * NS_PER_S))
    picture = asyncio.run(FlashFeed(faces).next_after("ada", 11 * NS_PER_S - 30_000_000))
    assert is_white_picture(picture)
    start_ns = 11 * NS_PER_S - 40_000_000
    samples = track_samples(ClickFeed(sample_rate=RATE), VirtualClock(), start_ns, frames=5)
    first_click_ns = start_ns + int(np.nonzero(samples)[0][0]) * NS_PER_S // RATE
    # the click's first sample is the first at or after the picture's time (the sine starts at zero: sample 1)
    assert 0 < first_click_ns - picture.frame_ns <= 2 * NS_PER_S // RATE


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
def test_an_offer_asking_for_calibration_gets_the_agent_with_flashes_and_clicks_a_second_apart(web: WebService) -> None:
    hum = np.round(2_000 * np.sin(2 * np.pi * 300 * np.arange(RATE) / RATE)).astype(np.int16)  # 1 s, under a click

    async def main() -> tuple[list[Any], list[Any]]:
        client = Client(base(web), ["ada"])
        body = await client.offer_body()
        body["calibration"] = True
        status, answer = await post(base(web) + "offer", body)
        assert status == 200, answer
        await client.accept(answer)
        web.voices["ada"].add(web.clock.now_ns() + 1_000_000_000, hum, RATE)  # the agent's voice, as played
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
    peaks = [int(np.abs(f.to_ndarray()).max()) for f in audio]
    loud = [f.pts for f, p in zip(audio, peaks, strict=True) if p > 3_000]
    clicks = [b for a, b in zip([None, *loud], loud, strict=False) if a is None or b - a > 960 * 5]
    assert len(clicks) >= 2
    assert all(abs(b - a - RATE) <= 960 for a, b in zip(clicks, clicks[1:], strict=False))  # a second apart
    humming = sum(1 for p in peaks if 1_000 < p <= 3_000)  # the voice, in the frames without a click
    assert 40 <= humming <= 52  # its second is 50 frames of 20 ms, a click's frame or two louder


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
    from eca.services.processes.web.server import parse_offer

    body = {"type": "offer", "sdp": "v=0", "streams": [{"mid": "0", "agent": "ada", "kind": "video"}]}
    _, plain = parse_offer(body, WebOptions(), ("ada",))
    _, calibrating = parse_offer({**body, "calibration": True}, WebOptions(), ("ada",))
    assert not plain.calibration and calibrating.calibration

