"""The web front-end in a real headless Chromium (Debian's chromium and chromium-driver, through selenium)
with fake media devices: the page connects to `eca up --web`, the face is decoded at the asked size and
rate, the voice is heard during a say and silent otherwise, the user's speech (a WAV as the microphone)
reaches the bus and interrupts the agent, the token rule holds, a second browser sees the same agent, and
the decoded picture has the face's background colour up to its edges.
"""

from __future__ import annotations

import base64
import io
import re
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zmq

from eca.agent.vocabulary import EYE_MODES
from eca.protocol.bus import Subscriber
from eca.protocol.client import AgentClient
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import Say, SpeechFinished, SpeechInterrupted, UserAudio, UserSpeech
from eca.services.processes.renderer.config import load_render_config
from eca.services.processes.web.options import WebOptions
from eca.services.processes.web.service import WebService
from eca.services.tools.child_processes import LineReader, eca_command
from tests.support.browser import browser_available, chromium, page_stats, wait_for, wait_for_frames
from tests.support.bus import BrokerThread, ServiceThread, private_bus_config, running
from tests.support.web_client import user_speech_wav

pytestmark = [pytest.mark.slow, pytest.mark.skipif(browser_available() is not None,
                                                   reason=str(browser_available()))]
RATE = 16_000
LOGS: dict[str, LineReader] = {}  # what each instance printed, by its page's address: for failure messages


def said(url: str, count: int = 30) -> str:
    """The instance's last lines from the web service and the supervisor."""
    lines = [line for line in LOGS[url].lines if line.startswith(("[web]", "[up]"))]
    return "\n".join(lines[-count:])


@pytest.fixture(scope="module")
def instance() -> Iterator[tuple[BusConfig, str]]:
    """`eca up --web` (dialogue, gaze, audio and the web service) on a free port; its page's address. Its
    viewer watchdog is strict (2 s without receiver reports on any stream): a healthy page must stay, a
    closed one goes soon."""
    with private_bus_config(services=["dialogue", "gaze", "audio"]) as config:
        text = config.config_path.read_text()
        strict, found = re.subn(r"^silent_timeout_s = [0-9.]+", "silent_timeout_s = 2.0", text, count=1,
                                flags=re.MULTILINE)
        assert found, "configs/default.toml has a [web] silent_timeout_s to tighten"
        config.config_path.write_text(strict)
        argv = eca_command("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet",
                           "--web", "--web-port", "0")
        with running(argv) as (proc, reader):
            reader.wait_for("[up] ready in", 90.0)
            url = served_url(reader)
            LOGS[url] = reader
            yield config, url


def test_a_healthy_page_stays_connected_past_the_watchdog(instance: tuple[BusConfig, str]) -> None:
    """Chromium reports on a received audio stream only every 2.5-7.5 s; the watchdog counts every stream's
    reports, so a page that receives the face and the voice outlives a 2 s watchdog many times over."""
    config, url = instance
    with chromium() as driver:
        connect(driver, url + "?mic=0&width=160&height=120&fps=10")
        time.sleep(9.0)  # the behaviour under test is what happens over this time (not synchronisation)
        assert driver.execute_script("return window.eca.state") == "connected"
        before = video_stats(driver)["framesDecoded"]
        deadline = time.monotonic() + 5.0
        while video_stats(driver)["framesDecoded"] <= before and time.monotonic() < deadline:
            time.sleep(0.1)  # polling the page's counters
        assert video_stats(driver)["framesDecoded"] > before  # frames still arrive


def served_url(reader: LineReader) -> str:
    line = reader.lines[reader.wait_for("[web] INFO serving http://", 10.0)]
    match = re.search(r"(http://\S+/)", line)
    assert match
    return match.group(1)


def connect(driver: Any, url: str) -> None:
    driver.get(url)
    driver.find_element("id", "connect").click()
    wait_for(driver, "return window.eca.state", 30.0, "the page connecting", lambda s: s == "connected")


def video_stats(driver: Any) -> dict[str, Any]:
    stats = page_stats(driver)
    assert stats is not None and stats["video"], stats
    return stats["video"][0]


def frames_decoded(driver: Any, at_least: int, timeout_s: float = 15.0) -> int:
    """Poll the page's video stats until `at_least` frames are decoded (or the time is up); the count."""
    def decoded() -> int:
        stats = page_stats(driver)  # no video entry until its first packets arrive
        return int(stats["video"][0]["framesDecoded"] or 0) if stats and stats["video"] else 0

    deadline = time.monotonic() + timeout_s
    while (n := decoded()) < at_least and time.monotonic() < deadline:
        time.sleep(0.1)  # polling the page from outside: no event to wait on
    return n


def audio_energy(driver: Any) -> float:
    stats = page_stats(driver)
    assert stats is not None and stats["audio"], stats
    return float(stats["audio"][0]["totalAudioEnergy"] or 0.0)


def tone(seconds: float) -> bytes:
    t = np.arange(int(seconds * RATE)) / RATE
    return (0.4 * np.sin(2 * np.pi * 300 * t) * (1 + 0.5 * np.sin(2 * np.pi * 3 * t)) * 32767 / 1.5) \
        .astype("<i2").tobytes()


def say(client: AgentClient, seconds: float) -> str:
    rid = client.new_request_id()
    client.wait_applied(client.send(Say(agent="ada", request_id=rid, pcm=tone(seconds), sample_rate=RATE)), 10.0)
    return rid


def test_the_page_shows_the_face_at_the_asked_size_and_rate(instance: tuple[BusConfig, str],
                                                            tmp_path: Path) -> None:
    config, url = instance
    with chromium() as driver:
        connect(driver, url + "?mic=0&width=320&height=240&fps=15")
        first = wait_for(driver, "return 1", 1.0, "")  # (a no-op round trip)
        assert first == 1
        # the first second of frames, the keyframe with them, is past
        assert frames_decoded(driver, 15) >= 15, said(url)
        before = video_stats(driver)
        time.sleep(3.0)
        after = video_stats(driver)
        driver.save_screenshot(str(tmp_path / "page.png"))
        status = driver.execute_script("return document.getElementById('status').textContent")
        eye_buttons = driver.execute_script("return [...document.querySelectorAll('#eyes button')]"
                                            ".map((b) => b.textContent)")
    assert eye_buttons == list(EYE_MODES)  # the panel offers every eye mode the service knows
    assert (after["frameWidth"], after["frameHeight"]) == (320, 240)
    decoded = after["framesDecoded"] - before["framesDecoded"]
    assert decoded >= 0.7 * 15 * 3, f"{decoded} frames decoded in 3 s at 15 fps"
    assert status.startswith("connected · rtt") and "fps" in status
    assert (tmp_path / "page.png").stat().st_size > 10_000


def test_the_voice_is_heard_during_a_say_and_silent_otherwise(instance: tuple[BusConfig, str]) -> None:
    config, url = instance
    with chromium() as driver, AgentClient(config) as client:
        connect(driver, url + "?mic=0&width=160&height=120&fps=10")
        time.sleep(2.0)
        quiet_start = audio_energy(driver)
        time.sleep(2.0)
        quiet = audio_energy(driver) - quiet_start
        rid = say(client, 3.0)
        client.wait_for(lambda m: getattr(m, "request_id", None) == rid and m.TYPE == "speech_started", 10.0)
        time.sleep(0.5)
        loud_start = audio_energy(driver)
        time.sleep(2.0)
        loud = audio_energy(driver) - loud_start
        assert isinstance(client.wait_for_speech(rid, 20.0), SpeechFinished)
        time.sleep(1.0)
        after_start = audio_energy(driver)
        time.sleep(2.0)
        after = audio_energy(driver) - after_start
    assert quiet < 1e-4 and after < 1e-4, (quiet, after)
    assert loud > 0.05, loud


@pytest.fixture(scope="module")
def user_says(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The fake microphone: eight seconds of silence, then the user speaking."""
    return user_speech_wav(tmp_path_factory.mktemp("microphone") / "user.wav",
                           "Wait, wait, let me ask you something first.", before_s=8.0, after_s=1.0)


def test_the_users_speech_reaches_the_bus_and_interrupts_the_agent(instance: tuple[BusConfig, str],
                                                                   user_says: Path) -> None:
    config, url = instance
    ctx = zmq.Context()
    bus = Subscriber(ctx, config, ["cmd.ada.user_speech", "stream.ada.user_audio"])
    bus.wait_ready()
    try:
        with chromium(microphone_wav=user_says) as driver, AgentClient(config) as client:
            rid = say(client, 40.0)  # the agent talks ...
            client.wait_for(lambda m: getattr(m, "request_id", None) == rid and m.TYPE == "speech_started", 10.0)
            connect(driver, url + "?width=160&height=120&fps=10")  # ... the microphone starts with the connection
            ended = client.wait_for_speech(rid, 45.0)  # ... and the user cuts in 8 s later
        heard = [got.message for got in bus.drain()]
    finally:
        bus.close()
        ctx.term()
    turns = [m for m in heard if isinstance(m, UserSpeech)]
    blocks = [m for m in heard if isinstance(m, UserAudio)]
    levels = [round(float(np.sqrt(np.mean(np.frombuffer(b.pcm, "<i2").astype(float) ** 2)))) for b in blocks[:60]]
    what = f"turns {[(m.speaking, m.source, m.t_ns) for m in turns[:4]]}; first blocks' RMS {levels}"
    assert isinstance(ended, SpeechInterrupted) and ended.reason == "the user started speaking", (ended, what)
    # cut short by the user's speech, which starts 8 s into the microphone
    assert 8.0 < ended.played_s < 30.0, (ended, what)
    assert [m.speaking for m in turns[:1]] == [True]
    assert turns[0].t_ns <= ended.t_ns  # the user spoke, then the agent stopped
    # more than 2 s of the microphone's stream (what the browser left out of the silence counted), speech in it
    assert blocks and blocks[-1].first_sample - blocks[0].first_sample > 100 * 320 and any(b.speaking for b in blocks)
    assert all(b.sample_rate == 16_000 and len(b.pcm) == 640 for b in blocks)
    # the answer asks for Opus DTX (test_web_service checks the answer, test_web_microphone the counting): whatever
    # Chromium leaves out is counted in whole frames. How much it leaves out is its encoder's call, on its audio
    # processing's faint floor: 1.2 of the 8 s of silence in one run, one frame in a loaded one.
    firsts = np.array([b.first_sample for b in blocks])
    steps = np.diff(firsts)
    assert np.all(steps > 0) and np.all(steps % 320 == 0), what


def test_a_second_browser_sees_the_same_agent(instance: tuple[BusConfig, str]) -> None:
    config, url = instance
    with chromium() as first, chromium() as second:
        connect(first, url + "?mic=0&width=160&height=120&fps=10")
        connect(second, url + "?mic=0&width=160&height=120&fps=10")
        decoded = [frames_decoded(d, 10) for d in (first, second)]
    assert all(n >= 10 for n in decoded), f"{decoded}\n{said(url)}"


def test_without_the_token_nothing_happens_and_with_it_the_page_connects() -> None:
    with private_bus_config() as config, BrokerThread(config):
        service = WebService(config, WebOptions(port=0, token="s3cret-token", width=160, height=120, fps=10.0))
        with ServiceThread(service), chromium() as driver:
            driver.get(f"http://127.0.0.1:{service.port}/")
            assert "a wrong or missing token" in driver.find_element("tag name", "body").text
            assert service.viewers is not None and not service.viewers.open
            connect(driver, f"http://127.0.0.1:{service.port}/?mic=0&token=s3cret-token")
            assert len(service.viewers.open) == 1


# The face's <video> drawn into a canvas at its own size, as the page decoded it: a lossless PNG.
VIDEO_PICTURE = """
const video = Object.values(window.eca.faces)[0];
if (!video || !video.videoWidth) return null;
const canvas = document.createElement("canvas");
canvas.width = video.videoWidth;
canvas.height = video.videoHeight;
canvas.getContext("2d").drawImage(video, 0, 0);
return canvas.toDataURL("image/png");
"""


def video_picture(driver: Any) -> np.ndarray:
    """The picture the page's face video shows now, as decoded by the browser: (height, width, 3) uint8."""
    from PIL import Image

    url = wait_for(driver, "return (() => {" + VIDEO_PICTURE + "})()", 10.0, "a picture in the face's video")
    png = base64.b64decode(url.split(",", 1)[1])
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


def edges_off_background(picture: np.ndarray, background: np.ndarray, depth: int = 2,
                         tolerance: int = 4) -> dict[str, float]:
    """For each edge (a strip `depth` pixels deep), the share of its pixels further than `tolerance` (in any
    channel) from the background colour."""
    strips = {"top": picture[:depth], "bottom": picture[-depth:], "left": picture[:, :depth],
              "right": picture[:, -depth:]}
    return {name: float((np.abs(strip.astype(int) - background).max(axis=-1) > tolerance).mean())
            for name, strip in strips.items()}


def test_the_video_has_the_background_colour_up_to_its_edges(instance: tuple[BusConfig, str],
                                                              tmp_path: Path) -> None:
    """The page's default size (640x480; at 15 fps, the same bits per picture as 30 for half the work on
    a small machine), as the browser decodes it, has the face's background colour along all four edges: no
    neutral grey band along the top and left. VP8 predicts the macroblocks at those edges from a fixed grey;
    an encoder that codes them too coarsely, or judges its choices on luma alone, loses the background's
    slight tint there, and the grey spreads into the background and stays. Checked on the first frames, and
    after a keyframe made while the agent talks (the rate control at its coarsest): a second page watching
    the same stream asks for one, for both pages."""
    config, url = instance
    background = np.round(np.array(load_render_config().colors["background"]) * 255).astype(int)
    pictures: dict[str, np.ndarray] = {}
    with chromium() as first, chromium() as second, AgentClient(config) as client:
        connect(first, url + "?mic=0&fps=15")
        decoded = wait_for_frames(first, 30, 30.0)["framesDecoded"]
        pictures["the first page's first second"] = video_picture(first)
        rid = say(client, 6.0)  # the mouth moves: every picture costs more bits
        client.wait_for(lambda m: getattr(m, "request_id", None) == rid and m.TYPE == "speech_started", 10.0)
        decoded = wait_for_frames(first, decoded + 30, 30.0)["framesDecoded"]
        connect(second, url + "?mic=0&fps=15")
        wait_for_frames(second, 30, 30.0)
        wait_for_frames(first, decoded + 30, 30.0)
        pictures["the first page after the second page's keyframe"] = video_picture(first)
        pictures["the second page"] = video_picture(second)
        first.save_screenshot(str(tmp_path / "page.png"))  # what a person saw, kept for a failure's reader
        assert isinstance(client.wait_for_speech(rid, 20.0), SpeechFinished)
    for when, picture in pictures.items():
        assert picture.shape == (480, 640, 3), when
        off = edges_off_background(picture, background)
        medians = {name: np.median(strip.reshape(-1, 3), axis=0).tolist() for name, strip in
                   (("top", picture[:2]), ("left", picture[:, :2]), ("bottom", picture[-2:]),
                    ("right", picture[:, -2:]))}
        # A grey band turns a whole edge (its median too); a talking face's coarse picture after a keyframe may
        # leave a few blocks' pixels along an edge just off the tint (2.1 % of the left edge in one loaded run).
        problem = (f"{when}: edge pixels off the background {background.tolist()}: {off}; "
                   f"the edges' median colours {medians}\n{said(url)}")
        assert all(np.abs(np.array(m) - background).max() <= 4 for m in medians.values()), problem
        assert max(off.values()) <= 0.05, problem
