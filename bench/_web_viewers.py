"""Bench part for bench/web.py, phase 3: the web service's cost per viewer, and the load process (aiortc viewers that
receive but do not decode; see bench/web.py's docstring)."""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from bench._stdio import say, stdin_lines
from bench._web_common import (
    AFTER_LEAVING_S,
    AGENT,
    CONNECT_TIMEOUT_S,
    FPS,
    REPO,
    TARGET_CPU_PER_VIEWER,
    TARGET_FPS_MIN,
    TARGET_RSS_RETURN,
    VIDEO,
    VIEWER_SETTLE_S,
    VIEWER_WINDOW_S,
    Instance,
    connect_page,
    disconnect_page,
    progress,
    rss_mib,
    video_stats,
)
from bench._web_latency import delta
from bench.procs import cpu_seconds
from bench.report import Report
from eca.services.tools.child_processes import subprocess_env


@contextmanager
def load_process(url: str, drawn: bool = False) -> Iterator[tuple[subprocess.Popen[bytes], Any]]:
    """The helper process holding the aiortc viewers (`drawn`: viewers that draw the face themselves); killed
    (its group) afterwards."""
    from eca.services.tools.child_processes import LineReader

    argv = [sys.executable, str(REPO / "bench" / "web.py"), "--role", "load", "--url", url,
            *(("--drawn",) if drawn else ())]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stdin=subprocess.PIPE, env=subprocess_env(), cwd=REPO,
                            start_new_session=True)
    try:
        yield proc, LineReader(proc.stdout)
    finally:
        try:
            assert proc.stdin is not None
            proc.stdin.close()  # it closes its connections and exits
            proc.wait(timeout=10)
        except (OSError, subprocess.TimeoutExpired):
            pass
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait(timeout=5)


def ask(proc: subprocess.Popen[bytes], reader: Any, line: str, timeout_s: float) -> dict[str, Any]:
    """Send a command line to the load process; its JSON answer."""
    assert proc.stdin is not None
    start = len(reader.lines)
    proc.stdin.write((line + "\n").encode())
    proc.stdin.flush()
    index = reader.wait_for("{", timeout_s, start)
    answer: dict[str, Any] = json.loads(reader.lines[index])
    return answer


def measure_window(pid: int, driver: Any | None, load: tuple[Any, Any] | None, seconds: float) -> dict[str, Any]:
    """The web service's CPU share and RSS over `seconds`; the page's and the aiortc viewers' frame rates."""
    page0 = video_stats(driver) if driver is not None else {}
    load0 = ask(*load, "stats", 10.0) if load is not None else {}
    t0, c0 = time.monotonic(), cpu_seconds(pid)
    time.sleep(seconds)  # the measuring window
    t1, c1 = time.monotonic(), cpu_seconds(pid)
    out: dict[str, Any] = {"cpu_pct": 100.0 * (c1 - c0) / (t1 - t0), "rss_mib": rss_mib(pid)}
    if driver is not None:
        page1 = video_stats(driver)
        frames = delta(page1, page0, "framesDecoded")
        span_s = (page1.get("at", 0) - page0.get("at", 0)) / 1e3
        if frames is not None and span_s > 0:
            out["page_fps"] = frames / span_s
        out["page_fps_browser"] = page1.get("framesPerSecond")
        out["page_dropped"] = delta(page1, page0, "framesDropped")
    if load is not None:
        load1 = ask(*load, "stats", 10.0)
        if load1.get("clients"):
            out["load_fps_each"] = (load1["frames"] - load0["frames"]) / (
                load1["t"] - load0["t"]) / load1["clients"]
        out["load_cpu_pct"] = 100.0 * (load1["cpu_s"] - load0["cpu_s"]) / (load1["t"] - load0["t"])
    return out


def wait_watching(inst: Instance, count: int, timeout_s: float, since: int) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if inst.viewers_watching(since) == count:
            return True
        time.sleep(0.1)  # polling the service's output for its line
    return False




def least_squares_slope(xs: list[float], ys: list[float]) -> float | None:
    if len(set(xs)) < 2:
        return None
    return float(np.polyfit(np.asarray(xs, float), np.asarray(ys, float), 1)[0])


Levels = tuple[dict[str, Any], list[tuple[int, dict[str, Any]]], dict[str, Any], bool]


def viewer_levels(inst: Instance, counts: list[int], drawn: bool, page: Any | None,
                  line: Callable[[int, dict[str, Any]], str], details: dict[str, Any]) -> Levels:
    """The web service's CPU and memory with no viewer, with each of `counts` viewers (pairs of the count and its
    window), and once all have left, with whether they did; also written into `details` ("zero", "levels", "after",
    "all_left"). The viewers are the load process's
    aiortc ones (drawing the face themselves with `drawn`), and with `page` (a driven Chromium) the page's own
    connection as the first of them; each level's window starts once its new viewers' first frames have passed, and
    `line(n, window)` is its progress line."""
    pid = inst.web_pid
    others = 0 if page is None else 1
    time.sleep(VIEWER_SETTLE_S)  # the service lets go of its drawing
    zero = measure_window(pid, None, None, VIEWER_WINDOW_S)
    levels = []
    with load_process(inst.url, drawn=drawn) as load:
        ask(*load, "hello", 30.0)
        if page is not None:
            connect_page(page)  # the first viewer; the aiortc ones make up the rest
        for n in counts:
            got = ask(*load, f"set {n - others}", 60.0)
            if got.get("connected") != n - others:
                raise RuntimeError(f"the aiortc viewers did not all connect: {got}")
            time.sleep(VIEWER_SETTLE_S)  # measuring starts after the new viewers' first frames (and keyframes)
            window = measure_window(pid, page, load, VIEWER_WINDOW_S)
            levels.append((n, window))
            progress(line(n, window))
        mark = len(inst.reader.lines)
        ask(*load, "set 0", 30.0)
    if page is not None:
        disconnect_page(page)
    left = wait_watching(inst, 0, 20.0, mark)
    time.sleep(AFTER_LEAVING_S)  # what the service lets go of when the last viewer leaves
    after = measure_window(pid, None, None, VIEWER_WINDOW_S)
    details.update(zero=zero, levels=[{"viewers": n, **m} for n, m in levels], after=after, all_left=left)
    return zero, levels, after, left


def viewers_phase(args: argparse.Namespace, inst: Instance, driver: Any, report: Report,
                  baselines: dict[str, float] | None) -> None:
    details: dict[str, Any] = {}
    report.details["viewers"] = details
    mark = len(inst.reader.lines)
    disconnect_page(driver)
    if not wait_watching(inst, 0, 20.0, mark):
        raise RuntimeError("the page's viewers did not leave")
    progress(f"viewers: 0 (baseline), then {', '.join(map(str, args.viewers))}; "
             f"{VIEWER_WINDOW_S:g} s windows after {VIEWER_SETTLE_S:g} s")
    zero, levels, after, left = viewer_levels(inst, args.viewers, False, driver, lambda n, m: (
        f"  {n} viewer(s): web CPU {m['cpu_pct']:.0f} % of a core, RSS {m['rss_mib']:.0f} MiB, "
        f"page {m.get('page_fps', float('nan')):.1f} fps"), details)

    report.add("viewers: web CPU with 0 viewers", round(zero["cpu_pct"], 1), "-", None, "% core",
               f"RSS {zero['rss_mib']:.0f} MiB")
    for n, m in levels:
        note = f"RSS {m['rss_mib']:.0f} MiB; page {m.get('page_fps', float('nan')):.1f} fps"
        if "load_fps_each" in m:
            note += f"; aiortc viewers {m['load_fps_each']:.1f} fps each (their process {m['load_cpu_pct']:.0f} %)"
        report.add(f"viewers: web CPU with {n}", round(m["cpu_pct"], 1), "-", None, "% core", note)
    xs = [float(n) for n, _ in levels]
    slope = least_squares_slope(xs, [m["cpu_pct"] for _, m in levels])
    if slope is not None:
        report.add("viewers: CPU per additional viewer", round(slope, 1), f"<= {TARGET_CPU_PER_VIEWER:g}",
                   slope <= TARGET_CPU_PER_VIEWER, "% core", f"least squares over {', '.join(map(str, args.viewers))}")
    if levels:
        first = levels[0][1]["cpu_pct"] - zero["cpu_pct"]
        note = "the face drawn for the first viewer (plus its encode)"
        if baselines:
            note += (f"; bench: draw {baselines['draw_ms']:.1f} ms/frame = {baselines['draw_ms'] * FPS / 10:.0f} % "
                     f"at {FPS:g} fps, encode {baselines['encode_ms']:.1f} ms = "
                     f"{baselines['encode_ms'] * FPS / 10:.0f} %")
        report.add(f"viewers: CPU 0 -> {levels[0][0]}", round(first, 1), "-", None, "% core", note)
        n_max, m_max = levels[-1]
        fps = m_max.get("page_fps")
        report.add(f"viewers: page frame rate with {n_max}", "none" if fps is None else round(fps, 1),
                   f">= {TARGET_FPS_MIN:g}", fps is not None and fps >= TARGET_FPS_MIN, "fps",
                   f"getStats framesDecoded; the browser's own figure {m_max.get('page_fps_browser')}")
    rss_slope = least_squares_slope(xs, [m["rss_mib"] for _, m in levels])
    if rss_slope is not None:
        report.add("viewers: RSS per additional viewer", round(rss_slope, 1), "-", None, "MiB")
    back = abs(after["rss_mib"] - zero["rss_mib"]) / zero["rss_mib"]
    report.add("viewers: RSS after all left vs 0 viewers", round(after["rss_mib"] - zero["rss_mib"], 1),
               f"+-{100 * TARGET_RSS_RETURN:g} %", back <= TARGET_RSS_RETURN and left, "MiB",
               f"{after['rss_mib']:.0f} vs {zero['rss_mib']:.0f} MiB ({100 * back:.1f} %); CPU after "
               f"{after['cpu_pct']:.1f} %" + ("" if left else "; the viewers did not all leave"))




# --- the load process: aiortc viewers that receive but do not decode -------------------------------


class CountingNullDecoder:
    """Takes encoded frames and counts them: the server's work per viewer is the same, the load's CPU is
    not spent decoding pictures nobody looks at."""

    counts: dict[str, int] = {"video": 0, "audio": 0}

    def __init__(self, kind: str) -> None:
        self.kind = kind

    def decode(self, encoded_frame: Any) -> list[Any]:
        CountingNullDecoder.counts[self.kind] += 1
        return []


def run_load(url: str, drawn: bool = False) -> int:
    """The load process: aiortc viewers of the agent at 640x480/30 fps, as many as asked on stdin. `drawn`: each
    draws the face itself (as tests/support/web_client.py FaceClient: the "eca-face" data channel, the voice
    only, `draw_here`), and its face frames are counted; else each receives the face as video."""
    import aiohttp
    import aiortc.rtcrtpreceiver
    from aiortc import RTCPeerConnection, RTCSessionDescription

    aiortc.rtcrtpreceiver.get_decoder = (  # type: ignore[attr-defined]
        lambda codec: CountingNullDecoder(codec.mimeType.split("/")[0].lower()))  # type: ignore[assignment, return-value]
    face_frames = [0]

    def on_message(message: object) -> None:
        if isinstance(message, bytes) and len(message) > 2 and message[2] == 1:  # browser_face.py FRAME
            face_frames[0] += 1

    async def connect(session: aiohttp.ClientSession) -> RTCPeerConnection:
        pc = RTCPeerConnection()
        if drawn:
            channel = pc.createDataChannel("eca-face", ordered=False, maxRetransmits=0)
            channel.on("message", on_message)
        kinds = ("audio",) if drawn else ("video", "audio")
        sections = [(pc.addTransceiver(kind, direction="recvonly"), kind) for kind in kinds]
        await pc.setLocalDescription(await pc.createOffer())
        body = {"type": "offer", "sdp": pc.localDescription.sdp, "agents": [AGENT],
                "video": {"width": VIDEO.width, "height": VIDEO.height, "fps": FPS},
                "streams": [{"mid": t.mid, "agent": AGENT, "kind": k} for t, k in sections], "mic_mid": None,
                "draw_here": [AGENT] if drawn else []}
        async with session.post(url + "offer", json=body) as response:
            answer = await response.json()
            if response.status != 200:
                await pc.close()
                raise RuntimeError(f"offer refused ({response.status}): {answer}")
        await pc.setRemoteDescription(RTCSessionDescription(sdp=answer["sdp"], type="answer"))
        return pc

    async def main() -> None:
        loop = asyncio.get_running_loop()
        lines = stdin_lines()
        clients: list[RTCPeerConnection] = []

        async with aiohttp.ClientSession() as session:
            try:
                while (line := await lines.get()) is not None:
                    if line == "hello":
                        say({"hello": True})
                    elif line.startswith("set "):
                        want = int(line.split()[1])
                        while len(clients) > want:
                            await clients.pop().close()
                        while len(clients) < want:
                            clients.append(await connect(session))
                        deadline = loop.time() + CONNECT_TIMEOUT_S
                        while loop.time() < deadline and any(c.connectionState != "connected" for c in clients):
                            await asyncio.sleep(0.05)  # polling the connection states
                        say({"connected": sum(c.connectionState == "connected" for c in clients)})
                    elif line == "stats":
                        frames = face_frames[0] if drawn else CountingNullDecoder.counts["video"]
                        say({"clients": len(clients), "frames": frames, "t": time.monotonic(),
                             "cpu_s": time.process_time()})
            finally:
                for c in clients:
                    await c.close()

    asyncio.run(main())
    return 0
