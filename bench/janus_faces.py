"""Benchmark: faces the pages draw, carried by Janus. What a conversation's media costs eca and Janus when each
agent's voice and face frames go once into a Janus Streaming mountpoint (`[web] sfu`, `draw = "browser"`,
web/sfu.py) and Janus, in C, does each viewer's WebRTC (DTLS, SRTP, SCTP) instead of eca's aiortc.

Hosts are network namespaces (tests/support/netns.py; as root): `eca up --web --silent-audio` with K agents on a
"web" host, Janus on an "sfu" host, headless aiortc viewers on a "viewer" host (tests/support/janus.py's
JanusViewer, in processes of VIEWERS_PER_PROCESS), one viewer per agent's mountpoint: K conversations' worth of
media. For each K: the CPU (utime + stime from /proc over a window, as a share of one core) of eca (every process of
the instance), of its web service alone, of Janus and of the viewers' processes, eca's memory (PSS), and per viewer
the face frames and voice packets a second it received. The baseline is measured in the same run: K = the first
count (1 by default); the figures per added conversation are the lines through the counts.

The viewers decode the voice (aiortc's receiver does) but draw nothing. By default the agents do not speak. Into a
mountpoint without video the voice pauses in silence (web/sfu.py), so these are a listening agent's figures: no voice
packet goes in or out (`voice pps` 0). With `--speak-s S` each agent speaks S seconds of a synthetic voice (a `Say`
on the bus, bench/conversations.py's voice) every `--cycle-s` seconds, the agents' turns spread evenly over the
cycle, as in a conversation where the agent speaks part of the time: its 50 voice packets a second go in and out
while it speaks. All the hosts share the machine's cores (two here): the figures are of this machine, not of hosts.

    python bench/janus_faces.py [--counts 1,8,16] [--window-s 15] [--speak-s 0] [--cycle-s 8] [--json]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import re
import statistics
import sys
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from bench._workers import WorkerProcesses  # noqa: E402
from bench.procs import cpu_seconds, descendants, eca_label, pss_mib  # noqa: E402

FPS = 30.0  # the face frames' rate (the page's default)
VIEWERS_PER_PROCESS = 8
SETTLE_S = 5.0
READY_TIMEOUT_S = 180.0
FRAME, VOICE_CLOCK = 1, 2  # the data section's message kinds (web/browser_face.py)


def progress(line: str) -> None:
    print(f"[janus-faces] {line}", file=sys.stderr, flush=True)


# --- the viewers' processes (--worker) -------------------------------------------------------------------------


async def _worker(url: str, mountpoints: list[int]) -> None:
    from tests.support.janus import JanusViewer

    viewers: list[JanusViewer] = []
    for i in range(0, len(mountpoints), 4):  # a few at a time: many ICE checks at once starve a two-core machine
        batch = [JanusViewer(url, m) for m in mountpoints[i:i + 4]]
        await asyncio.gather(*(v.connect() for v in batch))
        viewers += batch
    voice = [0] * len(viewers)

    async def pull(i: int, viewer: JanusViewer) -> None:
        while "audio" not in viewer.tracks:
            await asyncio.sleep(0.05)
        track = viewer.tracks["audio"]
        while True:
            try:
                await track.recv()
            except Exception:  # the connection ended
                return
            voice[i] += 1

    tasks = [asyncio.ensure_future(pull(i, v)) for i, v in enumerate(viewers)]
    print(f"ready {len(viewers)}", flush=True)
    loop = asyncio.get_running_loop()
    marks: dict[str, Any] = {}

    def counts() -> list[list[int]]:
        return [[voice[i], sum(1 for _, m in v.messages if isinstance(m, bytes) and len(m) > 2 and m[2] == FRAME)]
                for i, v in enumerate(viewers)]

    while True:
        line = (await loop.run_in_executor(None, sys.stdin.readline)).strip()
        if line == "mark":  # the window's start
            marks = {"t": time.time(), "counts": counts()}
        if line in ("stop", ""):
            break
    report = {"t": time.time(), "counts": counts(), "mark": marks}
    for task in tasks:
        task.cancel()
    await asyncio.gather(*(v.close() for v in viewers), return_exceptions=True)
    print(json.dumps(report), flush=True)


class Viewers(WorkerProcesses):
    """Viewer processes on the viewer host, one viewer per mountpoint."""

    def __init__(self, host: Any, url: str, mountpoints: list[int]) -> None:
        super().__init__(host, [[sys.executable, str(Path(__file__).resolve()), "--worker", url,
                                 ",".join(map(str, mountpoints[first:first + VIEWERS_PER_PROCESS]))]
                                for first in range(0, len(mountpoints), VIEWERS_PER_PROCESS)])


def rates(reports: list[dict[str, Any]]) -> tuple[list[float], list[float]]:
    """Per viewer over the window: voice packets and face frames a second."""
    voice, frames = [], []
    for r in reports:
        if not r.get("mark"):
            continue
        span = r["t"] - r["mark"]["t"]
        for now, then in zip(r["counts"], r["mark"]["counts"], strict=True):
            voice.append((now[0] - then[0]) / span)
            frames.append((now[1] - then[1]) / span)
    return voice, frames


def cpu_of(pids: list[int]) -> dict[int, float]:
    out = {}
    for pid in pids:
        try:
            out[pid] = cpu_seconds(pid)
        except OSError:
            pass  # gone
    return out


def one_count(net: Any, janus: Any, count: int, window_s: float, speak_s: float = 0.0,
              cycle_s: float = 8.0) -> dict[str, Any]:
    from bench.conversations import Driver, agent_voice
    from eca.services.tools.child_processes import eca_command
    from tests.support.bus import private_bus_config, running

    web_host = net["web"]
    agents = [f"a{i}" for i in range(count)]
    extra = (f'[web]\nhost = "{web_host.address}"\nport = 8080\ntoken = "bench-janus-faces"\nfps = {FPS}\n'
             f'sfu = "{janus.url}"\ndraw = "browser"\n[heartbeat]\ninterval_s = 0.25\n'
             'timeout_s = 5.0\n')
    with private_bus_config(services=["dialogue", "gaze", "audio"], agents=agents, extra=extra) as config:
        argv = web_host.argv(eca_command("up", "--config", str(config.config_path), "--instance", config.instance,
                                         "--quiet", "--silent-audio", "--web", "--face", "head"))
        with running(argv, stop_timeout_s=20.0) as (proc, reader):
            reader.wait_for("[up] ready in", READY_TIMEOUT_S)
            ready = reader.lines[reader.wait_for("[web] INFO ready (pid", 10.0)]
            published = reader.lines[reader.wait_for("[web] INFO publishing", 10.0)]
            pid_match = re.search(r"ready \(pid (\d+)\)", ready)
            assert pid_match is not None
            web_pid = int(pid_match.group(1))
            mountpoints = [int(m.group(1)) for a in agents if (m := re.search(rf"\b{a}: (\d+)", published))]
            assert len(mountpoints) == count, published
            assert janus.proc is not None
            janus_pids = [janus.proc.pid, *descendants(janus.proc.pid)]
            viewers = Viewers(net["viewer"], janus.url, mountpoints)
            driver: Driver | None = None
            try:
                with ExitStack() as speaking:
                    connected = viewers.wait_ready()
                    if speak_s > 0:  # each agent's turns, spread over the cycle
                        driver = speaking.enter_context(Driver(config, agent_voice(speak_s, random.Random(0)),
                                                               time.monotonic(), cycle_s, 0.0))
                        for i, agent in enumerate(agents):
                            driver.add(agent, cycle_s * i / count)
                    time.sleep(SETTLE_S)
                    eca_pids = [proc.pid, *descendants(proc.pid)]
                    watched = eca_pids + janus_pids + viewers.pids
                    before = cpu_of(watched)
                    began = time.monotonic()
                    viewers.say("mark")
                    time.sleep(window_s)
                    after = cpu_of(watched)
                    elapsed = time.monotonic() - began

                    def share(pids: list[int]) -> float:
                        return round(100 * sum(after[p] - before[p] for p in pids if p in after and p in before)
                                     / elapsed, 1)

                    cpu = {"eca": share(eca_pids), "web": share([web_pid]), "janus": share(janus_pids),
                           "viewers": share(viewers.pids)}
                    labels = {p: eca_label(p, proc.pid) for p in eca_pids}
                    services = {name: share([p for p in eca_pids if labels[p] == name])
                                for name in sorted(set(labels.values()))}
                    pss = round(sum(pss_mib(p) for p in eca_pids if Path(f"/proc/{p}").exists()), 1)
                    voice, frames = rates(viewers.finish())
                    said = len(driver.log.says) if driver is not None else 0
                    failed = len([e for e in driver.log.speech if e[2] == "speech_failed"]) if driver is not None else 0
            finally:
                viewers.kill()
    return {"conversations": count, "connected": connected, "cpu": cpu, "services": services, "eca_pss_mib": pss,
            "face_fps_median": round(statistics.median(frames), 1) if frames else None,
            "face_fps_min": round(min(frames), 1) if frames else None,
            "voice_pps_min": round(min(voice), 1) if voice else None,
            "voice_pps_median": round(statistics.median(voice), 1) if voice else None,
            "turns_said": said, "speech_failed": failed}


def slope(rows: list[dict[str, Any]], key: str) -> float | None:
    """Least-squares CPU per added conversation (% of a core) through the counts measured."""
    points = [(r["conversations"], r["cpu"][key]) for r in rows if "cpu" in r]
    if len(points) < 2:
        return None
    xs, ys = zip(*points, strict=True)
    mx, my = statistics.fmean(xs), statistics.fmean(ys)
    den = sum((x - mx) ** 2 for x in xs)
    return round(sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True)) / den, 2) if den else None


def run(counts: tuple[int, ...], window_s: float, speak_s: float = 0.0, cycle_s: float = 8.0) -> dict[str, Any]:
    from tests.support.janus import janus_available, janus_server
    from tests.support.netns import hosts, netns_available

    why = netns_available() or janus_available()
    if why is not None:
        return {"skipped": why}
    out: dict[str, Any] = {"counts": list(counts), "fps": FPS, "window_s": window_s, "speak_s": speak_s,
                           "cycle_s": cycle_s, "cores": os.cpu_count(),
                           "load_before": os.getloadavg(), "rows": []}
    with hosts("web", "sfu", "viewer") as net, janus_server(net["sfu"]) as janus:
        for count in counts:
            progress(f"{count} conversation(s) through Janus")
            try:
                out["rows"].append(one_count(net, janus, count, window_s, speak_s, cycle_s))
            except Exception as exc:  # a count this machine cannot carry: said, and the rest goes on
                out["rows"].append({"conversations": count, "error": f"{type(exc).__name__}: {exc}"})
            progress(json.dumps(out["rows"][-1]))
    out["per_conversation"] = {key: slope(out["rows"], key) for key in ("eca", "web", "janus", "viewers")}
    names = sorted({n for r in out["rows"] for n in r.get("services", {})})
    out["per_conversation_services"] = {n: slope([{"conversations": r["conversations"], "cpu": {n: r["services"][n]}}
                                                  for r in out["rows"] if n in r.get("services", {})], n)
                                        for n in names}
    out["load_after"] = os.getloadavg()
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--counts", default="1,8,16", help="conversations, comma-separated (the first: the baseline)")
    parser.add_argument("--window-s", type=float, default=15.0, help="each count's measuring window (s)")
    parser.add_argument("--speak-s", type=float, default=0.0, help="each agent speaks this long a cycle (0: silent)")
    parser.add_argument("--cycle-s", type=float, default=8.0, help="the agents' speaking cycle (s)")
    parser.add_argument("--json", action="store_true", help="print the result as one JSON object last")
    parser.add_argument("--worker", nargs=2, metavar=("URL", "MOUNTPOINTS"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        url, mountpoints = args.worker
        asyncio.run(_worker(url, [int(m) for m in mountpoints.split(",")]))
        return 0
    if not 0.0 <= args.speak_s < args.cycle_s:
        parser.error("--speak-s must be at least 0 and less than --cycle-s")
    result = run(tuple(int(c) for c in args.counts.split(",") if c), args.window_s, args.speak_s, args.cycle_s)
    if "skipped" in result:
        print(f"skipped: {result['skipped']}")
    else:
        speaking = (f"each agent speaking {result['speak_s']:g} s of every {result['cycle_s']:g}"
                    if result["speak_s"] else "the agents listening")
        print(f"faces drawn by the pages, through Janus ({speaking}; {result['fps']:g} face frames a second; "
              f"{result['cores']} "
              f"cores shared by every host; load {result['load_before'][0]:.2f} before, "
              f"{result['load_after'][0]:.2f} after)")
        print("  conversations  eca CPU %  web CPU %  Janus CPU %  viewers CPU %  eca PSS MiB  face fps median/min"
              "  voice pps median/min  turns said (failed)")
        for r in result["rows"]:
            if "error" in r:
                print(f"  {r['conversations']:>13}  {r['error']}")
                continue
            c = r["cpu"]
            print(f"  {r['conversations']:>13}  {c['eca']:>9}  {c['web']:>9}  {c['janus']:>11}  {c['viewers']:>13}  "
                  f"{r['eca_pss_mib']:>11}  {r['face_fps_median']}/{r['face_fps_min']:<16}  "
                  f"{r['voice_pps_median']}/{r['voice_pps_min']:<16}  {r['turns_said']} ({r['speech_failed']})")
            print("                 eca's processes: " + ", ".join(f"{k} {v}" for k, v in r["services"].items()))
        per = result["per_conversation"]
        both = round(per["eca"] + per["janus"], 2) if per["eca"] is not None and per["janus"] is not None else None
        print(f"  per added conversation (% of a core): eca {per['eca']}, of it web {per['web']}; Janus "
              f"{per['janus']}; eca + Janus {both} (target <= 2); viewers {per['viewers']}")
        each = result["per_conversation_services"]
        print("    of eca, per process: " + ", ".join(f"{k} {v}" for k, v in each.items()))
    if args.json:
        print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
