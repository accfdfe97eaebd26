"""Conversations across eca hosts behind HAProxy against one host: part of bench/scale.py, runnable alone.

`conversations_behind_haproxy()` starts, for each topology, eca hosts (`eca up --web --per-visitor --face head
--web-draw browser --silent-audio`, each on a private bus, tests/support/haproxy.py `eca_hosts`) behind a real
HAProxy with the shipped eca/configs/haproxy.cfg (tests/support/haproxy.py `balancer`), and brings synthetic
visitors to HAProxy's address in steps. The visitors live in a helper process (this file run with `--client`;
bench/_conversation_clients.py's visitor: the page's `POST /conversation`, an offer with a microphone, the voice and
the "eca-face" data channel, every RTP packet and face frame noted where it arrives, nothing decoded), each visitor
with a cookie jar of its own, as each browser has: the SERVERID cookie keeps it on its host.

Per step, after `settle_s`, a window of `hold_s`: a conversation holds when its connection stays up, its face
frames arrive at the asked rate within 10 % and its voice packets (the agents are silent: Opus silence, 50 a
second) arrive without a gap over `gap_ms`. The figures per topology: the largest N where every conversation held,
the servers' CPU (every process of every host, /proc) as a share of one core per added conversation (a line fitted
over the steps), and how HAProxy spread the visitors (each host's /health `viewers`).

All hosts share this machine's cores: two hosts on one machine carry no more than one does; what the comparison
shows is that routing through HAProxy and a second host's own processes cost little per conversation, and that the
visitors are spread evenly. On separate machines the capacity adds up per host.

    python bench/_scale_hosts.py [--steps 1,2,4] [--hold-s 6] [--settle-s 3] [--fps 15] [--per-host-max 8]
                                 [--gap-ms 100] [--json]

About 2 minutes on 2 cores with the defaults.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

FPS_TOLERANCE = 0.10
SILENCE_BYTES = 8  # bench/conversations.py: an Opus payload this small is digital silence
SPLIT_PACKETS = 15


def _progress(line: str) -> None:
    print(f"[scale-hosts] {line}", file=sys.stderr, flush=True)


def _server_ticks(pids: Sequence[int]) -> int:
    """CPU ticks (user + system) of every process in the trees of `pids` (the hosts' `eca up` supervisors)."""
    from bench.procs import descendants, proc_table

    table = proc_table()
    return sum(table[p].own_ticks for root in pids for p in descendants(root, table))


def _health(url: str) -> dict[str, Any]:
    import urllib.request

    try:
        with urllib.request.urlopen(url + "health", timeout=5) as response:
            body: dict[str, Any] = json.loads(response.read())
            return body
    except Exception as exc:  # a 503 (full) carries the same JSON
        read = getattr(exc, "read", None)
        return json.loads(read()) if callable(read) else {"error": str(exc)}


class _Helper:
    """The visitors' process: JSON lines in, one JSON line out per command."""

    def __init__(self, url: str, wav: Path, fps: float) -> None:
        argv = [sys.executable, str(Path(__file__).resolve()), "--client", "--url", url, "--mic", str(wav),
                "--fps", str(fps), "--epoch-ns", str(time.monotonic_ns())]
        self.proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                     start_new_session=True)

    def ask(self, command: dict[str, Any]) -> dict[str, Any]:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps(command) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError("the visitors' helper process ended")
        answer: dict[str, Any] = json.loads(line)
        return answer

    def close(self) -> None:
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        try:
            self.proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            import os
            import signal

            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(timeout=5)


def _held(row: dict[str, Any], fps: float, gap_ms: float) -> tuple[bool, str]:
    """Whether one visitor's conversation held through the window, and why not."""
    if row["state"] != "connected" or row["ended_at"] is not None:
        return False, f"connection {row['state']}"
    face, voice = row.get("face", {}), row["voice"]
    if face.get("fps", 0.0) < fps * (1 - FPS_TOLERANCE):
        return False, f"face frames at {face.get('fps', 0.0)} fps"
    if voice["packets"] < 2 or voice["max_gap_client_on_time_ms"] > gap_ms:
        return False, f"voice gap {voice['max_gap_client_on_time_ms']} ms ({voice['packets']} packets)"
    return True, ""


def _fit_slope(points: list[tuple[float, float]]) -> float | None:
    if len({x for x, _ in points}) < 2:
        return None
    import numpy as np

    xs, ys = np.array([p[0] for p in points]), np.array([p[1] for p in points])
    return float(np.polyfit(xs, ys, 1)[0])


def _topology(hosts: int, steps: Sequence[int], wav: Path, hold_s: float, settle_s: float, fps: float,
              per_host_max: int, gap_ms: float, progress: Callable[[str], None]) -> dict[str, Any]:
    import os

    from tests.support.haproxy import balancer, eca_hosts

    tick = os.sysconf("SC_CLK_TCK")
    out: dict[str, Any] = {"hosts": hosts, "steps": []}
    t_start = time.monotonic()
    with eca_hosts([per_host_max] * hosts, max_viewers=max(16, per_host_max)) as started:
        out["start_s"] = round(time.monotonic() - t_start, 1)
        names = [f"h{i + 1}" for i in range(hosts)]
        with balancer(list(zip(names, [h.address for h in started], strict=True)), check_inter_ms=500) as lb:
            helper = _Helper(lb.url, wav, fps)
            try:
                have, failed_in_a_row = 0, 0
                for n in [0, *steps]:
                    if n > have:
                        added = helper.ask({"op": "add", "count": n - have})
                        have += len(added["added"])
                        if added["failed"]:
                            progress(f"{hosts} host(s), N={n}: {len(added['failed'])} refused: {added['failed'][:2]}")
                    time.sleep(settle_s)
                    ticks0, t0 = _server_ticks([h.process.pid for h in started]), time.monotonic()
                    time.sleep(hold_s)
                    ticks1, t1 = _server_ticks([h.process.pid for h in started]), time.monotonic()
                    window = helper.ask({"op": "window", "t0": t0, "t1": t1, "gap_ms": gap_ms})  # one clock
                    judged = [_held(row, fps, gap_ms) for row in window["visitors"]]
                    held = sum(ok for ok, _ in judged)
                    cpu = 100.0 * (ticks1 - ticks0) / tick / (t1 - t0)
                    spread = {name: _health(h.url).get("viewers") for name, h in zip(names, started, strict=True)}
                    step = {"n": n, "connected": have, "held": held, "server_cpu_pct": round(cpu, 1),
                            "spread": spread, "why_not": sorted({why for ok, why in judged if not ok})[:3],
                            "client_loop_lag": window.get("loop_lag", {})}
                    out["steps"].append(step)
                    progress(f"{hosts} host(s), N={n}: {held}/{have} held, server CPU {cpu:.0f} % of a core, "
                             f"visitors per host {spread}")
                    failed_in_a_row = failed_in_a_row + 1 if n and held < n else 0
                    if failed_in_a_row >= 2:
                        break  # past what this machine carries (one failed step may be a loaded moment)
                helper.ask({"op": "close"})
            finally:
                helper.close()
    whole = [s["n"] for s in out["steps"] if s["held"] == s["n"] == s["connected"]]
    out["largest_n_held"] = max(whole, default=0)
    slope = _fit_slope([(s["n"], s["server_cpu_pct"]) for s in out["steps"]])
    out["cpu_per_conversation_pct"] = None if slope is None else round(slope, 1)
    return out


def conversations_behind_haproxy(steps: Sequence[int] = (1, 2, 4), hold_s: float = 6.0, settle_s: float = 3.0,
                                 fps: float = 15.0, per_host_max: int = 8, gap_ms: float = 100.0,
                                 progress: Callable[[str], None] = _progress) -> dict[str, Any]:
    """Conversations served by two eca hosts behind HAProxy against one host behind it (the same visitors, the same
    steps): per topology the largest N whose conversations all held, the servers' CPU per conversation, and how the
    visitors were spread. A dict for bench/scale.py (`"skipped"` says why when HAProxy or the head is missing)."""
    from eca.services.processes.avatar.loader import DEFAULT_HEAD
    from tests.support.haproxy import haproxy_available

    reason = haproxy_available() or (None if DEFAULT_HEAD.exists() else "the default head is not baked")
    if reason is not None:
        return {"skipped": reason}
    if not steps or any(n < 1 for n in steps) or list(steps) != sorted(set(steps)):
        raise ValueError(f"steps must be increasing whole numbers from 1, got {list(steps)}")
    if max(steps) > per_host_max:
        raise ValueError(f"the largest step ({max(steps)}) must fit one host (per_host_max {per_host_max})")
    from bench.conversations import uptime, user_sentence

    with tempfile.TemporaryDirectory(prefix="eca-scale-") as folder:
        wav, _ = user_sentence(Path(folder))
        load_before = uptime()
        one = _topology(1, steps, wav, hold_s, settle_s, fps, per_host_max, gap_ms, progress)
        two = _topology(2, steps, wav, hold_s, settle_s, fps, per_host_max, gap_ms, progress)
    result: dict[str, Any] = {
        "one_host": one, "two_hosts": two,
        "settings": {"steps": list(steps), "hold_s": hold_s, "settle_s": settle_s, "fps": fps,
                     "per_host_max": per_host_max, "gap_ms": gap_ms},
        "load_before": load_before, "load_after": uptime(),
        "note": "all hosts share this machine's cores: the comparison is routing and per-conversation cost, not "
                "capacity (which adds up per machine)",
    }
    last = two["steps"][-1]["spread"] if two["steps"] else {}
    counts = [v for v in last.values() if isinstance(v, int)]
    result["two_hosts_spread_even"] = bool(counts) and max(counts) - min(counts) <= 1
    return result


# --- the visitors' helper process ---------------------------------------------------------------------------------


async def _serve_visitors(args: argparse.Namespace) -> None:
    import aiohttp

    from bench import _conversation_clients as clients

    speech, silence = clients.encode_speech(args.mic)
    visitors: list[tuple[Any, aiohttp.ClientSession]] = []
    lag = clients.LoopLag()
    lag_task = asyncio.ensure_future(lag.run())
    loop = asyncio.get_running_loop()
    index = 0

    def say(obj: dict[str, Any]) -> None:
        print(json.dumps(obj), flush=True)

    try:
        while line := await loop.run_in_executor(None, sys.stdin.readline):
            command = json.loads(line)
            if command["op"] == "add":
                added, failed = [], []
                for _ in range(command["count"]):  # one at a time: each is routed on what HAProxy knows then
                    # a cookie jar per visitor, as each browser has; unsafe: keep a cookie of an IP address host
                    session = aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True),
                                                    timeout=aiohttp.ClientTimeout(total=60))
                    index += 1
                    try:
                        visitor, why = await clients.arrive(session, args, index, 0.37 * index % args.cycle_s, speech,
                                                            silence)
                    except Exception as exc:  # a visitor that fails is reported; the others go on
                        visitor, why = None, {"index": index, "error": f"{type(exc).__name__}: {exc}"[:300]}
                    if visitor is None:
                        failed.append(why)
                        await session.close()
                    else:
                        host = next((c.value for c in session.cookie_jar if c.key == "SERVERID"), "")
                        visitors.append((visitor, session))
                        added.append({"index": index, "agent": visitor.agent, "host": host,
                                      "connect_s": round(visitor.connect_s, 2)})
                say({"op": "add", "added": added, "failed": failed})
            elif command["op"] == "window":
                t0, t1 = command["t0"], command["t1"]  # CLOCK_MONOTONIC: the same in both processes
                lags = lag.rows(t0 - 1.0, t1 + 1.0)
                rows = []
                for visitor, _ in visitors:
                    rows.append({"index": visitor.index, "state": visitor.pc.connectionState,
                                 "ended_at": visitor.ended_at,
                                 "voice": clients.voice_stats(visitor.voice, t0, t1, command["gap_ms"] / 1e3,
                                                              SILENCE_BYTES, SPLIT_PACKETS, lags),
                                 "face": clients.face_stats(visitor, t0, t1)})
                    clients.trim(visitor, t0)
                say({"op": "window", "visitors": rows, "loop_lag": lag.window(t0, t1)})
            elif command["op"] == "close":
                for visitor, session in visitors:
                    await visitor.pc.close()
                    await session.close()
                say({"op": "close", "closed": len(visitors)})
                visitors.clear()
    finally:
        lag_task.cancel()
        for visitor, session in visitors:
            await visitor.pc.close()
            await session.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--steps", default="1,2,4", help="visitors at each step, increasing (default 1,2,4)")
    parser.add_argument("--hold-s", type=float, default=6.0)
    parser.add_argument("--settle-s", type=float, default=3.0)
    parser.add_argument("--fps", type=float, default=15.0, help="the face frames' rate each visitor asks")
    parser.add_argument("--per-host-max", type=int, default=8, help="[conversations] max of each host")
    parser.add_argument("--gap-ms", type=float, default=100.0, help="the longest voice gap that still holds")
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout (progress on stderr)")
    # the visitors' helper process (started by the bench itself)
    parser.add_argument("--client", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--url", help=argparse.SUPPRESS)
    parser.add_argument("--mic", help=argparse.SUPPRESS)
    parser.add_argument("--epoch-ns", type=int, default=0, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.client:
        # what bench/_conversation_clients.py's `arrive` reads of its arguments
        args.draw, args.width, args.height, args.cycle_s, args.user_at_s = "browser", 160, 120, 8.0, 0.0
        asyncio.run(_serve_visitors(args))
        return 0
    try:
        steps = [int(s) for s in args.steps.split(",") if s.strip()]
    except ValueError:
        parser.error(f"--steps must be whole numbers separated by commas, got {args.steps!r}")
    result = conversations_behind_haproxy(steps, args.hold_s, args.settle_s, args.fps, args.per_host_max, args.gap_ms)
    if args.json:
        print(json.dumps(result))
    else:
        for name in ("one_host", "two_hosts"):
            part = result.get(name)
            if part is None:
                print(result)
                break
            print(f"{name}: largest N held {part['largest_n_held']}, server CPU per conversation "
                  f"{part['cpu_per_conversation_pct']} % of a core, started in {part['start_s']} s")
            for step in part["steps"]:
                print(f"  N={step['n']}: {step['held']}/{step['connected']} held, CPU {step['server_cpu_pct']} %, "
                      f"spread {step['spread']} {step['why_not'] or ''}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
