"""Faces fanned out by Janus (`eca web --sfu URL`, web/sfu.py): the web service publishes each face once into a Janus
Streaming mountpoint, and viewers watch through Janus.

Hosts are network namespaces (tests/support/netns.py): Janus on an "sfu" host, the viewers (aiortc, in a process of
their own) on a "viewer" host; the web service runs in this process (its counters are read directly) and reaches
Janus over the bridge, as a web host would. WebRTC through Janus needs those addresses: libnice and aioice skip
127.0.0.1. Skipped without root (namespaces) or without Debian's janus.
"""

from __future__ import annotations

import base64
import json
import shutil
import statistics
import subprocess
import sys
import threading
import time
import urllib.request
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar, cast

import numpy as np
import pytest
import zmq

from eca.protocol.bus import Publisher
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import EmotionState
from eca.services.processes.runtime import wait_until
from eca.services.processes.web.browser_face import (
    FRAME,
    NTP_UNIX_OFFSET_MS,
    VOICE_SPURTS,
    VOICED,
    unpack,
    unpack_voice_spurts,
)
from eca.services.processes.web.options import WebOptions, WebOptionsError
from eca.services.processes.web.service import WebService
from eca.services.processes.web.sfu import MAX_DATA_BYTES, RtpStream
from tests.support.browser import (
    browser_available,
    canvas_pixels,
    chromium,
    head_box,
    page_stats,
    wait_for,
    wait_for_frames,
)
from tests.support.bus import BrokerThread, ServiceThread, private_bus_config
from tests.support.janus import Janus, janus_available, janus_server, running_logs
from tests.support.netns import Host, Network, hosts, netns_available
from tests.support.vrm import many_primitives_file
from tests.support.web_client import SMALL, Client, speak_tone

ROOT = Path(__file__).resolve().parents[1]
WIDTH, HEIGHT, FPS = 160, 120, 15.0  # tests/support/web_client.py's SMALL: what direct viewers there ask
FAR_S = 0.03  # a far Janus: each way between it and everything else


def _skip_reason() -> str | None:
    return netns_available() or janus_available()


needs_janus = pytest.mark.skipif(_skip_reason() is not None, reason=str(_skip_reason()))


# --- options and RTP numbering (no Janus) -----------------------------------------------------------------------


@pytest.mark.parametrize("url", ["not a url", "ftp://sfu/janus", "http:///janus", "sfu:8088/janus",
                                 "http://sfu:99999/janus", "http://sfu/janus?x=1", "http://u:p@sfu/janus",
                                 "http://sfu/" + "a" * 2000, ""])
def test_a_bad_sfu_url_is_refused_with_a_sentence(url: str) -> None:
    with pytest.raises(WebOptionsError, match="sfu"):
        WebOptions(sfu=url).check()


def test_an_sfu_excludes_conversations_per_visitor_but_not_pages_drawing_every_face() -> None:
    assert WebOptions(sfu="https://sfu.example/janus").check().sfu == "https://sfu.example/janus"
    with pytest.raises(WebOptionsError, match="per_visitor"):
        WebOptions(sfu="http://sfu:8088/janus", per_visitor=True).check()
    assert WebOptions(sfu="http://sfu:8088/janus", draw="browser").check().draw == "browser"


def test_rtp_timestamps_follow_the_master_clock_stamps() -> None:
    """Audio and video stamps from one origin: their RTP timestamps advance with the stamps, at their own rates."""
    video, audio = RtpStream(96, 90_000, origin_ns=5_000_000_000), RtpStream(111, 48_000, origin_ns=5_000_000_000)
    first = video.packetize([b"a", b"b"], 5_000_000_000)
    later = video.packetize([b"c"], 5_500_000_000)
    seqs = [int.from_bytes(p[2:4], "big") for p in first + later]
    assert seqs == [(seqs[0] + i) & 0xFFFF for i in range(3)]

    def stamp(packet: bytes) -> int:
        return int.from_bytes(packet[4:8], "big")

    assert (stamp(later[0]) - stamp(first[0])) & 0xFFFFFFFF == 45_000
    assert [p[1] >> 7 for p in first] == [0, 1]  # the marker on a picture's last packet
    a0, a1 = audio.packetize([b"x"], 5_000_000_000), audio.packetize([b"y"], 5_020_000_000)
    assert (stamp(a1[0]) - stamp(a0[0])) & 0xFFFFFFFF == 960
    report = video.sender_report(5_600_000_000, 1_700_000_000.0)
    assert report is not None and report[1] == 200  # an RTCP SR
    assert (int.from_bytes(report[16:20], "big") - stamp(later[0])) & 0xFFFFFFFF == 9_000  # carried 100 ms on


# --- through a real Janus ----------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def network() -> Iterator[Network]:
    why = _skip_reason()
    if why is not None:
        pytest.skip(why)
    with hosts("sfu", "viewer") as net:
        yield net


@pytest.fixture(scope="module")
def janus(network: Network) -> Iterator[Janus]:
    with janus_server(network["sfu"]) as server:
        yield server


@pytest.fixture(scope="module")
def web(janus: Janus) -> Iterator[tuple[BusConfig, WebService]]:
    with private_bus_config(agents=["ada"]) as config, BrokerThread(config):
        service = WebService(config, WebOptions(port=0, sfu=janus.url, width=WIDTH, height=HEIGHT, fps=FPS))
        with ServiceThread(service):
            yield config, service


@pytest.fixture(scope="module")
def web_drawn(janus: Janus) -> Iterator[tuple[BusConfig, WebService]]:
    """An instance whose pages draw every face (the default head, draw = "browser"), published into Janus: voice and
    face frames, no video."""
    with private_bus_config(agents=["ada"]) as config, BrokerThread(config):
        service = WebService(config, WebOptions(port=0, sfu=janus.url, width=WIDTH, height=HEIGHT, fps=FPS,
                                                face="head", draw="browser"))
        with ServiceThread(service):
            yield config, service


T = TypeVar("T")

# The page's connections to Janus as the page sees them: state, and every candidate pair's (its two ends, whether
# nominated or selected, its traffic and when its last packet came)
JANUS_PCS = """
const done = arguments[arguments.length - 1];
(async () => {
  const out = [];
  for (const watch of window.eca.janus || []) {
    const pc = watch.pc;
    if (!pc) { out.push(null); continue; }
    const stats = await pc.getStats();
    const end = (id) => { const c = stats.get(id); return c ? `${c.candidateType} ${c.address}:${c.port}` : id; };
    let selected = null;
    stats.forEach((r) => { if (r.type === "transport") selected = r.selectedCandidatePairId; });
    const pairs = [];
    stats.forEach((r) => {
      if (r.type !== "candidate-pair") return;
      pairs.push({local: end(r.localCandidateId), remote: end(r.remoteCandidateId), state: r.state,
                  nominated: r.nominated, selected: r.id === selected, bytesReceived: r.bytesReceived,
                  bytesSent: r.bytesSent, requestsSent: r.requestsSent, responsesReceived: r.responsesReceived,
                  sinceLastPacketMs: r.lastPacketReceivedTimestamp ? Math.round(performance.timeOrigin
                    + performance.now() - r.lastPacketReceivedTimestamp) : null});
    });
    out.push({connection: pc.connectionState, ice: pc.iceConnectionState, pairs});
  }
  return out;
})().then(done, (e) => done(String(e)));
"""


# The voice clock of each face the page draws (static/face3d.js VoiceClock), through Janus: how it reads Janus's
# numbering of the voice
VOICE_CLOCKS = """
return Object.fromEntries(Object.entries(window.eca.drawn || {}).map(([agent, face]) => {
  const c = face.clock;
  return [agent, c && {base: c.base, rebasings: c.rebasings || 0, firsts: c.firsts, dropped: c.dropped,
                       spurts: c.spurts.slice(-5), report: c.report, asks: c.asks.length, legs: c.legs,
                       watchedSinceMs: c.watchedSinceMs}];
}));"""


def connect_through_janus(driver: Any) -> None:
    """The page (loaded) connects, and its connection to Janus comes up."""
    driver.find_element("id", "connect").click()
    wait_for(driver, "return window.eca.state", 30.0, "the page connecting through Janus", lambda s: s == "connected")


def through_janus(driver: Any, service: WebService, wait: Callable[[], T]) -> T:
    """`wait()` for what a page watching through Janus should get; when it times out, the error says what eca sent
    into Janus and encoded over a second (counters that stand still: eca stopped; moving: Janus or the page) and
    how the page's connections to Janus stand."""
    try:
        return wait()
    except TimeoutError as exc:
        def sent() -> dict[str, Any]:
            assert service.sfu is not None
            streams = {f"{k[0]} {k[1]}x{k[2]}": {"encoded": st.encoded, "keyframes": st.keyframes,
                                                   "stopped": st.stopped}
                       for k, st in list(service.encoded.streams.items())}
            return {"sfu": service.sfu.stats(), "streams": streams, "plan": repr(service._plan)}
        before = sent()
        time.sleep(1.0)  # a second of counting what eca sends, for the message
        raise AssertionError(f"{exc}; eca then: {before}; a second later: {sent()}; the page's connections to "
                             f"Janus: {driver.execute_async_script(JANUS_PCS)}; the voice clocks of the faces it "
                             f"draws: {driver.execute_script(VOICE_CLOCKS)}; Janus's log:\n{running_logs()}") from None


def sfu_frames(driver: Any, service: WebService, count: int, timeout_s: float) -> dict[str, Any]:
    """wait_for_frames for a page watching through Janus (through_janus says why when they do not come)."""
    return through_janus(driver, service, lambda: wait_for_frames(driver, count, timeout_s))


@contextmanager
def audio_and_dialogue(config: BusConfig) -> Iterator[tuple[Publisher, Publisher]]:
    """Publishers as the audio and dialogue services (voice blocks, the emotion's state), ready, the agent calm."""
    ctx = zmq.Context()
    audio, dialogue = Publisher(ctx, config, "audio"), Publisher(ctx, config, "dialogue")
    try:
        audio.wait_ready()
        dialogue.wait_ready()
        dialogue.publish(EmotionState(agent="ada", name="natural", transition_s=0.0))
        yield audio, dialogue
    finally:
        audio.close()
        dialogue.close()
        ctx.term()


@contextmanager
def talking(audio: Publisher) -> Iterator[None]:
    """The agent's voice sounds (a tone, half a second at a time, each part stamped as it is published) until the
    block ends; then it is silent."""
    stop = threading.Event()

    def talk() -> None:
        while not stop.is_set():
            speak_tone(audio, 0.5)
            # the next part well before this one ends (each is stamped from when it is published, so the parts
            # overlap by 0.26 s, not queue): a continuous voice even when a loaded machine holds this thread back
            stop.wait(0.3)

    thread = threading.Thread(target=talk, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(5.0)


@pytest.fixture(scope="module")
def web_auto_head(janus: Janus) -> Iterator[tuple[BusConfig, WebService]]:
    """An instance with the default head and draw = "auto" published into Janus: video for pages without WebGL, face
    frames for those that draw."""
    with private_bus_config(agents=["ada"]) as config, BrokerThread(config):
        service = WebService(config, WebOptions(port=0, sfu=janus.url, width=WIDTH, height=HEIGHT, fps=FPS,
                                                face="head"))
        with ServiceThread(service):
            yield config, service


def watch_from(host: Host, url: str, mountpoint: int, seconds: float, viewers: int = 1) -> subprocess.Popen[str]:
    """Viewers of a mountpoint in a process on `host` (tests/support/janus.py's `watch`)."""
    argv = [sys.executable, "-m", "tests.support.janus", "watch", url, str(mountpoint), str(seconds),
            "--viewers", str(viewers)]
    proc = host.popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return cast("subprocess.Popen[str]", proc)  # text=True: its pipes carry str


def result_of(proc: subprocess.Popen[str], timeout_s: float = 60.0) -> dict[str, Any]:
    out, err = proc.communicate(timeout=timeout_s)
    assert proc.returncode == 0, err[-3000:]
    got: dict[str, Any] = json.loads(out)
    return got


def mean_thumb(stats: list[dict[str, Any]]) -> np.ndarray:
    return np.asarray(np.mean([np.asarray(s["thumb"], dtype=np.float64) for s in stats], axis=0))


@needs_janus
def test_a_viewer_through_janus_sees_and_hears_the_face_and_its_change(network: Network, janus: Janus,
                                                                       web: tuple[BusConfig, WebService]) -> None:
    config, service = web
    assert service.sfu is not None
    info = service.sfu_info()
    assert info is not None and info["url"] == janus.url and info["mountpoints"]["ada"] == info["mountpoint"]
    mp = service.sfu.mountpoints["ada"]
    requests = mp.keyframe_requests
    with audio_and_dialogue(config) as (audio, dialogue):
        proc = watch_from(network["viewer"], janus.url, info["mountpoint"], 7.0)
        # Janus asks for a keyframe (PLI) as the viewer starts: that is when it watches
        assert wait_until(lambda: mp.keyframe_requests > requests, 20.0), "Janus never asked for a keyframe"
        time.sleep(2.0)  # a baseline: two seconds of the face before the change (the viewer reports at its end)
        speak_tone(audio, 1.0)
        changed_at = time.time()
        dialogue.publish(EmotionState(agent="ada", name="surprised", transition_s=0.0))
        got = result_of(proc)
    viewer = got["viewers"][0]
    assert viewer["pictures"] >= 0.6 * SMALL["fps"] * 5, viewer["pictures"]
    assert {(s["w"], s["h"]) for s in viewer["stats"]} == {(SMALL["width"], SMALL["height"])}
    assert min(s["std"] for s in viewer["stats"][-10:]) > 10, "a face, not a blank picture"
    assert viewer["audio_frames"] >= 150 and viewer["audio_rms"] > 1000, (viewer["audio_frames"], viewer["audio_rms"])
    before = [s for s in viewer["stats"] if s["t"] < changed_at]
    after = [s for s in viewer["stats"] if s["t"] > changed_at + 1.0]
    assert len(before) >= 10 and len(after) >= 10, (len(before), len(after))
    still = np.abs(mean_thumb(before[-10:-5]) - mean_thumb(before[-5:])).mean()
    change = np.abs(mean_thumb(before[-5:]) - mean_thumb(after[-5:])).mean()
    assert change > 0.5 and change > 3 * still, f"the expression's change: {change:.2f} levels (still: {still:.2f})"


@needs_janus
def test_five_viewers_through_janus_cost_eca_one_stream(network: Network, janus: Janus,
                                                         web: tuple[BusConfig, WebService]) -> None:
    """Five viewers of one face: eca encodes and sends each picture once (its counters), peers with none of them,
    and Janus counts five viewers."""
    config, service = web
    assert service.sfu is not None
    mp = service.sfu.mountpoints["ada"]
    stream = service.encoded.streams[("ada", WIDTH, HEIGHT, FPS)]
    proc = watch_from(network["viewer"], janus.url, mp.id, 6.0, viewers=5)
    assert wait_until(lambda: mp.viewers == 5, 20.0), f"Janus counts {mp.viewers} viewers"
    assert mp.video is not None
    pictures, encoded, packets, began = mp.pictures, stream.encoded, mp.video.packets, time.monotonic()
    time.sleep(3.0)  # the window the counters are compared over
    elapsed = time.monotonic() - began
    sent = mp.pictures - pictures
    sent_packets = mp.video.packets - packets
    encodes = stream.encoded - encoded
    got = result_of(proc)
    assert len(service.viewers.open if service.viewers else []) == 0  # no viewer peers with eca
    # one picture sent per picture encoded, at the stream's rate, whatever the number of viewers
    assert abs(sent - encodes) <= 1, (sent, encodes)
    assert sent <= SMALL["fps"] * elapsed * 1.2 + 2, f"{sent} pictures in {elapsed:.1f} s at {SMALL['fps']} fps"
    assert sent_packets <= 3 * sent + 3, (sent_packets, sent)
    counts = [v["pictures"] for v in got["viewers"]]
    assert all(n >= 0.5 * SMALL["fps"] * 4 for n in counts), counts


@needs_janus
def test_a_face_the_pages_draw_reaches_viewers_through_janus_as_face_frames(network: Network, janus: Janus,
                                                                          web_drawn: tuple[BusConfig, WebService]
                                                                          ) -> None:
    """draw = "browser" through Janus: the mountpoint has the voice and a data section and no video; each face frame
    eca sends reaches the viewer's data channel as one binary message, whole (the page's layout), at the configured
    rate, in order; they change with an emotion command and say when the voice sounds; the voice's clock comes with
    them. The voice pauses in silence: Janus relays only the tone's packets. eca draws and encodes nothing."""
    config, service = web_drawn
    assert service.sfu is not None and service.sfu.faces == ("ada",) and not service.sfu.video
    info = service.sfu_info()
    assert info is not None and info["faces"] == ["ada"] and info["video"] is False
    with urllib.request.urlopen(service.url.split("?")[0] + "config", timeout=10) as response:
        described = json.loads(response.read())["sfu"]["faces"]["ada"]
    layout = service.face_frames.face("ada").layout
    assert described["frame_bytes"] == layout.size and described["url"].startswith("avatars/")
    mp = service.sfu.mountpoints["ada"]
    assert mp.data_port and not mp.video_port
    with audio_and_dialogue(config) as (audio, dialogue):
        proc = watch_from(network["viewer"], janus.url, mp.id, 7.0)
        assert wait_until(lambda: mp.viewers == 1, 20.0), f"Janus counts {mp.viewers} viewers"
        sent = mp.face_frames
        assert wait_until(lambda: mp.face_frames >= sent + 2 * FPS, 10.0)  # a baseline: two seconds of the face
        changed_at = time.time()
        dialogue.publish(EmotionState(agent="ada", name="surprised", transition_s=0.0))
        speak_tone(audio, 1.0)
        got = result_of(proc)
    viewer = got["viewers"][0]
    assert viewer["pictures"] == 0 and not service.encoded.streams, "video: eca encoded or Janus sent pictures"
    assert 45 <= viewer["audio_frames"] <= 60, viewer["audio_frames"]  # the tone's second, not the silence
    messages = viewer["messages"]
    assert messages and all(m["binary"] for m in messages), "no face frames, or as text"
    received = [(m["t"], base64.b64decode(m["data"])) for m in messages]
    frames = [(t, unpack(data, layout)) for t, data in received if data[2] == FRAME]
    clocks = [unpack_voice_spurts(data) for t, data in received if data[2] == VOICE_SPURTS]
    assert len(frames) + len(clocks) == len(received), "a message neither a frame nor the voice's clock"
    # the voice's clock at the tone's first packet (a talk spurt) and every 12 packets (240 ms) while it sounds: the
    # RTP timestamp eca gave a packet, when it left, the way to Janus (this network's: quick) and the spurts
    assert 3 <= len(clocks) <= 6, len(clocks)
    assert all(c[0] == described["slot"] and 0.0 <= c[3] < 10.0 for c in clocks), clocks
    spurt_seq, spurt_ts = clocks[0][5][-1]
    assert all(c[5][-1] == (spurt_seq, spurt_ts) for c in clocks), "the tone is one spurt"
    for _, rtp, _, _, last_seq, _ in clocks:  # each packet after the spurt's first: 960 samples and one number on
        assert (rtp - spurt_ts) % 2**32 == 960 * ((last_seq - spurt_seq) % 2**16), (rtp, last_seq, spurt_ts, spurt_seq)
    span = frames[-1][0] - frames[0][0]
    assert len(frames) >= 0.8 * FPS * span, f"{len(frames)} frames in {span:.1f} s at {FPS:g} fps"
    seqs = [f[2] for _, f in frames]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs), "out of order or repeated"
    before = np.array([f[4] for t, f in frames if t < changed_at])
    after = np.array([f[4] for t, f in frames if t > changed_at + 1.0])
    assert len(before) >= 10 and len(after) >= 10, (len(before), len(after))
    still = np.abs(before[-10:-5].mean(axis=0) - before[-5:].mean(axis=0)).sum()
    change = np.abs(before[-5:].mean(axis=0) - after[-5:].mean(axis=0)).sum()
    assert change > 0.5 and change > 3 * still, f"the expression's change: {change:.2f} (still: {still:.2f})"
    voiced = [f for t, f in frames if f[1] & VOICED]
    assert len(voiced) >= 0.5 * FPS, f"{len(voiced)} frames said the voice sounds"


@needs_janus
def test_a_mountpoint_janus_lost_is_made_again_and_direct_viewers_carry_on(network: Network, janus: Janus,
                                                                            web: tuple[BusConfig, WebService]) -> None:
    """Janus restarted (every session and mountpoint gone): eca makes the mountpoint again under the same id, and a
    viewer watches again; meanwhile a viewer peering with eca directly keeps its face."""
    import asyncio

    config, service = web
    assert service.sfu is not None
    mp = service.sfu.mountpoints["ada"]
    old_id, recreated = mp.id, service.sfu.recreated
    janus.stop()

    async def direct() -> int:
        client = Client(f"http://127.0.0.1:{service.port}/", ["ada"])
        await client.connect()
        try:
            return len(await client.frames("ada", "video", 3.0))
        finally:
            await client.pc.close()

    try:
        seen_directly = asyncio.run(direct())
    finally:
        janus.start()
    assert seen_directly >= 10, f"a direct viewer saw {seen_directly} pictures while Janus was down"
    assert wait_until(lambda: service.sfu is not None and service.sfu.recreated > recreated, 30.0), \
        "the mountpoint was not made again"
    assert mp.id == old_id  # pages keep watching the same id
    got = result_of(watch_from(network["viewer"], janus.url, mp.id, 4.0))
    assert got["viewers"][0]["pictures"] >= 0.5 * SMALL["fps"] * 3, got["viewers"][0]["pictures"]


@needs_janus
def test_face_frames_flow_again_into_a_mountpoint_janus_made_again(network: Network, janus: Janus,
                                                                   web_drawn: tuple[BusConfig, WebService]) -> None:
    """Janus restarted under an instance whose pages draw the face: eca makes the mountpoint again, its data section
    with it, under the same id, and a new viewer gets the face frames (and the voice, which sounds meanwhile) at the
    rate."""
    config, service = web_drawn
    assert service.sfu is not None
    mp = service.sfu.mountpoints["ada"]
    old_id, recreated = mp.id, service.sfu.recreated
    janus.restart()
    assert wait_until(lambda: service.sfu is not None and service.sfu.recreated > recreated, 30.0), \
        "the mountpoint was not made again"
    assert mp.id == old_id and mp.data_port
    with audio_and_dialogue(config) as (audio, _):
        proc = watch_from(network["viewer"], janus.url, mp.id, 4.0)
        with talking(audio):
            got = result_of(proc)["viewers"][0]
    frames = [m for m in got["messages"] if m["binary"] and base64.b64decode(m["data"])[2] == FRAME]
    assert len(frames) >= 0.6 * FPS * 3, f"{len(frames)} face frames in 4 s at {FPS:g} fps"
    assert got["audio_frames"] >= 100, got["audio_frames"]


@needs_janus
def test_a_face_too_large_for_janus_s_data_goes_as_video_or_is_refused(network: Network, janus: Janus,
                                                                      tmp_path: Path) -> None:
    """Janus reads a data port into 1,500 bytes: an avatar whose face frames are larger (the head's primitives five
    times over) cannot go as face frames. With draw = "browser" `eca web` stops at start with one line saying so;
    with "auto" it publishes that face as video, the mountpoint without a data section, and says nothing of faces."""
    big = many_primitives_file(tmp_path, 5)
    with private_bus_config(agents=["ada"]) as config, BrokerThread(config):
        done = subprocess.run([sys.executable, "-m", "eca.services.tools.cli", "web", "--config",
                               str(config.config_path), "--instance", config.instance, "--sfu", janus.url,
                               "--web-face", str(big), "--web-draw", "browser", "--web-port", "0"],
                              capture_output=True, text=True, cwd=ROOT, timeout=120)
        assert done.returncode == 1, (done.returncode, done.stderr[-2000:])  # a service that cannot start
        refused = [line for line in done.stderr.splitlines() if "cannot start" in line]
        assert len(refused) == 1 and "1500 bytes" in refused[0] and "ada" in refused[0], done.stderr[-2000:]
        service = WebService(config, WebOptions(port=0, sfu=janus.url, width=WIDTH, height=HEIGHT, fps=FPS,
                                                face=str(big)))
        assert service.face_frames.face("ada").layout.size > MAX_DATA_BYTES
        with ServiceThread(service):
            assert service.sfu is not None and service.sfu.faces == () and service.sfu.video
            mp = service.sfu.mountpoints["ada"]
            assert mp.video_port and not mp.data_port
            info = service.sfu_info()
            assert info is not None and info["faces"] == [] and info["video"] is True
            got = result_of(watch_from(network["viewer"], janus.url, mp.id, 4.0))["viewers"][0]
    assert got["pictures"] >= 0.5 * FPS * 2 and not got["messages"], got


@needs_janus
def test_a_janus_that_does_not_answer_stops_eca_web_at_once_with_one_line(network: Network) -> None:
    with private_bus_config(agents=["ada"]) as config:
        unreachable = f"http://{network['sfu'].address}:1/janus"  # the host is there, nothing listens on port 1
        for url, said in ((unreachable, "no answer from"), ("ftp://sfu/janus", "http:// or https://")):
            began = time.monotonic()
            done = subprocess.run([sys.executable, "-m", "eca.services.tools.cli", "web", "--config",
                                   str(config.config_path), "--sfu", url], capture_output=True, text=True, cwd=ROOT,
                                  timeout=60)
            assert done.returncode == 2, (done.returncode, done.stderr[-2000:])
            lines = [line for line in done.stderr.splitlines() if line.strip()]
            assert len(lines) == 1 and said in lines[0] and lines[0].startswith("eca web:"), done.stderr[-2000:]
            assert time.monotonic() - began < 20


@needs_janus
@pytest.mark.skipif(browser_available() is not None, reason=str(browser_available()))
def test_the_page_in_a_real_browser_watches_the_face_through_janus(web: tuple[BusConfig, WebService],
                                                                   tmp_path: Path) -> None:
    """The page as a person opens it, in a real headless Chromium: /config names the SFU, the page watches the
    agent through Janus's HTTP API (its own small client, trickle included), and the face plays: pictures decoded
    at the stream's size, the voice's track there, and the picture is the face, not a blank."""
    _, service = web
    with chromium() as driver:
        driver.get(service.url + "?mic=0")
        connect_through_janus(driver)
        assert driver.execute_script("return (window.eca.janus || []).length") == 1  # watched through Janus
        stats = sfu_frames(driver, service, 20, 30.0)
        pixels = np.array(driver.execute_script("""
            const v = document.querySelector('#faces video'); const c = document.createElement('canvas');
            c.width = v.videoWidth; c.height = v.videoHeight; const g = c.getContext('2d'); g.drawImage(v, 0, 0);
            return Array.from(g.getImageData(0, 0, c.width, c.height).data);"""), dtype=np.uint8)
        driver.save_screenshot(str(tmp_path / "through_janus.png"))
        audio = page_stats(driver)
    assert (stats["frameWidth"], stats["frameHeight"]) == (WIDTH, HEIGHT)
    assert audio is not None and audio["audio"] and audio["audio"][0]["packetsReceived"] > 0
    rgb = pixels.reshape(HEIGHT, WIDTH, 4)[:, :, :3].astype(int)
    assert rgb.std() > 20, "a blank picture"  # the face on its background: many colours


def janus_session_alive(url: str, session: int) -> bool:
    """Whether Janus still has `session` (a keepalive on it answers success, not "no such session")."""
    body = json.dumps({"janus": "keepalive", "transaction": "alive"}).encode()
    request = urllib.request.Request(f"{url}/{session}", data=body, headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=5.0) as response:
        answer = json.loads(response.read())
    return bool(answer.get("janus") == "ack")


@needs_janus
@pytest.mark.skipif(browser_available() is not None, reason=str(browser_available()))
def test_a_page_that_goes_away_has_janus_drop_its_viewer_at_once(web: tuple[BusConfig, WebService],
                                                                 janus: Janus) -> None:
    """A page watching through Janus that goes away (another page in its tab here; a closed tab, a reload) tells Janus
    to drop its viewer as it goes: its session is gone within seconds, where Janus would relay to it until the session
    timed out (60 s), and count it among the mountpoint's viewers until then."""
    _, service = web
    with chromium() as driver:
        driver.get(service.url + "?mic=0")
        connect_through_janus(driver)
        sfu_frames(driver, service, 5, 30.0)
        session = int(driver.execute_script("return window.eca.janus[0].session"))
        assert janus_session_alive(janus.url, session)
        driver.get("about:blank")
        assert wait_until(lambda: not janus_session_alive(janus.url, session), 5.0), \
            f"Janus still has the session of a page that went away: {running_logs()}"


@needs_janus
@pytest.mark.skipif(browser_available() is not None, reason=str(browser_available()))
def test_the_page_watches_through_janus_although_its_first_requests_to_janus_fail(
        web: tuple[BusConfig, WebService]) -> None:
    """A request to Janus's API that fails on the way (fetch's network error, as when Janus closes a keep-alive
    connection just as the page reuses it) is sent again: with the page's first two requests to Janus (the session,
    the handle) and its first long poll failing so, the page still watches the agent through Janus."""
    _, service = web
    assert service.sfu is not None
    janus_url = service.sfu.janus.url
    with chromium() as driver:
        driver.get(service.url + "?mic=0")
        driver.execute_script("""
            const janus = arguments[0]; const real = window.fetch.bind(window);
            window.failedToJanus = { post: 0, get: 0 };
            window.fetch = (url, init) => {
              const kind = init && init.method === "POST" ? "post" : "get";
              if (String(url).startsWith(janus) && window.failedToJanus[kind] < (kind === "post" ? 2 : 1)) {
                window.failedToJanus[kind] += 1;
                return Promise.reject(new TypeError("Failed to fetch"));
              }
              return real(url, init);
            };""", janus_url)
        connect_through_janus(driver)
        assert driver.execute_script("return window.failedToJanus") == {"post": 2, "get": 1}
        assert driver.execute_script("return (window.eca.janus || []).length") == 1
        stats = sfu_frames(driver, service, 10, 30.0)
    assert (stats["frameWidth"], stats["frameHeight"]) == (WIDTH, HEIGHT)


# What the page knows of the packets its voice played: five times over a second, the RTP timestamp of the one played
# last as Janus renumbered it and when it played (the synchronization source); the page's estimate of Janus's first
# packet; and the jitter buffer's own delay over that second (getStats, before and after), in ms.
def steady(played: list[list[float]]) -> bool:
    """Whether the synchronization source's readings (RTP timestamp, when played) come from steady playout: each a
    new packet, played as long after its timestamp as the others (within 20 ms)."""
    delays = [played_ms - rtp * 1000 / 48_000 for rtp, played_ms in played]
    return len({rtp for rtp, _ in played}) == len(played) and max(delays) - min(delays) <= 20.0


VOICE_PACKETS = """
    const done = arguments[0]; const receiver = window.eca.drawn.ada.clock.receiver;
    receiver.getStats().then((stats) => { let n = 0;
      stats.forEach((r) => { if (r.type === "inbound-rtp") n = r.packetsReceived; }); done(n); });"""


PLAYED = """
    const done = arguments[0]; const f = window.eca.drawn.ada; const receiver = f.clock.receiver;
    const inbound = async () => { for (const r of (await receiver.getStats()).values()) {
      if (r.type === "inbound-rtp") return r; } return null; };
    (async () => {
      const a = await inbound(); const played = [];
      for (let i = 0; i < 5; i += 1) {
        await new Promise((r) => setTimeout(r, 200));
        const src = receiver.getSynchronizationSources()[0]; played.push([src.rtpTimestamp, src.timestamp]);
      }
      const b = await inbound();
      done([played, f.clock.base, 1000 * (b.jitterBufferDelay - a.jitterBufferDelay)
            / (b.jitterBufferEmittedCount - a.jitterBufferEmittedCount), f.clock.report]);
    })();"""


@needs_janus
@pytest.mark.skipif(browser_available() is not None, reason=str(browser_available()))
def test_the_page_in_a_real_browser_draws_the_face_from_frames_through_janus(
        web_drawn: tuple[BusConfig, WebService], tmp_path: Path) -> None:
    """draw = "browser" through Janus, in a real headless Chromium: the page watches the agent through Janus, opens
    the mountpoint's data channel, draws the head from the face frames (no video anywhere), and knows what its voice
    plays although Janus renumbers the voice's RTP timestamps (the page works out from what: exactly the first
    packet Janus relayed to it): each packet it played, taken back to eca's numbering and so to when eca sent it,
    was played as long after as the jitter buffer held it; it hears the voice's frames while a tone plays."""
    check_drawn_through_janus(*web_drawn, tmp_path)


@needs_janus
@pytest.mark.skipif(browser_available() is not None, reason=str(browser_available()))
@pytest.mark.skipif(shutil.which("ethtool") is None, reason="a delayed link needs ethtool (Debian: ethtool)")
def test_a_page_far_from_janus_and_a_janus_far_from_eca_still_find_janus_s_first_packet(tmp_path: Path) -> None:
    """The same, with Janus on a host 30 ms away from everything (eca, the page): the voice takes 60 ms from eca to
    the page. The page still works out exactly which packet Janus relayed first: eca dates its voice's clock reports
    by their arrival at Janus (half its API round trip to Janus), the page its packets' by their departure from
    Janus (half its connection's round trip). Counted from arrival at the page, as before, it would be three
    packets late, the mouth 60 ms behind the voice."""
    with hosts("sfu", delays={"sfu": FAR_S}) as net, janus_server(net["sfu"]) as janus, \
            private_bus_config(agents=["ada"]) as config, BrokerThread(config):
        service = WebService(config, WebOptions(port=0, sfu=janus.url, width=WIDTH, height=HEIGHT, fps=FPS,
                                                face="head", draw="browser"))
        with ServiceThread(service):
            assert service.sfu is not None
            assert abs(service.sfu.janus.one_way_s() - FAR_S) < 0.01, service.sfu.janus.round_trips
            leg_ms = check_drawn_through_janus(config, service, tmp_path, trip_ms=2000 * FAR_S)
    assert abs(leg_ms - 1000 * FAR_S) < 10.0, leg_ms


def check_drawn_through_janus(config: BusConfig, service: WebService, tmp_path: Path, trip_ms: float = 0.0) -> float:
    """A real Chromium draws `service`'s agent ada from face frames through Janus (voice and data, no video). The
    voice pauses in silence: a tone, a second of silence (Janus relays nothing), another tone. During the second
    each voice packet plays as long after eca sent it as the way there (`trip_ms`, eca -> Janus -> page) and its
    jitter buffer make (a packet off on Janus's numbering, 20 ms, or a pause's length, shows), and the page's
    voice clock says when eca sent what plays. The page's estimate of its way from Janus (ms) is returned."""
    with audio_and_dialogue(config) as (audio, _), chromium() as driver:
        driver.get(service.url + "?mic=0")
        connect_through_janus(driver)
        wait_for(driver, "return window.eca.drawn.ada ? window.eca.drawn.ada.stats.received : 0", 30.0,
                 "the page drawing ada from face frames through Janus", lambda n: n >= 10)
        assert driver.execute_script("return (window.eca.janus || []).length") == 1
        assert driver.execute_script("return document.querySelector('#faces video')") is None
        with talking(audio):
            through_janus(driver, service, lambda: wait_for(
                driver, "return window.eca.drawn.ada.clock.rebasings || 0", 20.0,
                "the page working out Janus's numbering of the voice", lambda n: n >= 3))
        # a pause in the voice (what is tested): eca sends nothing into Janus for a second, then the voice again
        voice = service.sfu.mountpoints["ada"].audio if service.sfu else None
        assert voice is not None and voice.last_ns is not None
        assert wait_until(lambda: service.clock.now_ns() - (voice.last_ns or 0) > 1_000_000_000, 5.0), \
            "the voice did not pause in silence"
        before = driver.execute_async_script(VOICE_PACKETS)

        def voice_state() -> str:  # for a failure's message: the voice at both ends, the connection, Janus's log
            return (f"the page has {driver.execute_async_script(VOICE_PACKETS)} packets ({before} before the pause); "
                    f"eca sent {voice.packets}, the newest {(service.clock.now_ns() - (voice.last_ns or 0)) / 1e6:.0f} "
                    f"ms ago; the page's connection to Janus: {driver.execute_async_script(JANUS_PCS)}; Janus's log:\n"
                    f"{running_logs()}")

        with talking(audio):
            sent = service.sfu.mountpoints["ada"].voice_frames if service.sfu else 0
            assert wait_until(lambda: driver.execute_async_script(VOICE_PACKETS) >= before + 25, 15.0), \
                f"the voice did not come again ({sent} frames sent before): {voice_state()}"
            windows = []
            for _ in range(6):  # a window in which the browser plays steadily (a loaded machine stretches some)
                played, base, buffered_ms, report = driver.execute_async_script(PLAYED)
                windows.append(played)
                if steady(played):
                    break
            assert steady(played), \
                f"the browser's playout never steady in {len(windows)} windows of 1 s: {windows}; {voice_state()}"
            heard_ms, newest_ms = driver.execute_script("""
                const f = window.eca.drawn.ada; f.present();
                return [f.clock.nowMs(), f.frames[f.frames.length - 1].timeMs];""")
        leg_ms = driver.execute_script("return window.eca.drawn.ada.clock.legMs")
        clock_state = driver.execute_script(VOICE_CLOCKS)
        pixels = canvas_pixels(driver)
        driver.save_screenshot(str(tmp_path / "drawn_through_janus.png"))
    # each packet played, in eca's numbering by the page's estimate, and so when eca sent it: played as long after as
    # the way and the jitter buffer held it (a packet off on Janus's numbering, 20 ms, shows here)
    assert service.sfu is not None and base is not None
    stream = service.sfu.mountpoints["ada"].audio
    assert stream is not None
    wall_offset_ms = (time.time_ns() - service.clock.now_ns()) / 1e6
    held = [played_ms - (stream.origin_ns + ((rtp + base - stream.ts_offset) % 2**32) * 1_000_000_000 // stream.rate)
            / 1e6 - wall_offset_ms for rtp, played_ms in played]
    assert abs(statistics.median(held) - trip_ms - buffered_ms) < 10.0, (held, trip_ms, buffered_ms, clock_state)
    # the page's voice clock: when eca sent what plays (the report's time is the send time, not the arrival at Janus)
    for rtp, _ in played:
        page_ms = report["ntpMs"] + ((rtp - report["rtp"] + 2**31) % 2**32 - 2**31) * 1000 / stream.rate
        sent_ns = stream.origin_ns + ((rtp + base - stream.ts_offset) % 2**32) * 1_000_000_000 // stream.rate
        assert abs(page_ms - ((sent_ns / 1e6 + wall_offset_ms) + NTP_UNIX_OFFSET_MS)) < 1.0, (page_ms, sent_ns)
    behind = heard_ms - newest_ms
    assert -1500.0 < behind < 500.0, f"the voice heard {behind:.0f} ms from the newest frame"
    top, bottom, left, right = head_box(pixels)
    assert bottom - top > 0.5 * pixels.shape[0], f"the head is {bottom - top} of {pixels.shape[0]} pixels high"
    assert service.sfu is not None and service.sfu.mountpoints["ada"].face_frames > 0
    assert not service.encoded.streams  # nothing drawn nor encoded on the server
    return float(leg_ms)




INBOUND_KINDS = """
    const done = arguments[0];
    window.eca.pc.getStats().then((stats) => { const kinds = [];
      stats.forEach((r) => { if (r.type === "inbound-rtp" && r.packetsReceived > 0) kinds.push(r.kind); });
      done(kinds.sort()); });"""


@needs_janus
@pytest.mark.skipif(browser_available() is not None, reason=str(browser_available()))
def test_with_draw_auto_through_janus_each_page_takes_only_what_it_shows(
        web_auto_head: tuple[BusConfig, WebService]) -> None:
    """draw = "auto", a 3D head, through Janus: the mountpoint has the voice, the video and the face frames. A page
    with WebGL watches the voice and the face frames and draws the head (Janus sends it no video); a page opened
    with ?draw=server watches the voice and the video."""
    _, service = web_auto_head
    assert service.sfu is not None and service.sfu.faces == ("ada",) and service.sfu.video
    with chromium() as driver:
        driver.get(service.url + "?mic=0")
        driver.find_element("id", "connect").click()
        through_janus(driver, service, lambda: wait_for(
            driver, "return window.eca.drawn.ada ? window.eca.drawn.ada.stats.received : 0", 30.0,
            "the page drawing ada from face frames through Janus", lambda n: n >= 10))
        drawn_kinds = driver.execute_async_script(INBOUND_KINDS)
        pixels = canvas_pixels(driver)
    with chromium() as driver:
        driver.get(service.url + "?mic=0&draw=server")
        driver.find_element("id", "connect").click()
        stats = sfu_frames(driver, service, 10, 30.0)
        shown_kinds = driver.execute_async_script(INBOUND_KINDS)
        drawn_here = driver.execute_script("return Object.keys(window.eca.drawn).length")
    assert drawn_kinds == ["audio"], drawn_kinds  # the voice; the face frames come on the data channel
    top, bottom, _, _ = head_box(pixels)
    assert bottom - top > 0.5 * pixels.shape[0]
    assert shown_kinds == ["audio", "video"] and drawn_here == 0, (shown_kinds, drawn_here)
    assert (stats["frameWidth"], stats["frameHeight"]) == (WIDTH, HEIGHT)

