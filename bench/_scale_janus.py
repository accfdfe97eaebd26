"""eca's cost as viewers of one face grow, watching through Janus against peering with eca (bench/scale.py's part).

Hosts are network namespaces (tests/support/netns.py; as root): `eca up --web` with `[web] sfu` on a "web" host,
Janus (tests/support/janus.py) on an "sfu" host, headless aiortc viewers in processes on a "viewer" host (at most
VIEWERS_PER_PROCESS each). For each count of viewers and each way of watching: eca's CPU (all the instance's
processes, and the web service's alone; utime + stime from /proc over a window, as a share of one core) and memory
(PSS, /proc/<pid>/smaps_rollup), and the frame rate each viewer received. Through Janus the web service publishes
each face once whatever the count (its cost should stay flat); direct, each viewer is a peer connection of eca's.
Then command -> frame: a `set_emotion` sent to eca's `POST /command`, alternating, and the first decoded picture at
a viewer that shows the change (half the way from the old expression's picture to the new one's); through Janus
against direct. Decoded by aiortc, not shown by a browser: no browser's jitter buffer nor display in it.

All the hosts share the machine's cores (two here): the viewers' own decoding competes with eca, so at large counts
the frame rates fall for that reason, and the figures are of this machine, not of hosts.

    python bench/_scale_janus.py [--counts 1,10,50] [--json]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import re
import statistics
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from bench._workers import WorkerProcesses  # noqa: E402
from bench.procs import cpu_seconds, descendants, pss_mib  # noqa: E402

AGENT = "ada"
WIDTH, HEIGHT, FPS = 320, 240, 15.0  # what the mountpoint carries and what direct viewers ask
TOKEN = "bench-scale-token"
VIEWERS_PER_PROCESS = 10
WINDOW_S = 8.0
SETTLE_S = 3.0
COMMANDS = 12
COMMAND_EVERY_S = 1.5
READY_TIMEOUT_S = 180.0


def progress(line: str) -> None:
    print(f"[scale] {line}", file=sys.stderr, flush=True)


# --- the viewers' processes (--worker) -------------------------------------------------------------------------


async def _worker(mode: str, target: str, mountpoint: int, count: int, thumbs: bool) -> None:
    import numpy as np

    from tests.support.janus import JanusViewer
    from tests.support.web_client import Client

    viewers: list[Any] = []
    tracks: list[tuple[Any, Any]] = []
    for i in range(0, count, 5):  # in fives: fifty ICE checks at once starve a two-core machine
        batch = [JanusViewer(target, mountpoint) if mode == "janus"
                 else Client(target, [AGENT], token=TOKEN, video={"width": WIDTH, "height": HEIGHT, "fps": FPS})
                 for _ in range(min(5, count - i))]
        await asyncio.gather(*(v.connect() for v in batch))
        viewers += batch
    deadline = time.monotonic() + 20
    for v in viewers:
        while time.monotonic() < deadline:
            video = v.tracks.get("video") if mode == "janus" else v.tracks.get((AGENT, "video"))
            audio = v.tracks.get("audio") if mode == "janus" else v.tracks.get((AGENT, "audio"))
            if video is not None and audio is not None:
                tracks.append((video, audio))
                break
            await asyncio.sleep(0.05)
    counts = [[0, 0] for _ in tracks]
    pictures: list[tuple[float, list[float]]] = []

    async def pull(i: int, track: Any, kind: int) -> None:
        while True:
            try:
                frame = await track.recv()
            except Exception:  # the connection ended
                return
            counts[i][kind] += 1
            if thumbs and kind == 0 and i == 0:
                grey = frame.to_ndarray(format="gray").astype(np.float32)
                h, w = grey.shape
                thumb = grey[: h - h % 24, : w - w % 32].reshape(24, h // 24, 32, w // 32).mean(axis=(1, 3))
                pictures.append((time.time(), [round(float(x), 1) for x in thumb.ravel()]))

    tasks = [asyncio.ensure_future(pull(i, t, k)) for i, pair in enumerate(tracks) for k, t in enumerate(pair)]
    print(f"ready {len(tracks)}", flush=True)
    marks: dict[str, Any] = {}
    loop = asyncio.get_running_loop()
    while True:
        line = (await loop.run_in_executor(None, sys.stdin.readline)).strip()
        if line == "mark":  # the counts now: the window's start
            marks = {"t": time.time(), "counts": [list(c) for c in counts]}
        if line in ("stop", ""):
            break
    report = {"t": time.time(), "counts": counts, "mark": marks, "pictures": pictures}
    for task in tasks:
        task.cancel()
    await asyncio.gather(*(v.close() if mode == "janus" else v.pc.close() for v in viewers), return_exceptions=True)
    print(json.dumps(report), flush=True)


# --- the instance ---------------------------------------------------------------------------------------------


class Viewers(WorkerProcesses):
    """Viewer processes on the viewer host: `count` viewers in all, watching one way."""

    def __init__(self, host: Any, mode: str, target: str, mountpoint: int, count: int, thumbs: bool = False) -> None:
        argvs = []
        for first in range(0, count, VIEWERS_PER_PROCESS):
            n = min(VIEWERS_PER_PROCESS, count - first)
            argv = [sys.executable, str(Path(__file__).resolve()), "--worker", mode, target, str(mountpoint), str(n)]
            argvs.append([*argv, "--thumbs"] if thumbs else argv)
        super().__init__(host, argvs)


def received_fps(reports: list[dict[str, Any]]) -> list[float]:
    rates = []
    for r in reports:
        if not r.get("mark"):
            continue
        span = r["t"] - r["mark"]["t"]
        rates += [(c[0] - m[0]) / span for c, m in zip(r["counts"], r["mark"]["counts"], strict=True)]
    return rates


def measure(net: Any, mode: str, target: str, mountpoint: int, count: int, up_pid: int, web_pid: int) -> dict[str, Any]:
    viewers = Viewers(net["viewer"], mode, target, mountpoint, count)
    try:
        ready = viewers.wait_ready()
        time.sleep(SETTLE_S)
        pids = descendants(up_pid)
        before = {p: cpu_seconds(p) for p in pids}
        began = time.monotonic()
        viewers.say("mark")
        time.sleep(WINDOW_S)
        elapsed = time.monotonic() - began
        cpu_all = sum(cpu_seconds(p) - before[p] for p in pids if Path(f"/proc/{p}").exists()) / elapsed
        cpu_web = (cpu_seconds(web_pid) - before[web_pid]) / elapsed
        pss_all, pss_web = sum(pss_mib(p) for p in pids), pss_mib(web_pid)
        rates = received_fps(viewers.finish())
    finally:
        viewers.kill()
    return {"viewers": count, "connected": ready, "cpu_all": round(100 * cpu_all, 1),
            "cpu_web": round(100 * cpu_web, 1), "pss_all_mib": round(pss_all, 1), "pss_web_mib": round(pss_web, 1),
            "fps_median": round(statistics.median(rates), 1) if rates else None,
            "fps_min": round(min(rates), 1) if rates else None}


def post_command(base: str, name: str) -> None:
    import urllib.request

    body = json.dumps({"token": TOKEN, "command": {"type": "set_emotion", "agent": AGENT, "name": name,
                                                   "intensity": 1.0, "transition_s": 0.0}}).encode()
    request = urllib.request.Request(base + "command", data=body, headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=5) as response:
        response.read()


def command_latency(net: Any, mode: str, target: str, mountpoint: int, base: str) -> dict[str, Any]:
    """`set_emotion` -> the first decoded picture showing it, for COMMANDS commands (alternating)."""
    import numpy as np

    viewers = Viewers(net["viewer"], mode, target, mountpoint, 1, thumbs=True)
    sent: list[float] = []
    try:
        viewers.wait_ready()
        post_command(base, "natural")
        time.sleep(SETTLE_S)
        for k in range(COMMANDS):
            sent.append(time.time())
            post_command(base, "surprised" if k % 2 == 0 else "natural")
            time.sleep(COMMAND_EVERY_S)
        report = viewers.finish()[0]
    finally:
        viewers.kill()
    pictures = [(t, np.asarray(v)) for t, v in report["pictures"]]
    latencies = []
    for t_cmd in sent:
        old = [v for t, v in pictures if t_cmd - 0.4 <= t < t_cmd]
        new = [v for t, v in pictures if t_cmd + 1.0 <= t < t_cmd + COMMAND_EVERY_S - 0.05]
        if not old or not new:
            continue
        a, b = np.mean(old, axis=0), np.mean(new, axis=0)
        full = float(np.abs(b - a).mean())
        if full < 0.5:
            continue  # no visible change: not counted
        for t, v in pictures:
            if t >= t_cmd and float(np.abs(v - a).mean()) > 0.5 * full:
                latencies.append(1000 * (t - t_cmd))
                break
    latencies.sort()
    pick = lambda q: round(latencies[min(len(latencies) - 1, int(q * len(latencies)))], 1) if latencies else None  # noqa: E731
    return {"commands": len(sent), "measured": len(latencies), "p50_ms": pick(0.5), "p95_ms": pick(0.95)}


def viewers_through_janus(counts: tuple[int, ...] = (1, 10, 50)) -> dict[str, Any]:
    """eca's CPU and memory with 1..N viewers of one face through Janus and direct, and command -> frame p95."""
    from eca.services.tools.child_processes import eca_command
    from tests.support.bus import private_bus_config, running
    from tests.support.janus import janus_available, janus_server
    from tests.support.netns import hosts, netns_available

    why = netns_available() or janus_available()
    if why is not None:
        return {"skipped": why}
    out: dict[str, Any] = {"counts": list(counts), "size": f"{WIDTH}x{HEIGHT}", "fps": FPS, "janus": [],
                           "direct": [], "cores": os.cpu_count()}
    with hosts("web", "sfu", "viewer") as net, janus_server(net["sfu"]) as janus:
        web_host = net["web"]
        extra = (f'[web]\nhost = "{web_host.address}"\nport = 8080\ntoken = "{TOKEN}"\nwidth = {WIDTH}\n'
                 f'height = {HEIGHT}\nfps = {FPS}\nmax_viewers = {max(64, max(counts) + 4)}\nsilent_timeout_s = 30\n'
                 f'sfu = "{janus.url}"\n[heartbeat]\ninterval_s = 0.25\ntimeout_s = 5.0\n')
        with private_bus_config(services=["dialogue", "gaze", "audio"], agents=[AGENT], extra=extra) as config:
            argv = web_host.argv(eca_command("up", "--config", str(config.config_path), "--instance", config.instance,
                                             "--quiet", "--silent-audio", "--web"))
            progress(f"eca up --web on {web_host.address}, Janus at {janus.url}")
            with running(argv, stop_timeout_s=15.0) as (proc, reader):
                reader.wait_for("[up] ready in", 120.0)
                ready = reader.lines[reader.wait_for("[web] INFO ready (pid", 10.0)]
                published = reader.lines[reader.wait_for("[web] INFO publishing", 10.0)]
                pid_match = re.search(r"ready \(pid (\d+)\)", ready)
                mp_match = re.search(rf"{AGENT}: (\d+)", published)
                assert pid_match is not None and mp_match is not None
                web_pid, mountpoint = int(pid_match.group(1)), int(mp_match.group(1))
                base = f"http://{web_host.address}:8080/"
                for count in counts:
                    for mode, target in (("janus", janus.url), ("direct", base)):
                        progress(f"{count} viewer(s), {mode}")
                        try:
                            out[mode].append(measure(net, mode, target, mountpoint, count, proc.pid, web_pid))
                        except Exception as exc:  # a count this machine cannot carry: said, and the rest goes on
                            out[mode].append({"viewers": count, "error": f"{type(exc).__name__}: {exc}"})
                        progress(json.dumps(out[mode][-1]))
                for mode, target in (("janus", janus.url), ("direct", base)):
                    progress(f"command -> frame, {mode}")
                    try:
                        out[f"latency_{mode}"] = command_latency(net, mode, target, mountpoint, base)
                    except Exception as exc:
                        out[f"latency_{mode}"] = {"error": f"{type(exc).__name__}: {exc}"}
                    progress(json.dumps(out[f"latency_{mode}"]))
    first = next((r for r in out["janus"] if r.get("viewers") == min(counts) and "cpu_all" in r), None)
    last = next((r for r in out["janus"] if r.get("viewers") == max(counts) and "cpu_all" in r), None)
    if first and last:
        out["janus_cpu_ratio_at_max"] = round(last["cpu_all"] / first["cpu_all"], 3) if first["cpu_all"] else None
        out["janus_flat_within_10pct"] = bool(out["janus_cpu_ratio_at_max"] is not None
                                              and out["janus_cpu_ratio_at_max"] <= 1.10)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--counts", default="1,10,50", help="viewer counts, comma-separated (default 1,10,50)")
    parser.add_argument("--json", action="store_true", help="print the result as one JSON object")
    parser.add_argument("--worker", nargs=4, metavar=("MODE", "TARGET", "MOUNTPOINT", "COUNT"), help=argparse.SUPPRESS)
    parser.add_argument("--thumbs", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        mode, target, mountpoint, count = args.worker
        asyncio.run(_worker(mode, target, int(mountpoint), int(count), args.thumbs))
        return 0
    result = viewers_through_janus(tuple(int(c) for c in args.counts.split(",") if c))
    if args.json:
        print(json.dumps(result))
    else:
        if "skipped" in result:
            print(f"skipped: {result['skipped']}")
            return 0
        print(f"eca's cost per count of viewers of one face ({result['size']}, {result['fps']:g} fps; "
              f"{result['cores']} cores shared by every host)")
        print("  viewers  way     eca CPU %  web CPU %  eca PSS MiB  web PSS MiB  fps median/min")
        for mode in ("janus", "direct"):
            for r in result[mode]:
                if "error" in r:
                    print(f"  {r['viewers']:>7}  {mode:<6}  {r['error']}")
                    continue
                print(f"  {r['viewers']:>7}  {mode:<6}  {r['cpu_all']:>9}  {r['cpu_web']:>9}  {r['pss_all_mib']:>11}  "
                      f"{r['pss_web_mib']:>11}  {r['fps_median']}/{r['fps_min']}")
        for mode in ("janus", "direct"):
            print(f"  command -> frame decoded, {mode}: {result.get(f'latency_{mode}')}")
        print(f"  through Janus, eca's CPU at {max(result['counts'])} / at {min(result['counts'])}: "
              f"{result.get('janus_cpu_ratio_at_max')} (target <= 1.10: "
              f"{'met' if result.get('janus_flat_within_10pct') else 'MISSED'})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
