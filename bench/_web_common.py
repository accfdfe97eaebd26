"""Bench part for bench/web.py: what its phases share: the settings, the page's clock tied to this host's, the private
instance, the page's connection, and the in-process baselines of drawing and encoding the face."""

from __future__ import annotations

import math
import os
import re
import statistics
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from bench._web_page import CLOCK_JS, CLOSE_CALIBRATION_JS, VIDEO_STATS_JS
from bench.report import percentile
from eca.services.processes.web.calibration import PATCH

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

AGENT = "ada"
FPS = 30.0


@dataclass
class VideoSize:
    """The server-drawn video every phase asks for (--size sets it before any phase runs)."""

    width: int = 640
    height: int = 480


VIDEO = VideoSize()
READY_TIMEOUT_S = 90.0
HEARTBEAT_TIMEOUT_S = 10.0  # the bench's instances' supervisor (the product's default: 1.5 s; see instance())
CONNECT_TIMEOUT_S = 30.0

# A/V
BURST_S = 0.25
# a burst a second, its onset drawn from this span after the whole second of the master clock (a frame
# slot): onsets at every phase of the slots, and each burst and click with ONSET_QUIET_S of quiet before it
BURST_AFTER_SECOND_S = (0.36, 0.40)
CLEAR_AFTER_CLICK_S = (0.22, 0.54)  # a burst with its onset outside this (a say that started late) nears a click
SAY_RATE_HZ = 16_000
ONSET_LEVEL = 0.05  # of full scale: the first sample over it after ONSET_QUIET_S below it is an onset
ONSET_QUIET_S = 0.2
PAIR_WINDOW_MS = 300.0  # an audio onset and a mouth opening (flash) this close belong together
MOUTH_BOX = (0.34, 0.58, 0.66, 0.92)  # x0, y0, x1, y1 of the picture, around the mouth at 640x480
# inside a reference's flashing patch, clear of its edges (which the encoder blurs into the face)
PATCH_BOX = tuple(a + (b - a) * f for a, b, f in zip(PATCH[:2] * 2, PATCH[2:] * 2, (0.2, 0.2, 0.8, 0.8), strict=True))
MAX_SAY_S = 100.0  # the say's inline PCM (16 kHz, 16 bit) stays well under the bus's 4 MiB message cap
TRAJECTORY_WINDOW_S = 10.0
MARKED = "marked"  # the connection of the agent with the calibration markers on it (flashes and clicks)

# the face drawn in the browser (a second instance, its agent's face the default 3D head)
DRAWN_FACE = "head"
DRAWN = "drawn"  # the page's connection that draws the face itself, with the clicks on its voice
# A quiet tone under the bursts keeps the voice sounding at every frame (the service's "voiced" flag: a sample
# over 64 of 32767 within 10 ms), so the page shows a frame's voice part when its sound plays, at the marked
# seconds too, not as it arrives (face3d.js present(): in silence the newest frame is shown). Far under
# ONSET_LEVEL, and under the lip-sync's speech gate (30 dB below the bursts): it opens no mouth.
HUM_LEVEL = 0.008
HUM_HZ = 150.0
SAY_PART_S = 60.0  # the talk: says of this length, queued back to back (the player plays a queue without gaps)
LEAD_IN_S = 4.0  # the talk's first say, the hum alone: when it starts tells where the bursts that follow go
QUEUE_AHEAD_S = 15.0  # the next say is sent when the queued talk ends within this
DRAWN_SETTLE_S = 5.0  # latency: the browser-drawn face's frames flow this long before the first command
DRAWN_ALONE_SETTLE_S = 10.0  # A/V: the face alone is measured from this long after connecting

# latency
EMOTIONS = ("surprised", "angry")  # brows, eyes and mouth all move: far apart in a thumbnail
PAUSE_S = (0.6, 0.9)  # between commands, drawn per command: commands land at every phase of the slots
SIGNATURE_SIZE = (32, 24)

# viewers
VIEWER_SETTLE_S = 3.0
VIEWER_WINDOW_S = 6.0
AFTER_LEAVING_S = 5.0

# Targets
TARGET_AV_DIFF_MS = 15.0
ATSC_EARLY_MS, ATSC_LATE_MS = 15.0, 45.0
TARGET_LATENCY_P95_MS = 100.0
TARGET_DRAWN_LATENCY_P95_MS = 60.0
TARGET_CPU_PER_VIEWER = 10.0  # % of one core
TARGET_FPS_MIN = 28.0
TARGET_RSS_RETURN = 0.10


def progress(line: str) -> None:
    print(f"[web-bench] {line}", file=sys.stderr, flush=True)


def spread(values: list[float]) -> dict[str, float]:
    if not values:
        return {"n": 0}
    return {"n": len(values), "median": round(statistics.median(values), 2), "p10": round(percentile(values, 0.1), 2),
            "p90": round(percentile(values, 0.9), 2), "p95": round(percentile(values, 0.95), 2),
            "mean": round(statistics.fmean(values), 2)}



# --- the page's clock against this host's monotonic clock -----------------------------------------


class TimeServer:
    """A tiny HTTP server answering each GET with this host's monotonic time (ns), for the page."""

    def __init__(self) -> None:
        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:  # noqa: N802 (http.server's name)
                body = str(time.monotonic_ns()).encode()
                self.send_response(200)
                self.send_header("Access-Control-Allow-Origin", "*")  # the page is another origin (port)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args: Any) -> None:
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/now"
        self._thread = threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.1},
                                        daemon=True, name="time-server")

    def __enter__(self) -> TimeServer:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.shutdown()
        self.server.server_close()
        self._thread.join(timeout=5)


@dataclass(frozen=True)
class ClockTie:
    """host monotonic ms = page ms + offset_ms, to within +-uncertainty_ms."""

    offset_ms: float
    uncertainty_ms: float

    def host_ms(self, page_ms: float) -> float:
        return page_ms + self.offset_ms



class EmotionStates:
    """The agent's emotion states as the bus publishes them, (t_ns, name) each, read while the bench waits."""

    def __init__(self, ctx: Any, config: Any) -> None:
        from eca.protocol.bus import Subscriber

        self.sub = Subscriber(ctx, config, [f"state.{AGENT}.emotion"])
        self.sub.wait_ready()
        self.seen: list[tuple[int, str]] = []

    def listen(self, left_s: float) -> None:
        from eca.protocol.messages import EmotionState

        got = self.sub.recv(left_s)
        while got is not None:
            if isinstance(got.message, EmotionState):
                self.seen.append((got.message.t_ns, got.message.name))
            got = self.sub.recv(0.0)

    def close(self) -> None:
        self.sub.close()

def tie_clocks(driver: Any, server: TimeServer, round_trips: int = 40) -> ClockTie:
    """The browser's time at the middle of the fastest of `round_trips` GETs, against the host's."""
    got = driver.execute_async_script(CLOCK_JS, server.url, round_trips)
    if isinstance(got, dict):
        raise RuntimeError(f"the page could not reach the bench's clock: {got['error']}")
    t0, t1, host = min(got, key=lambda r: r[1] - r[0])
    return ClockTie(int(host) / 1e6 - (t0 + t1) / 2, (t1 - t0) / 2)


def combined_tie(ties: list[ClockTie]) -> tuple[ClockTie, float]:
    """One tie from several (the mean; the uncertainty covers each and their spread), and the drift seen."""
    offsets = [t.offset_ms for t in ties]
    drift = max(offsets) - min(offsets)
    return ClockTie(statistics.fmean(offsets), max(t.uncertainty_ms for t in ties) + drift / 2), drift


# --- the instance ----------------------------------------------------------------------------------


class HeartbeatWatch:
    """The heartbeats of one service on the bus, in a thread: the longest silence between two."""

    def __init__(self, config: Any, service: str) -> None:
        self.config, self.service = config, service
        self.longest_s = 0.0
        self.longest_at = 0.0  # when that silence ended (monotonic s)
        self.beats = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, daemon=True, name="heartbeat-watch")

    def _watch(self) -> None:
        import zmq

        from eca.protocol.bus import Subscriber
        from eca.protocol.messages import Heartbeat

        ctx = zmq.Context()
        sub = Subscriber(ctx, self.config, ["sys."])
        last: float | None = None
        try:
            while not self._stop.is_set():
                got = sub.recv(0.2)
                if got is None or not isinstance(got.message, Heartbeat) or got.message.service != self.service:
                    continue
                now = time.monotonic()
                if last is not None and now - last > self.longest_s:
                    self.longest_s, self.longest_at = now - last, now
                last = now
                self.beats += 1
        finally:
            sub.close()
            ctx.term()

    def __enter__(self) -> HeartbeatWatch:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


@dataclass
class Instance:
    config: Any
    reader: Any
    url: str
    web_pid: int
    beats: HeartbeatWatch

    def viewers_watching(self, since: int = 0) -> int | None:
        """How many viewers the web service says watch, from its latest 'left' line from line `since` on
        (None: none)."""
        for line in reversed(self.reader.lines[since:]):
            m = re.search(r"\[web\] INFO viewer \d+ left \((\d+) watching\)", line)
            if m:
                return int(m.group(1))
        return None


@contextmanager
def instance(face: str | None = None) -> Iterator[Instance]:
    """`eca up --web` on a private instance and a free port; with `face`, every agent's face (`--face`)."""
    from eca.services.tools.child_processes import eca_command
    from tests.support.bus import private_bus_config, running

    # The supervisor restarts a service whose loop is silent for [heartbeat] timeout_s (1.5 s); on a loaded machine
    # the web service's loop stalled longer (the figure "loop: longest stall"), and a web service restarted on
    # port 0 serves on another port, which ends the run: the bench's instances wait HEARTBEAT_TIMEOUT_S.
    with private_bus_config(services=["dialogue", "gaze", "audio"],
                            extra=f"[heartbeat]\ninterval_s = 0.25\ntimeout_s = {HEARTBEAT_TIMEOUT_S:g}\n") as config:
        # The product's own viewer watchdog runs (silent_timeout_s): the bench's connections last minutes,
        # so a healthy page closed as silent shows in the figures below.
        argv = eca_command("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet",
                           "--web", "--web-port", "0", *(("--face", face) if face else ()))
        progress(f"starting eca up --web{f' --face {face}' if face else ''} (instance {config.instance})")
        with running(argv, stop_timeout_s=10.0) as (proc, reader):
            try:
                reader.wait_for("[up] ready in", READY_TIMEOUT_S)
            except TimeoutError:
                said = [line for line in reader.lines if re.search(r"ERROR|Error|not restarted", line)]
                raise RuntimeError(f"eca up was not ready within {READY_TIMEOUT_S:g} s: "
                                   f"{' | '.join(said[-3:]) or 'no error printed'}") from None
            line = reader.lines[reader.wait_for("[web] INFO serving http://", 10.0)]
            url = re.search(r"(http://\S+/)", line)
            ready = reader.lines[reader.wait_for("[web] INFO ready (pid", 10.0)]
            pid = re.search(r"ready \(pid (\d+)\)", ready)
            assert url is not None and pid is not None
            with HeartbeatWatch(config, "web") as beats:
                yield Instance(config, reader, url.group(1), int(pid.group(1)), beats)


def open_page(driver: Any, url: str) -> None:
    driver.get(f"{url}?mic=0&width={VIDEO.width}&height={VIDEO.height}&fps={FPS:g}")
    connect_page(driver)


def connect_page(driver: Any) -> None:
    from tests.support.browser import wait_for

    driver.find_element("id", "connect").click()
    wait_for(driver, "return window.eca.state", CONNECT_TIMEOUT_S, "the page connecting", lambda s: s == "connected")


def video_stats(driver: Any, which: str = "face") -> dict[str, Any]:
    got = driver.execute_async_script(VIDEO_STATS_JS, which)
    return got or {}


# --- in-process baselines: the face drawn once, and its VP8 encode ------------------------------


def draw_and_encode_baselines(frames: int = 150) -> dict[str, float]:
    """Per frame at 640x480, in this process, as the service does them: compose + draw + yuv420p on the
    GPU + read-back (once per frame slot), and the VP8 encode of the result (once per picture for all
    the viewers of that size and rate)."""
    from eca.agent.face.model import FaceModel
    from eca.services.processes.renderer import Renderer, create_headless_context
    from eca.services.processes.renderer.yuv import YuvTarget
    from eca.services.processes.web.encoding import Vp8Encoder
    from eca.services.processes.web.feeds import Picture

    os.environ.setdefault("LP_NUM_THREADS", "1")  # as the web service draws (services/processes/web/service.py)
    ctx = create_headless_context()
    try:
        renderer = Renderer(ctx, (VIDEO.width, VIDEO.height))
        target = YuvTarget(ctx, (VIDEO.width, VIDEO.height))
        model = FaceModel(seed=1)
        encoder = Vp8Encoder(VIDEO.width, VIDEO.height, FPS)
        period_ns = round(1e9 / FPS)
        draw_ms: list[float] = []
        encode_ms: list[float] = []
        for i in range(frames + 20):  # the first 20: shader variants compile, the encoder starts
            t_ns = i * period_ns
            if i % 30 == 0:
                model.set_emotion(EMOTIONS[(i // 30) % 2], 1.0, t_ns=t_ns)
            model.set_eyes(15.0 * math.sin(i * 0.11), 8.0 * math.cos(i * 0.07), 1.0 if i % 90 < 5 else None)
            model.set_mouth({"say_ah": 0.5 + 0.5 * math.sin(i * 0.4)})
            t0 = time.perf_counter()
            renderer.render(model.frame_at(t_ns).values, target=target.fbo)
            yuv = target.read()
            t1 = time.perf_counter()
            encoder.encode(Picture(t_ns, yuv, VIDEO.width, VIDEO.height), keyframe=False)
            t2 = time.perf_counter()
            if i >= 20:
                draw_ms.append(1e3 * (t1 - t0))
                encode_ms.append(1e3 * (t2 - t1))
        target.release()
    finally:
        ctx.release()
    return {"draw_ms": statistics.median(draw_ms), "draw_p95_ms": percentile(draw_ms, 0.95),
            "encode_ms": statistics.median(encode_ms), "encode_p95_ms": percentile(encode_ms, 0.95),
            "frames": frames}


def rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def disconnect_page(driver: Any) -> None:
    """The page's connections closed (the bench's measuring paused): it watches nothing."""
    driver.execute_script(CLOSE_CALIBRATION_JS)
    driver.execute_script("""
      if (window.ecaBench) window.ecaBench.paused = true;
      if (window.eca && window.eca.pc) document.getElementById("connect").click();""")
