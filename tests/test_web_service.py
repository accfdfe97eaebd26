"""The web service end to end with a WebRTC client written in Python (aiortc): the page's offer answered,
the face as video at the asked size, the voice from the bus as audio, the microphone back as speech
turns and audio on the bus, the token rule, and bad requests refused without opening anything.

(tests/test_web_browser.py drives the same service from a real Chromium.)
"""

from __future__ import annotations

import asyncio
import json
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import aiohttp
import av
import numpy as np
import pytest
import soundfile as sf
import zmq
from aiortc import MediaStreamTrack
from aiortc.contrib.media import MediaPlayer
from aiortc.mediastreams import MediaStreamError

from eca.agent.clock import VirtualClock
from eca.protocol.bus import Publisher, Subscriber
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import EmotionState, UserAudio, UserSpeech
from eca.services.processes.audio.resample import resample
from eca.services.processes.runtime import wait_until
from eca.services.processes.web.feeds import Picture
from eca.services.processes.web.options import WebOptions
from eca.services.processes.web.service import WebService
from eca.services.processes.web.tracks import OpusFrames
from eca.services.processes.web.viewers import ViewRequest
from tests.support.bus import BrokerThread, ServiceThread, private_bus_config
from tests.support.web_client import SMALL, Client, post, speak_tone, user_speech_wav

pytestmark = pytest.mark.gl
S = 1_000_000_000


@pytest.fixture
def web() -> Iterator[tuple[BusConfig, WebService]]:
    with private_bus_config(agents=["ada", "bob"]) as config, BrokerThread(config):
        service = WebService(config, WebOptions(port=0, **SMALL))
        with ServiceThread(service):
            yield config, service


@pytest.fixture
def token_web() -> Iterator[tuple[BusConfig, WebService]]:
    with private_bus_config() as config, BrokerThread(config):
        service = WebService(config, WebOptions(port=0, token="s3cret-token", **SMALL))
        with ServiceThread(service):
            yield config, service


def base(service: WebService) -> str:
    return f"http://127.0.0.1:{service.port}/"


def test_the_face_arrives_at_the_asked_size_and_rate(web: tuple[BusConfig, WebService]) -> None:
    config, service = web

    async def main() -> tuple[dict[str, Any], list[Any]]:
        client = Client(base(service), ["ada"])
        answer = await client.connect()
        try:
            await client.frames("ada", "video", 2.0)  # the first frames: connection and keyframe
            return answer, await client.frames("ada", "video", 2.0)
        finally:
            await client.pc.close()

    answer, frames = asyncio.run(main())
    assert (answer["width"], answer["height"], answer["fps"]) == (160, 120, 15.0)
    assert {(f.width, f.height) for f in frames} == {(160, 120)}
    assert len(frames) >= 0.6 * 15 * 2, f"{len(frames)} frames in 2 s at 15 fps"
    picture = frames[-1].to_ndarray(format="rgb24")
    assert picture.std() > 10  # a face, not a blank frame
    assert wait_until(lambda: service._plan is None, 10.0)  # the viewer left: nothing is drawn any more


def test_two_viewers_see_the_same_agent_and_one_page_two_agents(web: tuple[BusConfig, WebService]) -> None:
    config, service = web

    async def main() -> tuple[int, int, int]:
        first, second = Client(base(service), ["ada"]), Client(base(service), ["ada", "bob"])
        await first.connect()
        await second.connect()
        try:
            a, b, c = await asyncio.gather(first.frames("ada", "video", 3.0), second.frames("ada", "video", 3.0),
                                           second.frames("bob", "video", 3.0))
            return len(a), len(b), len(c)
        finally:
            await first.pc.close()
            await second.pc.close()

    counts = asyncio.run(main())
    assert all(n >= 10 for n in counts), counts


def test_the_voice_on_the_bus_is_heard_and_silence_is_silent(web: tuple[BusConfig, WebService]) -> None:
    config, service = web
    ctx = zmq.Context()
    pub = Publisher(ctx, config, "audio")
    pub.wait_ready()

    def speak(seconds: float) -> None:
        speak_tone(pub, seconds)

    async def main() -> tuple[float, float]:
        client = Client(base(service), ["ada"])
        await client.connect()
        try:
            quiet = await client.frames("ada", "audio", 1.5)
            await asyncio.get_running_loop().run_in_executor(None, speak, 1.0)
            loud = await client.frames("ada", "audio", 1.0)
            level = lambda frames: float(np.sqrt(np.mean(np.concatenate(  # noqa: E731
                [f.to_ndarray().astype(np.float64).reshape(-1) for f in frames]) ** 2)))
            return level(quiet[len(quiet) // 2:]), level(loud)
        finally:
            await client.pc.close()

    try:
        quiet, loud = asyncio.run(main())
    finally:
        pub.close()
        ctx.term()
    assert quiet < 50 and loud > 3000, (quiet, loud)


@pytest.fixture(scope="module")
def speech_wav(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return user_speech_wav(tmp_path_factory.mktemp("speech") / "user.wav", "Excuse me, may I ask something?",
                           before_s=1.0, after_s=2.0)


def test_the_users_speech_becomes_turns_and_audio_on_the_bus(web: tuple[BusConfig, WebService],
                                                             speech_wav: Path) -> None:
    config, service = web
    ctx = zmq.Context()
    sub = Subscriber(ctx, config, ["cmd.ada.user_speech", "cmd.bob.user_speech", "stream.ada.user_audio"])
    sub.wait_ready()
    player = MediaPlayer(str(speech_wav))

    async def main() -> None:
        client = Client(base(service), ["ada", "bob"], mic=player.audio)
        await client.connect()
        try:
            await asyncio.sleep(6.0)  # the WAV plays in real time: let it (pacing, not synchronisation)
            assert service.viewers is not None
            (viewer,) = service.viewers.open.values()
            # decoded on the service's event loop (web/mic_decoding.py), not on a thread of aiortc's
            assert viewer.mic_decoding is not None and viewer.mic_decoding.decoded >= 3.0 * 50
        finally:
            await client.pc.close()

    try:
        asyncio.run(main())
        turns: dict[str, list[bool]] = {"ada": [], "bob": []}
        audio = 0
        for got in sub.drain():
            if isinstance(got.message, UserSpeech):
                turns[got.message.agent].append(got.message.speaking)
            elif isinstance(got.message, UserAudio):
                audio += 1
                assert got.message.sample_rate == 16_000 and len(got.message.pcm) == 640
    finally:
        sub.close()
        ctx.term()
    assert turns == {"ada": [True, False], "bob": [True, False]}  # both agents the page watches
    assert audio >= 3.0 * 50  # 20 ms blocks all along


class DtxMicrophone(MediaStreamTrack):
    """A browser's microphone as its Opus encoder sends it when the answer asks `usedtx=1`: every 20 ms frame of
    the WAV that sounds, and of digital silence one every 400 ms (the RTP timestamps jump over the rest)."""

    kind = "audio"

    def __init__(self, wav: Path) -> None:
        super().__init__()
        samples, rate = sf.read(wav, dtype="int16")
        self.pcm = np.round(resample(samples.astype(np.float32), rate, 48_000)).astype(np.int16)
        self.opus = OpusFrames()
        self.k, self.quiet, self.start_ns = 0, 0, time.monotonic_ns()
        self.sent = self.silent_seen = self.silent_sent = 0
        self.last_sound_ns = 0  # when the last frame that sounds was sent

    async def recv(self) -> av.Packet:
        while True:
            if (self.k + 1) * 960 > len(self.pcm):
                raise MediaStreamError("the WAV has played")
            frame = self.pcm[self.k * 960:(self.k + 1) * 960]
            self.k += 1
            await asyncio.sleep(max(0.0, (self.start_ns + self.k * 20_000_000 - time.monotonic_ns()) / 1e9))  # pace
            self.quiet = 0 if frame.any() else self.quiet + 1
            self.silent_seen += self.quiet > 0
            if self.quiet % 20 in (0, 1):
                break
        if not self.quiet:
            self.last_sound_ns = time.monotonic_ns()
        packet = self.opus.encode(frame, (self.k - 1) * 960)
        assert packet is not None
        self.sent += 1
        self.silent_sent += self.quiet > 0
        return packet


def test_a_microphone_with_discontinuous_transmission_gives_the_same_turns_from_a_few_packets(
        web: tuple[BusConfig, WebService], speech_wav: Path) -> None:
    """The answer asks the microphone for Opus DTX; one that honours it sends little in silence, and the turn still
    ends on time: the silence left out is counted, and no packet at all is silence too."""
    config, service = web
    ctx = zmq.Context()
    sub = Subscriber(ctx, config, ["cmd.ada.user_speech", "stream.ada.user_audio"])
    sub.wait_ready()
    mic = DtxMicrophone(speech_wav)
    stopped_at: list[float] = []

    async def main() -> str:
        client = Client(base(service), ["ada"], mic=mic)
        answer = await client.connect()
        try:
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline and not stopped_at:
                got = sub.recv(0.05)
                if got is not None and isinstance(got.message, UserSpeech):
                    turns.append(got.message.speaking)
                    if not got.message.speaking:
                        stopped_at.append(time.monotonic_ns())
                elif got is not None and isinstance(got.message, UserAudio):
                    blocks.append(got.message)
                await asyncio.sleep(0)  # the client's loop runs between reads
        finally:
            await client.pc.close()
        return str(answer["sdp"])

    turns: list[bool] = []
    blocks: list[UserAudio] = []
    try:
        sdp = asyncio.run(main())
    finally:
        sub.close()
        ctx.term()
    mic_section = next(m for m in sdp.split("m=")[1:] if m.startswith("audio") and "a=mid:0\r\n" in m)
    assert "usedtx=1" in mic_section and sdp.count("usedtx=1") == 1  # asked of the microphone alone
    assert turns == [True, False]
    assert mic.silent_seen > 50 and mic.silent_sent <= mic.silent_seen / 4  # the silence mostly not sent
    # the turn ended after the last sound, within stop_s, the late-packet allowance, the idle check and the bus
    waited_s = (stopped_at[0] - mic.last_sound_ns) / 1e9
    assert 0.3 < waited_s < 0.6 + 0.1 + 0.1 + 0.4, waited_s
    assert blocks and all(len(b.pcm) == 640 for b in blocks)
    firsts = [b.first_sample for b in blocks]
    assert firsts == sorted(firsts) and max(np.diff(firsts)) > 10 * 320  # the silence left out: a jump


def test_the_token_rule_holds_for_the_page_and_the_offer(token_web: tuple[BusConfig, WebService]) -> None:
    config, service = token_web

    async def main() -> tuple[list[int], float, float, float]:
        statuses = []
        async with aiohttp.ClientSession() as session:
            for path in ("", "?token=wrong-token", "?token=s3cret-token", "clock", "clock?token=s3cret-token"):
                asked_ms = time.time_ns() / 1e6
                async with session.get(base(service) + path) as response:
                    statuses.append(response.status)
                    answer = await response.json() if path.startswith("clock?") else None
                answered_ms = time.time_ns() / 1e6
        client = Client(base(service), ["ada"], token="wrong-token")
        status, _ = await post(base(service) + "offer", await client.offer_body())
        statuses.append(status)
        await client.pc.close()
        assert answer is not None
        return statuses, asked_ms, float(answer["unix_ms"]), answered_ms

    statuses, asked_ms, clock_ms, answered_ms = asyncio.run(main())
    assert statuses == [403, 403, 200, 403, 200, 403]
    assert asked_ms <= clock_ms <= answered_ms  # GET /clock: this machine's wall clock, when it answered
    assert not service.viewers.open  # nothing else happened


@pytest.mark.parametrize("change, status, words", [
    (lambda b: b.update(type="answer"), 400, "'type'"),
    (lambda b: b.update(sdp="v=0 this is no sdp"), 400, "could not be answered"),
    (lambda b: b.update(agents=["carol"]), 400, "'agents'"),
    (lambda b: b.update(video={"width": 100_000, "height": 120, "fps": 15}), 400, "'video.width'"),
    (lambda b: b.update(video={"width": 160, "height": 120, "fps": float("nan")}), 400, "'video.fps'"),
    (lambda b: b["streams"].append({"mid": "9", "agent": "ada", "kind": "smell"}), 400, "'streams[2].kind'"),
    (lambda b: b.update(sdp="x" * 70_000), 413, "over 65536 bytes"),
])
def test_a_bad_offer_gets_a_clear_error_and_opens_nothing(web: tuple[BusConfig, WebService], change: Any,
                                                          status: int, words: str) -> None:
    config, service = web

    async def main() -> tuple[int, Any]:
        client = Client(base(service), ["ada"])
        body = await client.offer_body()
        change(body)
        try:
            return await post(base(service) + "offer", None, raw=json.dumps(body).encode())
        finally:
            await client.pc.close()

    got_status, answer = asyncio.run(main())
    assert got_status == status and words in answer["error"], answer
    assert not service.viewers.open


def test_garbage_bodies_and_commands_are_refused(web: tuple[BusConfig, WebService]) -> None:
    config, service = web

    async def main() -> list[tuple[int, Any]]:
        url = base(service)
        return [
            await post(url + "offer", None, raw=b"\xff\xfe not json"),
            await post(url + "offer", None, raw=b"[" * 100_00 + b"]" * 100_00),
            await post(url + "offer", [1, 2, 3]),
            await post(url + "command", {"command": {"type": "set_emotion", "agent": "ada", "name": "happy",
                                                     "intensity": 7}}),
            await post(url + "command", {"command": {"type": "emotion", "agent": "ada", "name": "happy"}}),
            await post(url + "command", {"command": {"type": "set_emotion", "agent": "zed", "name": "happy"}}),
            await post(url + "command", {"command": {"type": "set_emotion", "agent": "ada", "name": "happy"}}),
        ]

    answers = asyncio.run(main())
    assert [s for s, _ in answers] == [400, 400, 400, 400, 400, 400, 202]
    assert "intensity" in answers[3][1]["error"] and "set_emotion" in answers[4][1]["error"]


def test_a_commanded_change_is_drawn_at_once_without_raising_the_frame_rate() -> None:
    """On a virtual clock: an emotion that arrives between two slots is drawn early (a quarter period
    after the last frame at the soonest), as the next slot; that slot is not drawn again at its time."""
    clock = VirtualClock(1_000 * S)
    with private_bus_config() as config, BrokerThread(config):
        service = WebService(config, WebOptions(port=0, **SMALL), clock=clock)
        pictures: list[Picture] = []
        put = service.frames.put
        service.frames.put = lambda agent, picture: (pictures.append(picture), put(agent, picture))  # type: ignore[method-assign]
        ctx = zmq.Context()
        pub = Publisher(ctx, config, "dialogue", now_ns=clock.now_ns)
        try:
            with ServiceThread(service):
                pub.wait_ready()
                service.watch(1, ViewRequest(("ada",), 160, 120, 15.0, (), None))
                assert wait_until(lambda: len(pictures) == 1, 10.0)  # slot 0, at once
                period = 1_000_000_000 // 15
                t0 = pictures[0].frame_ns
                assert t0 == 1_000 * S and not pictures[0].early
                clock.set_ns(t0 + 2_000_000)
                pub.publish(EmotionState(agent="ada", name="surprised", transition_s=0.0))
                scene = service.scenes.by_agent["ada"].scene
                assert wait_until(lambda: scene.emotion[0] == "surprised", 10.0)
                clock.set_ns(t0 + 30_000_000)  # past a quarter period after slot 0: drawn now, not at slot 1
                assert wait_until(lambda: len(pictures) == 2, 10.0)
                early = pictures[1]
                assert early.early and early.frame_ns == t0 + 30_000_000
                changed = np.abs(early.yuv.astype(int) - pictures[0].yuv.astype(int)).mean()
                clock.set_ns(t0 + period + 1_000_000)  # slot 1's time: it was drawn early, nothing now
                clock.set_ns(t0 + 2 * period + 1)  # slot 2
                assert wait_until(lambda: len(pictures) >= 3, 10.0)
        finally:
            pub.close()
            ctx.term()
    assert [p.frame_ns - t0 for p in pictures[:3]] == [0, 30_000_000, (2 * S) // 15]
    assert not pictures[2].early
    assert changed > 1.0, f"the early picture shows the new expression: mean change {changed:.2f} levels"


def test_a_browsers_request_for_a_keyframe_reaches_the_shared_encoder(web: tuple[BusConfig, WebService]) -> None:
    """A picture-loss report (PLI) goes to aiortc's sender, whose own encoder is not used: it must reach
    the face's shared stream, which then makes a keyframe for everyone."""
    config, service = web

    async def main() -> tuple[int, int, int]:
        client = Client(base(service), ["ada"])
        await client.connect()
        try:
            await client.frames("ada", "video", 1.0)
            stream = service.encoded.streams[("ada", SMALL["width"], SMALL["height"], SMALL["fps"])]
            assert wait_until(stream._keyframe_allowed, 5.0)  # past the least time between keyframes
            before = stream.keyframes
            receiver = next(t.receiver for t in client.pc.getTransceivers() if t.kind == "video")
            await receiver._send_rtcp_pli(receiver.getSynchronizationSources()[0].source)
            deadline = time.monotonic() + 3.0
            while stream.keyframes == before and time.monotonic() < deadline:
                await asyncio.sleep(0.02)  # polling the stream's count
            return before, stream.keyframes, stream.encoded
        finally:
            await client.pc.close()

    before, after, encoded = asyncio.run(main())
    assert after == before + 1, f"{before} keyframes before the request, {after} after ({encoded} pictures)"


def test_the_drawing_is_ready_before_the_first_viewer_and_kept_between_viewers(
        web: tuple[BusConfig, WebService]) -> None:
    """Making the GL context and compiling the shaders takes the loop a second or more on a loaded machine: an
    instance at rest holds none of it (some 200 MB), and it is done when a page is asked for, while the page loads
    and before its offer comes, then kept while no one watches."""
    config, service = web
    assert service._yuv is None  # at rest
    with urllib.request.urlopen(f"http://127.0.0.1:{service.port}/", timeout=10.0) as response:
        assert response.status == 200
    assert wait_until(lambda: service._yuv is not None, 20.0)
    prepared = service._yuv
    assert prepared is not None and prepared.size == (SMALL["width"], SMALL["height"])
    service.watch(1, ViewRequest(("ada",), SMALL["width"], SMALL["height"], SMALL["fps"], (), None))
    assert wait_until(lambda: service._plan is not None, 10.0)
    with urllib.request.urlopen(f"http://127.0.0.1:{service.port}/", timeout=10.0) as response:
        assert response.status == 200  # another page loading while one watches: what is drawn stays
    assert not wait_until(lambda: service._yuv is not prepared, 1.0)
    service.unwatch(1)
    assert wait_until(lambda: service._plan is None, 10.0)
    assert service._yuv is prepared
    service.watch(2, ViewRequest(("ada",), 2 * SMALL["width"], 2 * SMALL["height"], SMALL["fps"], (), None))
    assert wait_until(lambda: service._yuv is not None and service._yuv is not prepared, 10.0)  # another size
    service.unwatch(2)


def test_what_the_viewers_ask_for_is_worked_out_again_only_when_they_change() -> None:
    """The draw plan follows every page that watches or leaves, at once, and between such changes is the one
    already worked out (the bus loop asks for it at every wake)."""
    with private_bus_config(agents=["ada", "bob"]) as config:
        service = WebService(config, WebOptions(port=0, **SMALL))
        assert service._current_plan() is None
        small = ViewRequest(("ada",), 320, 240, 15.0, (), None, False, ("ada",))
        service.watch(1, small)
        first = service._current_plan()
        assert first is not None and first.drawn_by_pages == ("ada",) and (first.width, first.fps) == (320, 15.0)
        assert service._current_plan() is first  # nothing changed: not worked out again
        service.watch(2, ViewRequest(("bob",), 640, 480, 30.0, (), None, False, ()))
        both = service._current_plan()
        assert both is not None and both is not first
        assert (both.agents, both.drawn_by_pages, both.width, both.fps) == (("bob",), ("ada",), 640, 30.0)
        service.unwatch(2)
        assert service._current_plan() == first
        service.unwatch(1)
        assert service._current_plan() is None
