"""The face frames a page draws from, through a real web service and real aiortc peers (no browser, no GL: the
service runs with draw = "browser"): their layout, rate and clock reports; what the avatar routes serve and
refuse; offers that ask the wrong thing; and pages that misbehave on the data channel (garbage, floods, a
hundred channels, coming and going in a loop), dropped cleanly while the page beside them keeps its face.
"""

from __future__ import annotations

import asyncio
import os
import resource
from collections.abc import Iterator
from typing import Any

import aiohttp
import numpy as np
import pytest
import zmq

from eca.protocol.bus import Publisher
from eca.protocol.endpoints import BusConfig
from eca.services.processes.avatar.loader import DEFAULT_HEAD
from eca.services.processes.runtime import wait_until
from eca.services.processes.web.browser_face import FrameLayout, unpack
from eca.services.processes.web.options import WebOptions
from eca.services.processes.web.service import WebService
from tests.support.bus import BrokerThread, ServiceThread, private_bus_config
from tests.support.web_client import FaceClient, post, speak_tone

pytestmark = pytest.mark.skipif(not DEFAULT_HEAD.exists(), reason="the default head is not baked")


@pytest.fixture
def web() -> Iterator[tuple[BusConfig, WebService]]:
    with private_bus_config() as config, BrokerThread(config):
        service = WebService(config, WebOptions(port=0, fps=30.0, max_viewers=8, connect_timeout_s=3.0,
                                                face="head", draw="browser"))
        with ServiceThread(service):
            yield config, service


def layout_of(description: dict[str, Any]) -> FrameLayout:
    return FrameLayout(sum(p["targets"] for p in description["primitives"]), len(description["joints"]))


def rss_mb() -> float:
    with open(f"/proc/{os.getpid()}/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 2**20


def test_frames_come_whole_at_the_rate_asked_with_the_voice_clock(web: tuple[BusConfig, WebService]) -> None:
    config, service = web
    url = f"http://127.0.0.1:{service.port}/"
    ctx = zmq.Context()
    pub = Publisher(ctx, config, "audio")
    pub.wait_ready()

    async def main() -> FaceClient:
        client = FaceClient(url, ["ada"], fps=15.0)
        await client.connect()
        await client.wait_for_frames("ada", 10, 15.0)
        # the agent is silent: its voice pauses, so no packet has gone out and no clock is reported yet
        client.clocks_in_silence = len(client.frames_of("ada", kind=2))  # type: ignore[attr-defined]
        speak_tone(pub, 1.9)  # within what a voice feed holds ahead (2 s)
        start = len(client.frames_of("ada"))
        await asyncio.sleep(2.0)  # counting frames and clock reports over a span while the agent speaks
        client.counted = len(client.frames_of("ada")) - start  # type: ignore[attr-defined]
        await client.pc.close()
        return client

    try:
        client = asyncio.run(main())
    finally:
        pub.close()
        ctx.term()
    description = client.faces["ada"]
    assert description["url"].startswith("avatars/") and description["format"] == "gltf"
    layout = layout_of(description)
    assert layout.size == description["frame_bytes"]
    frames = [unpack(m, layout) for _, m in client.frames_of("ada")]
    seqs = [f[2] for f in frames]
    times = np.array([f[3] for f in frames])
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    span_s = (times[-1] - times[0]) / 1000
    assert 0.8 * 15 <= (len(times) - 1) / span_s <= 1.15 * 15, (len(times), span_s)  # made at the rate asked
    assert client.counted > 0  # type: ignore[attr-defined]  # and they kept coming
    assert np.median(np.diff(times)) == pytest.approx(1000 / 15, abs=12)
    for _slot, _flags, _seq, _t, weights, quats in frames:
        assert weights.min() >= 0.0 and weights.max() <= 1.0
        assert np.allclose(np.linalg.norm(quats, axis=1), 1.0, atol=1e-3)
    assert client.clocks_in_silence == 0  # type: ignore[attr-defined]
    clocks = client.frames_of("ada", kind=2)
    assert len(clocks) >= 4  # a few voice-clock reports a second once the voice sounds


def test_the_avatar_routes_serve_the_avatar_and_nothing_beside_it(web: tuple[BusConfig, WebService]) -> None:
    _config, service = web
    url = f"http://127.0.0.1:{service.port}/"

    async def main() -> dict[str, tuple[int, bytes]]:
        client = FaceClient(url, ["ada"])
        await client.connect()
        avatar = client.faces["ada"]["url"]
        await client.pc.close()
        out = {}
        async with aiohttp.ClientSession() as session:
            for path in (avatar, "avatars/0/..%2F..%2Fservice.py", "avatars/0/%2e%2e/%2e%2e/server.py",
                         "avatars/0/loader.py", "avatars/7/default_head.glb", "avatars/x/default_head.glb",
                         "avatars/0/", "static/../server.py", "static/%2e%2e/server.py", "static/vendor/three/LICENSE",
                         "static/vendor/three/three.module.js", "static/face3d.js"):
                async with session.get(url + path) as response:
                    out[path] = (response.status, await response.read())
        return out

    got = asyncio.run(main())
    first = next(iter(got))
    assert got[first] == (200, DEFAULT_HEAD.read_bytes())
    for path, (status, _body) in got.items():
        if path.startswith("static/vendor/three/three") or path == "static/face3d.js" or path == first:
            assert status == 200, path
        else:
            assert status == 404, (path, status)


@pytest.mark.parametrize("change, error", [
    ({"draw_here": ["bob"]}, "not one of the agents watched"),
    ({"draw_here": "ada"}, "must be a list"),
    ({"draw_here": ["ada", "ada"]}, "must be a list of the watched agents"),
    ({"draw_here": []}, "draws no faces"),
    ({"streams": [{"mid": "0", "agent": "ada", "kind": "video"}]}, "takes an audio section and no video"),
])
def test_offers_asking_the_wrong_drawing_are_refused(web: tuple[BusConfig, WebService], change: dict[str, Any],
                                                     error: str) -> None:
    _config, service = web
    url = f"http://127.0.0.1:{service.port}/"

    async def main() -> tuple[int, Any]:
        client = FaceClient(url, ["ada"])
        body = await client.offer_body()
        status, answer = await post(url + "offer", {**body, **change})
        await client.pc.close()
        return status, answer

    status, answer = asyncio.run(main())
    assert status == 400 and error in answer["error"], answer
    assert not service.viewers.open


def test_a_misbehaving_page_is_closed_and_the_page_beside_it_keeps_its_face(
        web: tuple[BusConfig, WebService]) -> None:
    _config, service = web
    url = f"http://127.0.0.1:{service.port}/"

    async def main() -> tuple[int, int]:
        steady = FaceClient(url, ["ada"], fps=15.0)
        await steady.connect()
        await steady.wait_for_frames("ada", 5, 15.0)
        flooding = FaceClient(url, ["ada"])
        await flooding.connect()
        await flooding.wait_for_frames("ada", 1, 15.0)
        for k in range(100):  # a hundred more channels
            flooding.pc.createDataChannel(f"extra-{k}")
        junk = [b"", b"\x00" * 65_000, "not bytes", b"\xff" * 3] * 30
        for message in junk:  # garbage, huge and many on the face channel
            flooding.channel.send(message)
        before = len(steady.frames_of("ada"))
        await asyncio.sleep(2.0)  # the steady page's frames over the flood
        during = len(steady.frames_of("ada")) - before
        for _ in range(100):  # the server closes the flooding page (its peer connection ends)
            if flooding.pc.connectionState == "closed" or len(service.viewers.open) == 1:
                break
            await asyncio.sleep(0.1)  # polling the server's side
        assert len(service.viewers.open) == 1, "the flooding page is still open"
        await flooding.pc.close()
        await steady.pc.close()
        return during, len(flooding.frames_of("ada"))

    during, _flooded = asyncio.run(main())
    assert during >= 0.7 * 30, f"the steady page got {during} frames in 2 s at 15 fps"
    assert wait_until(lambda: not service.viewers.open, 10.0), service.viewers.open


def test_pages_coming_and_going_in_a_loop_leave_nothing_behind(web: tuple[BusConfig, WebService]) -> None:
    _config, service = web
    url = f"http://127.0.0.1:{service.port}/"

    async def cycle(n: int) -> None:
        for _ in range(n):
            client = FaceClient(url, ["ada"])
            await client.connect()
            await client.wait_for_frames("ada", 2, 15.0)
            await client.pc.close()

    asyncio.run(cycle(5))  # warm: the avatar loaded, the first peers' libraries in place
    assert wait_until(lambda: not service.viewers.open, 10.0)
    level = rss_mb()
    asyncio.run(cycle(30))
    assert wait_until(lambda: not service.viewers.open, 10.0), service.viewers.open
    assert wait_until(lambda: service._plan is None, 5.0)
    grown = rss_mb() - level
    assert grown < 25.0, f"{grown:.1f} MB more after 30 pages came and went"
