"""Memory at rest: what a fresh `eca up --web --silent-audio` holds, per process, against 300 MB in all.

Starts `eca up --web --silent-audio --web-port 0` on a private instance (a copy of the default config with
its own runtime directory, as the tests make; the default services: dialogue, gaze, audio and the renderer,
which `eca up --web` leaves out where there is no display; `--headless` keeps it, drawing offscreen, as on
a machine with a display), waits for readiness (the supervisor's "ready" line, then the web service's
"serving" line), then waits for the memory to settle at rest: it samples every process every
--sample-s and calls it settled once no process's RSS has moved more than --settle-mb over the last
--settle-window-s (or --settle-timeout-s has passed: the figure says so). Nobody connects to the page and
nothing is said: this is the instance at rest.

Per process (the supervisor and every descendant, found through /proc, or psutil where it is installed):
RSS, PSS and USS from /proc/PID/smaps_rollup. PSS splits each shared page among the processes that map it,
so the sum of PSS is what the instance holds (a page shared with other programs of the machine is split with them
too: PSS moves with what else runs, RSS does not); the sum of RSS counts a shared library once per process (the
figure people read off `top`). USS: pages no other process maps. Beside each process, the heavy packages it
has loaded (numpy, numba, llvmlite, moderngl, av, aiortc, scipy ...), read from the extension modules and
libraries mapped in /proc/PID/maps (site-packages/<package>/...): what it really holds at rest, whatever
imported it. And, probed in a fresh interpreter after the instance has stopped, the heavy packages each
process's entry module imports (pure-Python ones such as aiortc included): what it pulls before it runs.

Baseline, measured in the same run: the floor of one bus process, a fresh interpreter that imported
eca.protocol.bus (zmq, msgpack) and sleeps; "floor x processes" is what the instance would hold if no
process imported anything it does not need beyond the bus.

Figures are printed one per line against their target (met / MISSED / info); the bench always exits 0,
it is a measurement. With --json the table goes to stderr and one JSON object to stdout, as the last line.

    python bench/memory.py [--headless] [--top-mappings N] [--no-import-probe] [--settle-window-s 5] [--settle-mb 1]
                           [--settle-timeout-s 90] [--target-mb 300] [--json]

A run takes about 20-40 s on 2 cores (start, at least one settle window, the probes).
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from bench.procs import descendants, eca_label, memory_kib  # noqa: E402
from bench.report import Report, run_guarded  # noqa: E402
from eca.services.tools.child_processes import eca_command, subprocess_env  # noqa: E402 (after the path is set)

READY_TIMEOUT_S = 90.0  # eca up to "ready": a cold numba cache compiles the renderer's kernels first
SERVING_TIMEOUT_S = 20.0
TARGET_MB = 300.0
MIB = 1024 * 1024
# Packages worth naming when a process holds them: each costs tens of MB (or more) once imported.
HEAVY = ("numpy", "numba", "llvmlite", "scipy", "moderngl", "glcontext", "glfw", "av", "aiortc", "aiohttp",
         "aioice", "pylibsrtp", "cryptography", "PIL", "matplotlib", "sounddevice", "soundfile", "webrtcvad",
         "pygltflib", "pythonosc")
SITE_PACKAGE = re.compile(r"/(?:site|dist)-packages/([A-Za-z0-9_]+)(?:[./]|$)")
# A fresh interpreter with the bus's libraries: what any bus process holds at least.
# What each process imports at its start, probed in a fresh interpreter: pure-Python packages (aiortc) leave no
# mapped library behind, and this shows what the module alone pulls before it runs.
ENTRY_MODULES = {"supervisor": "eca.services.tools.commands.up", "broker": "eca.services.processes.broker"}
IMPORT_PROBE = ("import importlib, sys\nfrom eca.services.processes.run import SERVICES\n"
                "entry = {{**{{n: s.split(':')[0] for n, s in SERVICES.items()}}, **{entries!r}}}\n"
                "importlib.import_module(entry[sys.argv[1]])\n"
                "print('IMPORTED', ' '.join(sorted({{m.split('.')[0] for m in sys.modules}} & set({heavy!r}))))\n")
FLOOR_PROGRAM = ("import sys, time\nimport eca.protocol.bus\nprint('FLOOR READY', flush=True)\n"
                 "while sys.stdin.readline():\n    pass\n")


def progress(line: str) -> None:
    print(f"[memory] {line}", file=sys.stderr, flush=True)


# --- /proc ------------------------------------------------------------------------------------------


def packages_mapped(pid: int) -> list[str]:
    """The site-packages packages whose extension modules or libraries the process has mapped."""
    try:
        text = Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return []
    found = set()
    for line in text.splitlines():
        m = SITE_PACKAGE.search(line)
        if m:
            found.add(m.group(1).removesuffix(".libs").split(".")[0])
    # numpy's, scipy's ... bundled libraries live in site-packages/numpy.libs/ and the like.
    return sorted(found)


def imported_at_start(name: str) -> list[str] | None:
    """The heavy packages a fresh interpreter holds after importing the process's entry module (None: unknown
    process, or the probe failed)."""
    program = IMPORT_PROBE.format(entries=ENTRY_MODULES, heavy=HEAVY)
    try:
        done = subprocess.run([sys.executable, "-c", program, name], capture_output=True, text=True,
                              env=subprocess_env(), cwd=REPO, timeout=120)
    except subprocess.TimeoutExpired:
        return None
    line = next((x for x in done.stdout.splitlines() if x.startswith("IMPORTED")), None)
    return None if line is None else line.removeprefix("IMPORTED").split()


def rss_by_mapping(pid: int) -> dict[str, int]:
    """RSS in KiB per backing file (a library, an extension module) or kind of anonymous mapping ([heap],
    [anon]), from /proc/PID/smaps."""
    try:
        text = Path(f"/proc/{pid}/smaps").read_text()
    except OSError:
        return {}
    totals: dict[str, int] = {}
    name = ""
    for line in text.splitlines():
        head = line.split(None, 1)[0]
        if "-" in head and not head.endswith(":"):  # a mapping's header: address range, perms, offset, dev, inode, path
            parts = line.split(None, 5)
            name = parts[5].strip() if len(parts) > 5 else "[anon]"
            name = SITE_PACKAGE.sub(lambda m: f"/site-packages/{m.group(1)}/", name, count=1)
        elif head == "Rss:":
            totals[name] = totals.get(name, 0) + int(line.split()[1])
    return totals


# --- the instance -----------------------------------------------------------------------------------


@dataclass
class Sampled:
    """The memory of every process of the instance, sample after sample."""

    root: int
    labels: dict[int, str] = field(default_factory=dict)
    series: dict[int, list[tuple[float, dict[str, int]]]] = field(default_factory=dict)  # pid -> (t, memory)

    def sample(self) -> None:
        now = time.monotonic()
        alive = set()
        for pid in descendants(self.root):
            got = memory_kib(pid)
            if got is None:
                continue
            alive.add(pid)
            self.labels.setdefault(pid, eca_label(pid, self.root))
            self.series.setdefault(pid, []).append((now, got))
        for gone in set(self.series) - alive:  # a restarted service is a new process: the old one is forgotten
            del self.series[gone]

    def settled(self, window_s: float, tolerance_kib: int) -> bool:
        """Whether every process has been sampled over the whole window and its RSS has stayed within
        tolerance over it."""
        if not self.series:
            return False
        now = time.monotonic()
        for points in self.series.values():
            if now - points[0][0] < window_s:
                return False
            recent = [m["rss"] for t, m in points if now - t <= window_s]
            if max(recent) - min(recent) > tolerance_kib:
                return False
        return True

    def latest(self) -> dict[int, dict[str, int]]:
        return {pid: points[-1][1] for pid, points in self.series.items()}


@contextmanager
def eca_up(headless: bool) -> Iterator[tuple[subprocess.Popen[bytes], Any, Any]]:
    from tests.support.bus import private_bus_config, running

    with private_bus_config() as config:
        argv = eca_command("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet",
                           "--web", "--web-port", "0", "--silent-audio", *(["--headless"] if headless else []))
        progress(f"starting {' '.join(argv[3:5])} ... --web --silent-audio{' --headless' if headless else ''} "
                 f"(instance {config.instance})")
        with running(argv, stop_timeout_s=10.0) as (proc, reader):
            yield proc, reader, config


@contextmanager
def floor_process() -> Iterator[subprocess.Popen[str]]:
    """The baseline: a bus process that does nothing else, alive while the instance settles."""
    proc = subprocess.Popen([sys.executable, "-c", FLOOR_PROGRAM], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True, env=subprocess_env(), cwd=REPO)
    try:
        assert proc.stdout is not None
        proc.stdout.readline()  # "FLOOR READY": its imports are done
        yield proc
    finally:
        if proc.stdin is not None:
            proc.stdin.close()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)


def run(args: argparse.Namespace, report: Report) -> None:
    tolerance_kib = int(args.settle_mb * 1024)
    with floor_process() as floor, eca_up(args.headless) as (proc, reader, _config):
        t0 = time.monotonic()
        try:
            reader.wait_for("[up] ready in", READY_TIMEOUT_S)
            reader.wait_for("[web] INFO serving http://", SERVING_TIMEOUT_S)
        except TimeoutError:
            said = [line for line in reader.lines if re.search(r"ERROR|Error|not restarted", line)]
            report.add("eca up ready", "not ready", f"within {READY_TIMEOUT_S:g} s", False, "",
                       " | ".join(said[-3:]) or "no error printed")
            report.details["up_said"] = reader.lines[-40:]
            return
        ready_s = time.monotonic() - t0
        progress(f"ready after {ready_s:.1f} s; waiting for the memory to settle")
        sampled = Sampled(proc.pid)
        deadline = time.monotonic() + args.settle_timeout_s
        while True:
            sampled.sample()
            if sampled.settled(args.settle_window_s, tolerance_kib) or time.monotonic() >= deadline:
                break
            time.sleep(args.sample_s)  # pacing the samples, not synchronisation
        settled = sampled.settled(args.settle_window_s, tolerance_kib)
        settle_s = time.monotonic() - t0 - ready_s
        latest = sampled.latest()
        packages = {pid: packages_mapped(pid) for pid in latest}
        mappings = {pid: rss_by_mapping(pid) for pid in latest} if args.top_mappings else {}
        floor_mem = memory_kib(floor.pid) or {"rss": 0, "pss": 0, "uss": 0}
        restarts = [line for line in reader.lines if "restarting in" in line]
        said = [line for line in reader.lines
                if re.search(r"ERROR|Error|Traceback|exited with|restarting in|not restarted", line)]

    probed = {}
    if args.import_probe:
        progress("probing what each process's module imports")
        probed = {label: imported_at_start(label) for label in sorted(set(sampled.labels.values()))}
    report.add("eca up ready", round(ready_s, 1), "-", None, "s", "the supervisor's ready line, then the page served")
    report.add("memory settled", "yes" if settled else "no", f"within {args.settle_timeout_s:g} s", settled, "",
               f"after {settle_s:.1f} s: every RSS within {args.settle_mb:g} MB over {args.settle_window_s:g} s")
    if restarts:
        report.add("restarts", len(restarts), "0", False, "", restarts[0][:120])
    order = sorted(latest, key=lambda pid: (pid != proc.pid, sampled.labels[pid]))
    rows = []
    for pid in order:
        m = latest[pid]
        heavy = [p for p in packages[pid] if p in HEAVY]
        rows.append({"process": sampled.labels[pid], "pid": pid, "rss_mb": round(m["rss"] / 1024, 1),
                     "pss_mb": round(m["pss"] / 1024, 1), "uss_mb": round(m["uss"] / 1024, 1), "heavy": heavy,
                     "packages": packages[pid], "imported_at_start": probed.get(sampled.labels[pid]),
                     "top_mappings_mb": {k: round(v / 1024, 1) for k, v in sorted(
                         mappings.get(pid, {}).items(), key=lambda kv: -kv[1])[:args.top_mappings]}})
        report.add(f"{sampled.labels[pid]} RSS / PSS", f"{m['rss'] / 1024:.0f} / {m['pss'] / 1024:.0f}", "-", None,
                   "MB", ", ".join(heavy) or "no heavy package")
    total = {kind: sum(m[kind] for m in latest.values()) / 1024 for kind in ("rss", "pss", "uss")}
    report.add("total PSS", round(total["pss"]), f"<= {args.target_mb:g} MB", total["pss"] <= args.target_mb, "MB",
               f"{len(latest)} processes; what the instance holds")
    report.add("total RSS", round(total["rss"]), f"<= {args.target_mb:g} MB", total["rss"] <= args.target_mb, "MB",
               "shared pages counted once per process")
    report.add("total USS", round(total["uss"]), "-", None, "MB", "pages private to one process")
    floor_rss, floor_pss = floor_mem["rss"] / 1024, floor_mem["pss"] / 1024
    report.add("floor: one bus process RSS / PSS", f"{floor_rss:.0f} / {floor_pss:.0f}", "-", None, "MB",
               "baseline: a fresh interpreter with eca.protocol.bus, measured in this run")
    report.add("floor x processes (RSS)", round(floor_rss * len(latest)), "-", None, "MB",
               f"total RSS {total['rss'] / floor_rss / len(latest):.1f}x of it" if floor_rss else "")
    report.details.update({
        "processes": rows, "total_mb": {k: round(v, 1) for k, v in total.items()},
        "floor_mb": {k: round(v / 1024, 1) for k, v in floor_mem.items()}, "settled": settled,
        "settle_s": round(settle_s, 1), "ready_s": round(ready_s, 1),
        "up_said": said,
        "rss_series_mb": {sampled.labels[pid]: [round(m["rss"] / 1024, 1) for _, m in points]
                          for pid, points in sampled.series.items()},
    })


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--headless", action="store_true",
                        help="pass --headless: keep the renderer, drawing offscreen (as with a display)")
    parser.add_argument("--sample-s", type=float, default=0.5, help="time between samples (s)")
    parser.add_argument("--settle-window-s", type=float, default=5.0, help="how long RSS must stay still (s)")
    parser.add_argument("--settle-mb", type=float, default=1.0, help="how much RSS may move in the window (MB)")
    parser.add_argument("--settle-timeout-s", type=float, default=90.0, help="give up settling after this (s)")
    parser.add_argument("--target-mb", type=float, default=TARGET_MB, help="the instance's target, in all (MB)")
    parser.add_argument("--top-mappings", type=int, default=0, metavar="N",
                        help="also list each process's N largest mappings (libraries, heap) by RSS")
    parser.add_argument("--no-import-probe", dest="import_probe", action="store_false",
                        help="skip probing what each process's module imports")
    parser.add_argument("--json", action="store_true", help="print one JSON object (the table goes to stderr)")
    args = parser.parse_args(argv)

    done = run_guarded(lambda report: run(args, report))  # Ctrl-C or SIGTERM: eca up and the floor stop
    report, host, wall_s = done.report, done.host, done.wall_s
    out = sys.stderr if args.json else sys.stdout
    report.print_table(done.header("memory at rest", "eca up --web --silent-audio"
                                   + (" --headless" if args.headless else "")), out,
                       report.details.get("up_said", []), "eca up said (errors, restarts):")
    rows = report.details.get("processes", [])
    if rows:
        print("  packages mapped per process (site-packages):", file=out)
        for row in rows:
            print(f"    {row['process']:<10} {' '.join(row['packages']) or '-'}", file=out)
        if args.top_mappings:
            print(f"  the {args.top_mappings} largest mappings per process (RSS, MB):", file=out)
            for row in rows:
                print(f"    {row['process']}: " + ", ".join(f"{Path(k).name or k} {v:g}"
                                                         for k, v in row["top_mappings_mb"].items()), file=out)
        if any(row["imported_at_start"] is not None for row in rows):
            print("  heavy packages its module imports, in a fresh interpreter (before it runs):", file=out)
            for row in rows:
                got = row["imported_at_start"]
                print(f"    {row['process']:<10} {'?' if got is None else ' '.join(got) or '-'}", file=out)
    if args.json:
        print(json.dumps({"bench": "memory", "machine": host, "wall_s": round(wall_s, 1),
                          "options": vars(args), **report.as_json()}, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
