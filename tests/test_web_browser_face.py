"""The face drawn by the page itself, in a real headless Chromium with WebGL (SwiftShader): `eca up --web --face
head` sends the voice as audio and the face frames on a data channel; the page draws the default head with
three.js. The head appears, an emotion changes its brows and mouth, the mouth opens with the voice and closes in
silence, the frames come at the asked rate, a browser without WebGL gets the server-drawn video instead, and a page
that draws through the system's EGL (Mesa's llvmpipe here; the benchmark's faster software WebGL) draws the head too.
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from eca.protocol.client import AgentClient
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import Say, SpeechFinished
from eca.services.tools.child_processes import LineReader
from tests.support.browser import (
    band_change,
    browser_available,
    canvas_pixels,
    chromium,
    head_box,
    video_stats,
    wait_for,
    webgl_renderer,
)
from tests.support.bus import eca_command, private_bus_config, running

pytestmark = [pytest.mark.slow, pytest.mark.skipif(browser_available() is not None,
                                                   reason=str(browser_available()))]
RATE = 16_000
LOGS: dict[str, LineReader] = {}


@pytest.fixture(scope="module")
def instance() -> Iterator[tuple[BusConfig, str]]:
    """`eca up --web --face head` (dialogue, gaze, audio, web; no sound card) on a free port; its page's address."""
    with private_bus_config(services=["dialogue", "gaze", "audio"]) as config:
        argv = eca_command("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet",
                           "--web", "--web-port", "0", "--face", "head", "--silent-audio")
        with running(argv) as (_proc, reader):
            reader.wait_for("[up] ready in", 90.0)
            line = reader.lines[reader.wait_for("[web] INFO serving http://", 10.0)]
            match = re.search(r"(http://\S+/)", line)
            assert match
            LOGS[match.group(1)] = reader
            yield config, match.group(1)


def said(url: str) -> str:
    lines = LOGS[url.split("?")[0]].lines
    return "\n".join([line for line in lines if line.startswith(("[web]", "[up]"))][-30:])


def connect_drawing(driver: Any, url: str) -> None:
    driver.get(url)
    driver.find_element("id", "connect").click()
    wait_for(driver, "return window.eca.state", 30.0, "the page connecting", lambda s: s == "connected")
    wait_for(driver, "return window.eca.drawn.ada ? window.eca.drawn.ada.stats.received : 0", 30.0,
             f"the page drawing ada from face frames\n{said(url)}", lambda n: n >= 5)


HEARD_MOUTH = """
    const f = window.eca.drawn.ada; const heard = f.heardFrame(); let m = 0, at = 0;
    f.d.primitives.forEach((p) => { for (let k = 0; k < p.targets; k += 1) {
      if (p.voiced[k]) m = Math.max(m, heard.weights[at + k] / 255); } at += p.targets; });
    return [m, !!(heard.flags & 1)];"""


def mouth_open(driver: Any) -> float:
    """The largest weight the page gives a target the voice moves (jaw, mouth) right now (drawn)."""
    return float(driver.execute_script("""
        const f = window.eca.drawn.ada; f.present(); let m = 0;
        f.d.primitives.forEach((p, i) => { const mesh = f.targets[i]; if (!mesh) return;
          p.voiced.forEach((v, k) => { if (v) m = Math.max(m, mesh.morphTargetInfluences[k]); }); });
        return m;"""))


def heard_mouth(driver: Any) -> tuple[float, bool]:
    """What the page would draw on the voiced targets for the frame heard now, and whether that frame is voiced:
    the page's own choice of frame, read without drawing (a loaded machine's software WebGL draws slowly)."""
    mouth, voiced = driver.execute_script(HEARD_MOUTH)
    return float(mouth), bool(voiced)


def tone(seconds: float) -> bytes:
    t = np.arange(int(seconds * RATE)) / RATE
    return (0.4 * np.sin(2 * np.pi * 220 * t) * (1 + 0.8 * np.sin(2 * np.pi * 4 * t)) * 32767 / 1.8) \
        .astype("<i2").tobytes()


def test_the_page_draws_the_head_and_an_emotion_changes_its_brows_and_mouth(instance: tuple[BusConfig, str],
                                                                             tmp_path: Any) -> None:
    config, url = instance
    with chromium() as driver, AgentClient(config) as client:
        connect_drawing(driver, url + "?mic=0")
        assert driver.execute_script("return document.querySelector('#faces video')") is None  # no video drawn
        client.wait_applied(client.set_emotion("natural", transition_s=0.1), 10.0)
        time.sleep(1.0)  # the behaviour under test is the face after the transition (not synchronisation)
        before = canvas_pixels(driver)
        box = head_box(before)
        client.wait_applied(client.set_emotion("surprised", transition_s=0.2), 10.0)
        time.sleep(1.0)  # the transition's time
        after = canvas_pixels(driver)
        driver.save_screenshot(str(tmp_path / "surprised.png"))
    top, bottom, left, right = box
    assert bottom - top > 0.5 * before.shape[0], f"the head is {bottom - top} of {before.shape[0]} pixels high"
    assert (before[top:bottom, left:right].astype(int).sum(axis=2) > 0).mean() > 0.9  # drawn, not black
    brows = band_change(before, after, box, 0.22, 0.40)
    mouth = band_change(before, after, box, 0.62, 0.82)
    still = band_change(before, after, box, 0.90, 1.0)  # the neck under the chin: surprise moves it little
    assert brows > 2.0 and mouth > 2.0, (brows, mouth, still)
    assert still < min(brows, mouth), (brows, mouth, still)


RECORD_FRAMES = """
    const f = window.eca.drawn.ada; window.ecaRecorded = []; const push = f.push.bind(f);
    f.push = (buffer) => {
      const before = f.frames.length ? f.frames[f.frames.length - 1].seq : -1;
      const ok = push(buffer); const last = f.frames[f.frames.length - 1];
      if (last && last.seq !== before) {
        let m = 0, at = 0;
        f.d.primitives.forEach((p) => { for (let k = 0; k < p.targets; k += 1) {
          if (p.voiced[k]) m = Math.max(m, last.weights[at + k] / 255); } at += p.targets; });
        window.ecaRecorded.push([last.timeMs, last.flags & 1, m]);
      }
      return ok;
    };"""


def test_the_mouth_opens_with_the_voice_and_closes_in_silence(instance: tuple[BusConfig, str]) -> None:
    """Every face frame the page receives is recorded by the page itself as it arrives (a loaded machine's
    software WebGL makes each round trip from the test slow, so the test reads the record once, after)."""
    config, url = instance
    with chromium() as driver, AgentClient(config) as client:
        connect_drawing(driver, url + "?mic=0")
        client.wait_applied(client.set_emotion("natural", transition_s=0.1), 10.0)
        time.sleep(1.0)  # the transition's time
        quiet = max(heard_mouth(driver)[0] for _ in range(3))
        driver.execute_script(RECORD_FRAMES)
        rid = client.new_request_id()
        client.wait_applied(client.send(Say(agent="ada", request_id=rid, pcm=tone(3.0), sample_rate=RATE)), 10.0)
        client.wait_for(lambda m: getattr(m, "request_id", None) == rid and m.TYPE == "speech_started", 10.0)
        wait_for(driver, "return window.eca.drawn.ada.stats.voiced", 15.0, "the page hearing the voice")
        assert isinstance(client.wait_for_speech(rid, 20.0), SpeechFinished)
        wait_for(driver, "return !window.eca.drawn.ada.stats.voiced", 15.0, "the page hearing the silence")
        time.sleep(0.5)  # the lips' own release
        after = max(heard_mouth(driver)[0] for _ in range(3))
        synced = driver.execute_script("return window.eca.drawn.ada.stats.syncedMs")
        recorded = np.array(driver.execute_script("return window.ecaRecorded"), dtype=np.float64)
    assert synced is not None, "the page never knew what the voice played"
    voiced = recorded[recorded[:, 1] == 1]
    assert len(voiced) >= 30, f"{len(voiced)} voiced frames for 3 s of voice"  # 30 fps asked; a loaded host sends fewer
    speaking = voiced[:, 2]
    assert speaking.max() > 0.2, f"the mouth never opened with the voice: {speaking.max():.3f}"
    assert np.std(speaking) > 0.03, "the mouth did not move with the voice"  # the tone's 4 Hz swell
    last_voiced = voiced[-1, 0]
    closed = recorded[(recorded[:, 1] == 0) & (recorded[:, 0] > last_voiced + 300)]  # past the lips' release
    assert len(closed) and closed[:, 2].max() < 0.1, closed[:, 2].max() if len(closed) else "no frames after"
    assert quiet < 0.1 and after < 0.1, (quiet, after)


RECEIVED = """const f = window.eca.drawn.ada; const last = f.frames[f.frames.length - 1];
               return [f.stats.received, last ? last.timeMs : null, f.stats.bad];"""


def test_face_frames_come_at_the_asked_rate(instance: tuple[BusConfig, str]) -> None:
    """The frames the page received over a span, against the span of their own times (when they were made): the
    rate the server sends them at, whatever a loaded machine does to when they arrive."""
    _config, url = instance
    with chromium() as driver:
        connect_drawing(driver, url + "?mic=0&fps=20")
        first, first_ms, _ = driver.execute_script(RECEIVED)
        time.sleep(3.0)  # counting frames over a span
        last, last_ms, bad = driver.execute_script(RECEIVED)
    span_s = (last_ms - first_ms) / 1000
    assert span_s > 1.5, span_s
    rate = (last - first) / span_s
    assert 0.8 * 20 <= rate <= 1.15 * 20, f"{last - first} frames over {span_s:.2f} s of their times at 20 fps"
    assert bad == 0


BAD_SPURTS = """
    const f = window.eca.drawn.ada; const before = f.stats.bad;
    const message = (count, bytes, timeMs, wayMs) => { const b = new ArrayBuffer(bytes); const v = new DataView(b);
      v.setUint8(2, 3); v.setUint8(3, count); v.setFloat64(8, timeMs, true); v.setFloat32(16, wayMs, true);
      return b; };
    const pushed = [message(1, 28, 1e12, 5), message(2, 28, 1e12, 5), message(0, 22, 1e12, 5),
                    message(1, 28, NaN, 5), message(1, 28, 1e12, -1), message(1, 28, 1e12, NaN)].map((b) => f.push(b));
    return [pushed, f.stats.bad - before];"""


def test_the_page_drops_malformed_voice_clocks(instance: tuple[BusConfig, str]) -> None:
    """A voice clock through Janus (kind 3) that is not whole or says no time is dropped and counted: a count of
    spurts its length does not hold, no spurt, a time or a way to Janus that is not a number, a negative way. A
    whole one is taken (and ignored by a page whose voice comes straight from eca)."""
    _config, url = instance
    with chromium() as driver:
        connect_drawing(driver, url + "?mic=0")
        pushed, bad = driver.execute_script(BAD_SPURTS)
    assert pushed == [True, False, False, False, False, False] and bad == 5, (pushed, bad)


def test_a_browser_without_webgl_gets_the_server_drawn_video(instance: tuple[BusConfig, str]) -> None:
    _config, url = instance
    with chromium(webgl=False) as driver:
        driver.get(url + "?mic=0&width=320&height=240&fps=15")
        driver.find_element("id", "connect").click()
        wait_for(driver, "return window.eca.state", 30.0, "the page connecting", lambda s: s == "connected")
        deadline = time.monotonic() + 30.0
        while (video_stats(driver).get("framesDecoded") or 0) < 10 and time.monotonic() < deadline:
            time.sleep(0.2)  # polling the page's counters
        stats = video_stats(driver)
        drawn = driver.execute_script("return Object.keys(window.eca.drawn).length")
    assert (stats.get("framesDecoded") or 0) >= 10, f"{stats}\n{said(url)}"
    assert (stats["frameWidth"], stats["frameHeight"]) == (320, 240)
    assert drawn == 0


def test_the_page_draws_the_head_through_the_systems_egl_too(instance: tuple[BusConfig, str]) -> None:
    """The benchmark's faster software WebGL (bench/web.py --browser-gl egl): ANGLE on the system's EGL, Mesa's
    llvmpipe here, draws the same head (not SwiftShader's renderer, and pixels where the head is)."""
    _config, url = instance
    with chromium(gl="egl") as driver:
        connect_drawing(driver, url + "?mic=0")
        renderer = webgl_renderer(driver)
        pixels = canvas_pixels(driver)
    assert renderer and "SwiftShader" not in renderer, renderer
    top, bottom, left, right = head_box(pixels)
    assert bottom - top > 0.5 * pixels.shape[0], f"the head is {bottom - top} of {pixels.shape[0]} pixels high"
    assert (pixels[top:bottom, left:right].astype(int).sum(axis=2) > 0).mean() > 0.9  # drawn, not black


def test_an_unknown_software_gl_is_refused() -> None:
    with pytest.raises(ValueError, match="gl must be one of"), chromium(gl="vulkan"):
        pass


# An audio receiver as the page's voice clock reads it, of the voice Janus relays from `packets[firstRelayed]` on: the
# script sets `newest` (the packet that arrived last) and `arrived` (when, on the page's clock) before each report
FAKE_RECEIVER = """
  let newest = packets[firstRelayed], arrived = 0;
  const receiver = { getSynchronizationSources: () => [], getStats: async () => new Map([
    ["in", { type: "inbound-rtp", packetsReceived: newest.seq - packets[firstRelayed].seq + 1, packetsLost: 0,
             lastPacketReceivedTimestamp: arrived }],
    ["tr", { type: "transport", selectedCandidatePairId: "cp" }],
    ["cp", { type: "candidate-pair", currentRoundTripTime: 2 * LEG_MS / 1000 }],
  ]) };
"""

JANUS_NUMBERING = """
const done = arguments[arguments.length - 1];
(async () => {
  const { VoiceClock } = await import("./static/face3d.js");
  const OFFSET_MS = 123456.5, NTP = 2208988800000, WAY_MS = 7, LEG_MS = 11;  // server ahead; eca -> Janus -> page
  const pageNow = () => performance.timeOrigin + performance.now();
  // the server's voice: three talk spurts with pauses, sequence numbers and RTP timestamps about to wrap
  const seq0 = 65530, ts0 = 2 ** 32 - 5000, t0 = pageNow() + OFFSET_MS + NTP;  // server NTP ms of the first packet
  const packets = [];  // { seq (unwrapped), ts, sentMs, spurt }
  let seq = seq0, slot = 0;  // slot: 20 ms frames of the master clock since t0
  for (const [spurt, length, pause] of [[0, 10, 25], [1, 20, 15], [2, 30, 0]]) {
    for (let i = 0; i < length; i += 1, seq += 1, slot += 1) {
      packets.push({ seq, ts: (ts0 + slot * 960) % 2 ** 32, sentMs: t0 + slot * 20, spurt, first: i === 0 });
    }
    slot += pause;
  }
  const firstRelayed = 3;  // Janus relayed from the fourth packet of the first spurt on
  let lateness = 1;
  const late = () => { lateness = (lateness * 75) % 65537; return lateness % 7 === 0 ? 1 : 5 + lateness % 40; };
""" + FAKE_RECEIVER + """
  const clock = new VoiceClock(receiver, { serverClock: async () => ({ unix_ms: pageNow() + OFFSET_MS }) });
  while (clock.serverOffsetMs() == null) await new Promise((r) => setTimeout(r, 10));  // its first ask answered
  // the page hears from the server only once the first spurt is over (its data channel opened late): reports at
  // each later spurt's first packet and every 12 packets, each naming the latest spurts
  const spurts = [];
  for (const p of packets) {
    if (p.first) spurts.push([p.seq % 2 ** 16, p.ts]);
    if (p.spurt === 0 || !(p.first || p.seq % 12 === 0)) continue;
    newest = p;
    arrived = p.sentMs - NTP - OFFSET_MS + WAY_MS + LEG_MS + late();  // on the page's clock
    clock.onSpurts(p.ts, p.sentMs, WAY_MS, p.seq % 2 ** 16, spurts.slice(-8));
    await new Promise((r) => setTimeout(r, 0));
  }
  done([clock.base, packets[firstRelayed].ts, clock.rebasings || 0, clock.legMs]);
  clock.stop();
})().catch((e) => done(String(e)));
"""


JANUS_EARLY_READING = """
const watched = arguments[0], done = arguments[arguments.length - 1];
(async () => {
  const { VoiceClock } = await import("./static/face3d.js");
  const OFFSET_MS = -5000.25, NTP = 2208988800000, WAY_MS = 3, LEG_MS = 4;
  const pageNow = () => performance.timeOrigin + performance.now();
  // an earlier talk spurt, a second's pause, then the spurt this page hears from its first packet on
  const t0 = pageNow() + OFFSET_MS + NTP - 5000, ts0 = 77777, seq0 = 1000;
  const packets = [];
  let seq = seq0, slot = 0;
  for (const [spurt, length, pause] of [[0, 10, 50], [1, 40, 0]]) {
    for (let i = 0; i < length; i += 1, seq += 1, slot += 1) {
      packets.push({ seq, ts: ts0 + slot * 960, sentMs: t0 + slot * 20, spurt, first: i === 0 });
    }
    slot += pause;
  }
  const firstRelayed = 10;  // the second spurt's first packet
  // the page asked Janus for the voice 200 ms before that packet left (on the page's clock)
  const watchedSinceMs = packets[firstRelayed].sentMs - NTP - OFFSET_MS - 200;
""" + FAKE_RECEIVER + """
  const clock = new VoiceClock(receiver, { serverClock: async () => ({ unix_ms: pageNow() + OFFSET_MS }),
                                           watchedSinceMs: watched ? watchedSinceMs : null });
  while (clock.serverOffsetMs() == null) await new Promise((r) => setTimeout(r, 10));
  const spurts = [];
  for (const p of packets) {
    if (p.first) spurts.push([p.seq % 2 ** 16, p.ts]);
    if (p.spurt === 0 || !(p.first || p.seq % 12 === 0)) continue;
    newest = p;
    // the first reading 15 ms early (the clocks' offset misjudged under load), the others 1-9 ms late
    const error = p.first ? -15 : 1 + (p.seq * 7) % 9;
    arrived = p.sentMs - NTP - OFFSET_MS + WAY_MS + LEG_MS + error;
    clock.onSpurts(p.ts, p.sentMs, WAY_MS, p.seq % 2 ** 16, spurts.slice(-8));
    await new Promise((r) => setTimeout(r, 0));
  }
  done([clock.base, packets[firstRelayed].ts, clock.rebasings || 0]);
  clock.stop();
})().catch((e) => done(String(e)));
"""


@pytest.mark.skipif(browser_available() is not None, reason=str(browser_available()))
def test_an_early_reading_at_a_spurt_s_first_packet_does_not_put_janus_s_first_a_pause_earlier(
        instance: tuple[BusConfig, str]) -> None:
    """Through Janus, a reading of the voice's clock that comes out early (a loaded page misjudges the clocks' offset)
    at the first packet of a talk spurt points at the packet before, the last of the spurt before, whose RTP timestamp
    is a whole pause earlier: the page, which takes the lowest of its readings, would show the mouth that pause away
    from the voice (a real Chromium once had its clock 9.9 s off, the pause before its first spurt). Knowing when it
    asked Janus for the voice, the page drops a reading that says Janus's first packet left before then. Without that
    (the control) the same readings go wrong."""
    _, url = instance
    with chromium() as driver:
        driver.get(url + "?mic=0")
        got = driver.execute_async_script(JANUS_EARLY_READING, True)
        control = driver.execute_async_script(JANUS_EARLY_READING, False)
    assert isinstance(got, list) and isinstance(control, list), (got, control)
    base, truth, rebasings = got
    assert rebasings >= 3 and base == truth, f"the page took {base}, Janus numbers from {truth}"
    assert (truth - control[0]) % 2**32 == 51 * 960, control  # the control: a pause and a packet (51 frames) early


SERVER_CLOCK_WHILE_BUSY = """
const done = arguments[arguments.length - 1];
(async () => {
  const face3d = await import("./static/face3d.js");
  // the page's script is held up 100 ms just after each ask leaves (as software WebGL drawing holds it): the answer
  // is there in a few milliseconds, its callback runs when the 100 ms are over
  const busy = (ask) => () => { const answer = ask(); const end = performance.now() + 100;
                                while (performance.now() < end) { /* the page drawing */ } return answer; };
  const offsets = [];
  for (const ask of [() => face3d.askServerClock("./clock"),
                     async () => (await fetch("./clock", { cache: "no-store" })).json()]) {
    const clock = new face3d.VoiceClock(null, { serverClock: busy(ask) });
    while (clock.asks.length < 4) await new Promise((r) => setTimeout(r, 20));  // its first four asks
    const quickest = clock.asks.reduce((x, y) => (y.rttMs < x.rttMs ? y : x));  // the ask the offset comes from
    offsets.push([clock.serverOffsetMs(), quickest.rttMs]);
    clock.stop();
  }
  done(offsets);
})().catch((e) => done(String(e)));
"""


@pytest.mark.skipif(browser_available() is not None, reason=str(browser_available()))
def test_the_page_reads_the_server_s_clock_right_while_its_script_is_held_up(instance: tuple[BusConfig, str]) -> None:
    """Through Janus the page dates each voice packet on the server's clock, which it learns by asking (GET /clock).
    Timed by when the page's script ran, an answer whose callback a busy page runs late looks like a long way back,
    and the midpoint puts the server's clock early by half of it: every reading of which packet Janus relayed first
    one packet early, all of them dropped, and the voice's numbering never found (a real Chromium through Janus,
    "rebasings 0"). Timed by the browser's network timing of each request, it holds. The server here is this
    machine: its clock is the page's (the offset is 0 within a millisecond or two). The control times by the script."""
    _, url = instance
    with chromium() as driver:
        driver.get(url + "?mic=0")
        got = driver.execute_async_script(SERVER_CLOCK_WHILE_BUSY)
    assert isinstance(got, list), got
    (timed, timed_rtt), (by_script, script_rtt) = got
    # timed by the network, the 100 ms hold is not in the round trip, and the offset is within half of it (all that a
    # midpoint can promise: a loaded server answers late, never early)
    assert timed_rtt < 100.0 and abs(timed) <= timed_rtt / 2 + 2.0, got
    # the control: the hold is in its round trip, and it puts the server's clock early by about half of it (less the
    # server's time to answer)
    assert script_rtt >= 100.0 and by_script <= -15.0, got


@pytest.mark.skipif(browser_available() is not None, reason=str(browser_available()))
def test_the_page_finds_janus_s_first_packet_across_pauses_in_the_voice(instance: tuple[BusConfig, str]) -> None:
    """Through Janus, the page's voice clock (static/face3d.js VoiceClock) finds the RTP timestamp of the first packet
    Janus relayed to it, which Janus's numbering starts from, when the voice pauses in silence and the page hears of
    it only after the first talk spurt is over: its packet counts are mapped to packets through the spurts the server
    names, sequence numbers and timestamps wrapping on the way, most readings late by up to 45 ms. A count that took
    the voice as continuous would put that packet a pause's length too late."""
    _, url = instance
    with chromium() as driver:
        driver.get(url + "?mic=0")
        got = driver.execute_async_script(JANUS_NUMBERING)
    assert isinstance(got, list), got
    base, truth, rebasings, leg_ms = got
    assert rebasings >= 5 and abs(leg_ms - 11) < 0.01, got
    assert base == truth, f"the page took {base}, Janus numbers from {truth} ({(base - truth) % 2**32 / 960} packets)"
