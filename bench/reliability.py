"""Reliability: how a running eca instance survives the field — a command flood, then long says under CPU load.

Starts `eca up --headless` (broker, dialogue, gaze, audio, renderer at 60 fps) on a private instance, then:

1. flood: for --flood-s seconds, one or more sender processes publish commands to agent `ada` at --rate
   messages per second, paced on the monotonic clock in small bursts per millisecond tick (the average
   rate is exact). A fraction (--garbage) is garbage on `cmd.ada.*` topics: bytes that are not msgpack,
   maps with wrong types, missing fields, unknown types or extra keys, NaN and infinities, oversize-ish
   strings, values nested 200 deep, the wrong number of frames, topics that disagree with the payload,
   non-UTF-8 topics. The rest is a mix of set_emotion, move_head, set_role, set_gaze_target and set_eyes
   with varying values. Meanwhile a monitor process (its own, so the bench's reading does not share the
   orchestrator's CPU time) counts the renderer's `stream.ada.face_frame` messages in 1 s windows of
   their publish stamps, and every 50 ms sends a set_emotion with a unique intensity (and a request id)
   and times the matching `state.ada.emotion`, or the command's `event.ada.ack` from a dialogue service
   that acknowledges commands and publishes one state per batch (where a later command in the same batch
   hides the probe's value). The supervisor's output tells restarts; /proc tells each process's
   resident memory before the flood (after a 3 s warm-up), every second of it, at its end and 5 s later.
2. settle: right after its last flood message each sender sends one final command per state (emotion
   surprised 0.37, head turn 0.21, role silence, gaze yaw 7.5, eyes saccade) on the same socket, so they
   queue behind the flood and no flood message can overtake them. The figure is the time from that send
   until the bus carries all five (and nothing later replaces them); a fresh client then reads the
   state from the broker's cache and compares.
3. long says under load: one busy-looping process per core for the rest of the run; a --say-s (60 s)
   WAV played to its end, then a --long-s (600 s) WAV interrupted after it has played 30 s. Each must end
   in exactly one terminal event (counted until 2 s after the first) with no service restarted.

Figures are printed one per line against their target (met / MISSED / info); the bench always exits 0,
it is a measurement. With --json the table goes to stderr and one JSON object to stdout (figures, and
details: fps per window, RSS series, sender counts, lifecycle events, what eca up said). The probe
latency targets (p50 and p99 <= 100 ms) are the settle target: a command should show within 100 ms.
One sender process offers 20,000 msg/s on a 2-core machine; where "flood rate offered" is missed, the
sender could not keep up: run again with --senders 2 (the rate is shared).

    python bench/reliability.py [--flood-s 30] [--rate 20000] [--garbage 0.1] [--senders 1]
                                [--say-s 60] [--long-s 600] [--skip-flood] [--skip-says] [--seed 0] [--json]
    python bench/reliability.py --flood-s 5 --rate 5000 --skip-says          # a quick look

A full run takes about 2.5 minutes (5 s start and warm-up, 30 + 5 s flood and settle, ~5 s of WAVs,
60 + 2 s and 30 + 2 s of says); less when a say fails early.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from bench._reliability_common import (  # noqa: E402
    AFTER_FLOOD_S,
    AGENT,
    BUSY_LOOP,
    INTERRUPT_AFTER_S,
    PLAYED_TOLERANCE_S,
    PROBE_ANSWER_TIMEOUT_S,
    PROBE_PERIOD_S,
    READY_TIMEOUT_S,
    SAY_RATE_HZ,
    SETTLE_TIMEOUT_S,
    STATE_KINDS,
    TARGET_FPS_OF_60,
    TARGET_PROBE_MS,
    TARGET_RSS_GROWTH,
    TARGET_SETTLE_MS,
    TARGET_START_S,
    WARM_UP_S,
    is_final,
    reliability_command,
    say_stderr,
)
from bench._reliability_flood import run_sender  # noqa: E402
from bench._reliability_monitor import run_monitor  # noqa: E402
from bench.report import Report, percentile, run_guarded, wait_until_ns  # noqa: E402
from eca.services.tools.child_processes import subprocess_env  # noqa: E402 (after the path is set)

# --- orchestration ---------------------------------------------------------------------------------


def rss_kib(pid: int) -> int | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except (FileNotFoundError, ProcessLookupError, PermissionError):
        return None
    return None


READY_LINE = re.compile(r"^\[([\w-]+)\] INFO ready \(pid (\d+)\)")
RESTART_LINE = re.compile(r"^\[up\] ([\w-]+) (.+?); restarting in ([0-9.]+) s")
BACK_LINE = re.compile(r"^\[up\] ([\w-]+) is back \(pid (\d+)\)")
GIVEN_UP_LINE = re.compile(r"^\[up\] ([\w-]+) (.+?); it failed \d+ times .* not restarted again")
NOTABLE = re.compile(r"ERROR|Traceback|Error:|WARNING|CRITICAL|exited with|no heartbeat|given up|killing")


class Up:
    """`eca up` on a private instance: its output lines, service pids, restarts by line range."""

    def __init__(self, proc: subprocess.Popen[bytes], reader: Any, instance: str) -> None:
        self.proc = proc
        self.reader = reader
        self.instance = instance
        self.all_pids: set[int] = set()

    def mark(self) -> int:
        return len(self.reader.lines)

    def pids(self) -> dict[str, int]:
        """The latest pid of each process (a restarted service announces its new one)."""
        out: dict[str, int] = {}
        for line in list(self.reader.lines):
            m = READY_LINE.match(line)
            if m:
                out[m.group(1)] = int(m.group(2))
                self.all_pids.add(int(m.group(2)))
        return out

    def events(self, start: int, end: int | None = None) -> dict[str, Any]:
        lines = list(self.reader.lines)[start:end]
        restarts: list[str] = []
        back: list[str] = []
        given_up: list[str] = []
        notable: list[str] = []
        rejections: list[str] = []
        for line in lines:
            if (m := RESTART_LINE.match(line)) is not None:
                restarts.append(f"{m.group(1)}: {m.group(2)}")
            elif (m := BACK_LINE.match(line)) is not None:
                back.append(m.group(1))
            elif (m := GIVEN_UP_LINE.match(line)) is not None:
                given_up.append(m.group(1))
            if "WARNING rejected" in line:
                rejections.append(line[:300])  # once per kind and service: what the garbage provoked
            elif NOTABLE.search(line) and len(notable) < 40:
                notable.append(line[:300])
        return {"restarts": restarts, "back": back, "given_up": given_up, "notable_lines": notable,
                "rejection_lines": rejections[:40]}

    def given_up(self) -> list[str]:
        return self.events(0)["given_up"]


@contextmanager
def child(argv: list[str], stdin: bool = False) -> Iterator[tuple[subprocess.Popen[bytes], Any]]:
    """A helper process of the bench with its stdout read line by line; killed (group) afterwards."""
    from eca.services.tools.child_processes import LineReader

    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stdin=subprocess.PIPE if stdin else subprocess.DEVNULL,
                            env=subprocess_env(), cwd=REPO, start_new_session=True)
    try:
        yield proc, LineReader(proc.stdout)
    finally:
        stop_process_group(proc, 5.0)


def stop_process_group(proc: subprocess.Popen[Any], grace_s: float) -> None:
    if proc.stdin is not None:
        try:
            proc.stdin.close()
        except OSError:
            pass
    try:
        proc.wait(timeout=grace_s)
    except subprocess.TimeoutExpired:
        pass
    try:
        os.killpg(proc.pid, signal.SIGKILL)  # its own session: the group is only this helper
    except ProcessLookupError:
        pass
    proc.wait(timeout=5)


def send_line(proc: subprocess.Popen[bytes], line: str) -> None:
    assert proc.stdin is not None
    try:
        proc.stdin.write((line + "\n").encode())
        proc.stdin.flush()
    except (BrokenPipeError, OSError):
        pass  # it has gone: its missing output is reported as such


def json_line(reader: Any, timeout_s: float, start: int = 0, prefix: str = "{") -> dict[str, Any] | None:
    """The first line from `start` on that begins with `prefix`, parsed as JSON (None: none in time)."""
    try:
        index = reader.wait_for(prefix, timeout_s, start)
    except TimeoutError:
        return None
    text = reader.lines[index]
    return json.loads(text[text.index("{"):])


def fps_windows(frames_t_ns: list[int], start_ns: int, end_ns: int) -> list[int]:
    """Frames published in each whole 1 s window of [start, end)."""
    n = int((end_ns - start_ns) // 1_000_000_000)
    counts = [0] * n
    for t in frames_t_ns:
        i = (t - start_ns) // 1_000_000_000
        if 0 <= i < n:
            counts[i] += 1
    return counts


# --- phase 1 + 2: flood and settle ----------------------------------------------------------------


def flood_phase(args: argparse.Namespace, config: Any, up: Up, monitor: subprocess.Popen[bytes],
                monitor_out: Any, report: Report) -> None:
    rate_each = args.rate / args.senders
    rss_before = {name: rss_kib(pid) for name, pid in up.pids().items()}
    pids_before = up.pids()
    with contextmanager_list([child(reliability_command("--role", "sender", "--config", str(config.config_path),
                                                        "--instance", config.instance, "--rate", str(rate_each),
                                                        "--flood-s", str(args.flood_s), "--garbage", str(args.garbage),
                                                        "--seed", str(args.seed), "--index", str(i)), stdin=True)
                              for i in range(args.senders)]) as senders:
        for _, out in senders:
            try:
                out.wait_for("READY", 60.0)
            except TimeoutError:
                report.add("flood", "not run", "runs", False, "", "a sender did not get ready (no broker?)")
                return
        mark = up.mark()
        start_ns = time.monotonic_ns() + 300_000_000  # time for the go lines to arrive
        end_ns = start_ns + int(args.flood_s * 1e9)
        send_line(monitor, f"probe {start_ns} {end_ns - 100_000_000}")  # probes stop before the final commands
        for proc, _ in senders:
            send_line(proc, f"go {start_ns}")
        say_stderr(f"phase 1: flood, {args.flood_s:g} s at {args.rate:g} msg/s ({args.garbage:.0%} garbage) "
                   f"from {args.senders} sender process(es)")
        next_progress = [start_ns + 10_000_000_000]
        rss_series: list[tuple[float, dict[str, int | None]]] = []  # a plateau or a steady climb

        def progress(left_s: float) -> None:
            time.sleep(min(left_s, 1.0))
            now = time.monotonic_ns()
            rss_series.append((round((now - start_ns) / 1e9, 1),
                               {name: rss_kib(pid) for name, pid in up.pids().items()}))
            if now >= next_progress[0]:
                say_stderr(f"  flood: {(now - start_ns) / 1e9:.0f} / {args.flood_s:g} s")
                next_progress[0] += 10_000_000_000

        wait_until_ns(end_ns, progress)
        rss_end = {name: rss_kib(pid) for name, pid in up.pids().items()}
        pids_end = up.pids()
        results = [json_line(out, args.flood_s + 120.0) for _, out in senders]
        done = [r for r in results if r is not None and "offered" in r]
        say_stderr("phase 2: settle")
        settle: dict[str, Any] = {}
        if len(done) == len(results):
            settle = settle_phase(config, monitor_out, done)
        wait_until_ns(end_ns + int(AFTER_FLOOD_S * 1e9))
        rss_after = {name: rss_kib(pid) for name, pid in up.pids().items()}
        pids_after = up.pids()
        flood_events = up.events(mark)
        send_line(monitor, "stop")
        watched = json_line(monitor_out, 30.0, start=0, prefix='{"frames_t_ns"')
    report.details["flood"] = {"senders": results, "events": flood_events,
                               "rss_kib": {"before": rss_before, "end": rss_end, "after": rss_after,
                                           "during": rss_series},
                               "pids": {"before": pids_before, "end": pids_end, "after": pids_after}}
    report.details["settle"] = settle

    # the flood's figures
    if done:
        offered = sum(r["offered"] for r in done)
        sent = sum(r["sent"] for r in done)
        span_s = (max(r["last_ns"] for r in done) - min(r["first_ns"] for r in done)) / 1e9
        offered_rate = offered / span_s if span_s > 0 else 0.0
        kept_up = offered_rate >= args.rate * 0.99
        report.add("flood rate offered", round(offered_rate), f">= {args.rate * 0.99:.0f}", kept_up, "msg/s",
                   f"{args.senders} sender process(es); most behind schedule "
                   f"{max(r['max_behind_ms'] for r in done):.0f} ms"
                   + ("" if kept_up else f"; the sender(s) could not keep up: try --senders {args.senders + 1}"))
        report.add("flood taken by the bus", round(sent / span_s) if span_s > 0 else 0, "-", None, "msg/s",
                   f"{offered - sent} refused: the sender's queue to the broker was full")
        garbage_sent = sum(r["garbage_sent"] for r in done)
        report.add("garbage sent", garbage_sent, "-", None, "msg", f"{garbage_sent / max(sent, 1):.1%} of sent")
    else:
        report.add("flood rate offered", 0, f">= {args.rate * 0.99:.0f}", False, "msg/s",
                   "the senders reported nothing")
    if watched is None:
        report.add("renderer fps during flood", "no data", f">= {TARGET_FPS_OF_60:g}", False, "",
                   "the monitor gave no report")
        return
    report.details["monitor"] = {k: v for k, v in watched.items() if k not in ("frames_t_ns", "probes")}
    fps_scale = args.fps / 60.0
    fps_target = TARGET_FPS_OF_60 * fps_scale
    warm = fps_windows(watched["frames_t_ns"], start_ns - int(WARM_UP_S * 1e9) + 10**8, start_ns)
    flood_windows = fps_windows(watched["frames_t_ns"], start_ns, end_ns)
    report.details["fps_windows"] = {"before": warm, "flood": flood_windows}
    if warm:
        report.add("renderer fps before flood", round(statistics.mean(warm), 1), "-", None, "fps")
    gone = "; renderer given up" if "renderer" in up.given_up() else ""
    if flood_windows:
        median_fps = statistics.median(flood_windows)
        min_fps = min(flood_windows)
        mean_fps = sum(flood_windows) / len(flood_windows)
        report.add("renderer fps, flood, median of 1 s", median_fps, f">= {fps_target:g}", median_fps >= fps_target,
                   "fps", gone.lstrip("; "))
        report.add("renderer fps, flood, min of 1 s", min_fps, f">= {fps_target:g}", min_fps >= fps_target, "fps")
        report.add("renderer fps, flood, mean", round(mean_fps, 1), f">= {fps_target:g}", mean_fps >= fps_target,
                   "fps")
    probes = watched["probes"]
    report.details["probe_latency_ms"] = [None if p[1] is None else round((p[1] - p[0]) / 1e6, 1) for p in probes]
    answered = [(p[1] - p[0]) / 1e6 for p in probes if p[1] is not None and p[1] - p[0] <= PROBE_ANSWER_TIMEOUT_S * 1e9]
    missing = len(probes) - len(answered)
    if answered:
        p50, p99 = percentile(answered, 0.5), percentile(answered, 0.99)
        report.add("command latency p50 (probe)", round(p50, 1), f"<= {TARGET_PROBE_MS:g}", p50 <= TARGET_PROBE_MS,
                   "ms", f"{len(probes)} probes, one per {PROBE_PERIOD_S * 1000:g} ms")
        report.add("command latency p99 (probe)", round(p99, 1), f"<= {TARGET_PROBE_MS:g}", p99 <= TARGET_PROBE_MS,
                   "ms")
        report.add("command latency max (probe)", round(max(answered), 1), "-", None, "ms")
    by_state = sum(1 for p in probes if p[3] is not None)
    by_ack = sum(1 for p in probes if p[4] is not None)
    report.add("probes unanswered within 2 s", missing, "0", missing == 0 and bool(probes), "",
               f"of {len(probes)}; {by_state} seen as their state, {by_ack} acknowledged")
    beats = watched.get("heartbeats", {}).get("dialogue", [])
    before = [b[3] for b in beats if b[0] <= start_ns]
    after = [b[3] for b in beats if b[0] <= end_ns + int(AFTER_FLOOD_S * 1e9)]
    if before and after and done:
        report.add("garbage counted bad by dialogue", after[-1] - before[-1], "-", None, "msg",
                   f"of {sum(r['garbage_sent'] for r in done)} sent (heartbeat bad_messages)")
    restarts = flood_events["restarts"]
    report.add("restarts during flood", len(restarts), "0", not restarts, "",
               "; ".join(restarts[:4]) + (" ..." if len(restarts) > 4 else ""))
    if flood_events["given_up"]:
        report.add("services given up (flood)", ", ".join(flood_events["given_up"]), "none", False)
    for name in sorted(rss_before):
        b, a = rss_before.get(name), rss_after.get(name)
        e = rss_end.get(name)
        restarted = pids_before.get(name) != pids_after.get(name)
        if b and a and not restarted:
            growth = a / b - 1.0
            mid = [kib.get(name) for t, kib in rss_series if t <= args.flood_s / 2]
            mid_mib = f"{(mid[-1] or 0) / 1024:.0f} (mid-flood) -> " if mid else ""
            report.add(f"RSS growth {name}", round(growth * 100, 1), f"<= {TARGET_RSS_GROWTH * 100:g}",
                       growth <= TARGET_RSS_GROWTH, "%",
                       f"{b / 1024:.0f} -> {mid_mib}{(e or 0) / 1024:.0f} (end) -> {a / 1024:.0f} MiB (+5 s)")
        else:
            why = "restarted" if restarted else "process gone"
            report.add(f"RSS growth {name}", why, f"<= {TARGET_RSS_GROWTH * 100:g}", False, "",
                       f"before {(b or 0) / 1024:.0f} MiB; a new process after it is not comparable"
                       if restarted else f"before {(b or 0) / 1024:.0f} MiB")
    # phase 2
    if not settle:
        report.add("settle: final states on the bus", "not measured",
                   f"<= {TARGET_SETTLE_MS:g}", False, "ms")
        return
    finals = watched.get("finals", {})
    missing_kinds = [k for k in STATE_KINDS if not finals.get(k)]
    if missing_kinds:
        refused = sorted({t for r in done for t in r.get("finals_refused", [])})
        report.add("settle: final states on the bus", f"{len(missing_kinds)} of 5 never came",
                   f"<= {TARGET_SETTLE_MS:g}", False, "ms", f"no final {', '.join(missing_kinds)} within "
                   f"{SETTLE_TIMEOUT_S:g} s" + (f"; the bus refused the final {', '.join(refused)}" if refused else ""))
    else:
        arrival = max(finals[k]["arrival_ns"] for k in STATE_KINDS)
        stamped = max(finals[k]["t_ns"] for k in STATE_KINDS)
        ms = (arrival - settle["final_sent_ns"]) / 1e6
        report.add("settle: final states on the bus", round(ms, 1), f"<= {TARGET_SETTLE_MS:g}",
                   ms <= TARGET_SETTLE_MS, "ms", "last of five, at a subscriber")
        report.add("settle: per dialogue's stamps", round((stamped - settle["final_sent_ns"]) / 1e6, 1), "-", None,
                   "ms", "the state's t_ns (when the dialogue service applied it)")
    read_back = settle.get("read_back", {})
    mismatch = final_mismatches(read_back)
    report.add("final state read back (fresh client)", "equal" if not mismatch else f"{len(mismatch)} differ",
               "equal", not mismatch, "", "; ".join(mismatch))


def settle_phase(config: Any, monitor_out: Any, done: list[dict[str, Any]]) -> dict[str, Any]:
    """Wait for the monitor to see all five final states; then read the state as a fresh client."""
    from eca.protocol.bus import BusTimeout
    from eca.protocol.client import AgentClient

    final_sent_ns = max(r["final_sent_ns"] for r in done)
    left_s = SETTLE_TIMEOUT_S - (time.monotonic_ns() - final_sent_ns) / 1e9
    settle: dict[str, Any] = {"final_sent_ns": final_sent_ns, "last_flood_ns": max(r["last_ns"] for r in done),
                              "seen": json_line(monitor_out, max(0.0, left_s), prefix="SETTLED")}
    try:  # the broker's cache hands a new client the current state
        with AgentClient(config, agent=AGENT, source="reliability-check", timeout_s=10.0) as client:
            read_back: dict[str, Any] = {k: v.__dict__ for k, v in client.state.items()}
    except (BusTimeout, OSError) as exc:
        read_back = {"error": f"{type(exc).__name__}: {exc}"}
    settle["read_back"] = {k: {f: v for f, v in d.items() if f not in ("seq", "t_ns", "source")}
                           if isinstance(d, dict) else d for k, d in read_back.items()}
    return settle


def final_mismatches(read_back: dict[str, Any]) -> list[str]:
    if "error" in read_back:
        return [str(read_back["error"])]
    out = []
    for kind in STATE_KINDS:
        state = read_back.get(kind)
        if state is None:
            out.append(f"{kind} missing")
        elif not is_final(kind, state):
            shown = {k: v for k, v in state.items() if k not in ("agent", "v", "type")}
            out.append(f"{kind} {shown}")
    return out


@contextmanager
def contextmanager_list(managers: list[Any]) -> Iterator[list[Any]]:
    from contextlib import ExitStack

    with ExitStack() as stack:
        yield [stack.enter_context(m) for m in managers]


# --- phase 3: long says under load -----------------------------------------------------------------


def make_wav(path: Path, seconds: float, workdir: Path) -> str:
    """A WAV of exactly `seconds` at 22,050 Hz: espeak-ng speech tiled, or a modulated tone without it."""
    import numpy as np
    import soundfile as sf

    n = int(round(seconds * SAY_RATE_HZ))
    clip: Any = None
    what = "modulated tone"
    espeak = shutil.which("espeak-ng")
    if espeak:
        speech = workdir / "clip.wav"
        if not speech.exists():
            subprocess.run([espeak, "-w", str(speech), "-s", "160",
                            "The quick brown fox jumps over the lazy dog, and then it rests for a while."],
                           check=False, capture_output=True, timeout=60)
        if speech.exists():
            data, rate = sf.read(str(speech), dtype="int16", always_2d=True)
            if rate == SAY_RATE_HZ and len(data):
                clip = np.concatenate([data[:, 0], np.zeros(SAY_RATE_HZ // 4, np.int16)])  # a pause per sentence
                what = "espeak-ng speech, tiled"
    if clip is None:
        t = np.arange(SAY_RATE_HZ * 2) / SAY_RATE_HZ
        envelope = 0.5 * (1 - np.cos(2 * np.pi * 4.0 * t))  # four syllables a second
        clip = (0.3 * 32767 * envelope * np.sin(2 * np.pi * 150.0 * t)).astype(np.int16)
    signal_ = np.resize(clip, n)  # tiles the clip up to n samples
    sf.write(str(path), signal_, SAY_RATE_HZ, subtype="PCM_16")
    return what


@dataclass
class SayOutcome:
    sent_ns: int
    events: list[tuple[int, str, dict[str, Any]]] = field(default_factory=list)
    interrupt_sent_ns: int | None = None

    @property
    def started_arrival_ns(self) -> int | None:
        return next((t for t, kind, _ in self.events if kind == "speech_started"), None)

    @property
    def terminals(self) -> list[tuple[int, str, dict[str, Any]]]:
        return [e for e in self.events if e[1] in ("speech_finished", "speech_interrupted", "speech_failed",
                                                   "error")]


def follow_say(client: Any, request_id: str, sent_ns: int, finish_by_ns: int, interrupt_after_s: float | None,
               label: str) -> SayOutcome:
    """Collect the request's lifecycle events until 2 s after its first terminal event (or the deadline);
    with `interrupt_after_s`, interrupt it once it has played that long."""
    outcome = SayOutcome(sent_ns)
    deadline = finish_by_ns
    first_terminal: int | None = None
    # until speech_started tells when playing began, count the wait from the send
    interrupt_at = sent_ns + int(interrupt_after_s * 1e9) if interrupt_after_s is not None else None
    next_progress = sent_ns + 10_000_000_000
    while (now := time.monotonic_ns()) < deadline:
        wake = min(deadline, interrupt_at or deadline, next_progress)
        got = client.sub.recv(max(0.0, (wake - now) / 1e9))
        now = time.monotonic_ns()
        msg = got.message if got is not None else None
        if msg is not None and getattr(msg, "request_id", None) == request_id and msg.TYPE in (
                "speech_started", "speech_finished", "speech_interrupted", "speech_failed", "error"):
            body = {k: v for k, v in msg.__dict__.items() if k not in ("agent", "seq", "source")}
            outcome.events.append((now, msg.TYPE, body))
            if msg.TYPE == "speech_started" and interrupt_after_s is not None:
                begun = msg.dac_time_ns or now  # type: ignore[attr-defined]
                interrupt_at = begun + int(interrupt_after_s * 1e9)
            elif msg.TYPE != "speech_started" and first_terminal is None:
                first_terminal = now
                deadline = now + 2_000_000_000  # any second terminal event would come within this
                interrupt_at = None
        if interrupt_at is not None and now >= interrupt_at and outcome.interrupt_sent_ns is None:
            client.interrupt(request_id, reason="reliability bench")
            outcome.interrupt_sent_ns = now
            interrupt_at = None
            deadline = min(deadline, now + 15_000_000_000)
        if now >= next_progress:
            say_stderr(f"  {label}: {(now - sent_ns) / 1e9:.0f} s, events so far: "
                       f"{', '.join(kind for _, kind, _ in outcome.events) or 'none'}")
            next_progress += 10_000_000_000
    return outcome


def say_figures(report: Report, label: str, outcome: SayOutcome, expect: str, played_target_s: float,
                start_target_s: float | None, events: dict[str, Any]) -> None:
    started = outcome.started_arrival_ns
    start_s = None if started is None else (started - outcome.sent_ns) / 1e9
    if start_target_s is None:
        report.add(f"{label}: send -> speech_started", "never" if start_s is None else round(start_s, 3), "-", None,
                   "s")
    else:
        report.add(f"{label}: send -> speech_started", "never" if start_s is None else round(start_s, 3),
                   f"<= {start_target_s:g}", start_s is not None and start_s <= start_target_s, "s")
    terminals = outcome.terminals
    first = terminals[0] if terminals else None
    note = ""
    if first is not None and first[1] == "speech_failed":
        note = str(first[2].get("reason", ""))[:160]
    if first is not None and first[1] == "error":
        note = str(first[2].get("reason", ""))[:160]
    report.add(f"{label}: terminal event", first[1] if first else "none", expect,
               first is not None and first[1] == expect, "", note)
    played = first[2].get("played_s") if first is not None else None
    report.add(f"{label}: played_s", "-" if played is None else round(played, 3),
               f"{played_target_s:g} +- {PLAYED_TOLERANCE_S:g}",
               played is not None and abs(played - played_target_s) <= PLAYED_TOLERANCE_S, "s")
    report.add(f"{label}: terminal events for the request", len(terminals), "1", len(terminals) == 1)
    restarts = events["restarts"]
    report.add(f"{label}: restarts", len(restarts), "0", not restarts, "",
               "; ".join(restarts[:4]) + (" ..." if len(restarts) > 4 else ""))


def says_phase(args: argparse.Namespace, config: Any, up: Up, workdir: Path, report: Report) -> None:
    from eca.protocol.bus import BusTimeout
    from eca.protocol.client import AgentClient

    say_stderr(f"phase 3: long says under load ({os.cpu_count()} busy processes); writing WAVs")
    short_wav, long_wav = workdir / "say_short.wav", workdir / "say_long.wav"
    what = make_wav(short_wav, args.say_s, workdir)
    make_wav(long_wav, args.long_s, workdir)
    report.details["says"] = {"audio": what, "short_s": args.say_s, "long_s": args.long_s}
    busy: list[subprocess.Popen[bytes]] = []
    try:
        for _ in range(os.cpu_count() or 1):
            busy.append(subprocess.Popen([sys.executable, "-c", BUSY_LOOP], start_new_session=True,
                                         stdin=subprocess.DEVNULL))
        report.add("busy processes", len(busy), "-", None, "", "pure Python loops, one per core, for the says")
        try:
            client = AgentClient(config, agent=AGENT, source="reliability-say", timeout_s=10.0)
        except (BusTimeout, OSError) as exc:
            report.add("says", "not run", "runs", False, "", f"no client: {exc}")
            return
        with client:
            mark = up.mark()
            rid = "reliability-short"
            say_stderr(f"  say {args.say_s:g} s ({what})")
            sent_ns = time.monotonic_ns()
            client.say(audio_path=str(short_wav), text="reliability bench, short", request_id=rid)
            outcome = follow_say(client, rid, sent_ns, sent_ns + int((args.say_s + 30) * 1e9), None,
                                 f"{args.say_s:g} s say")
            events = up.events(mark)
            report.details["says"]["short"] = {"events": outcome.events, "up": events}
            say_figures(report, f"{args.say_s:g} s say", outcome, "speech_finished", args.say_s, None, events)

            mark = up.mark()
            rid = "reliability-long"
            interrupt_after = min(INTERRUPT_AFTER_S, args.long_s / 2)
            say_stderr(f"  say {args.long_s:g} s, interrupted after {interrupt_after:g} s")
            sent_ns = time.monotonic_ns()
            client.say(audio_path=str(long_wav), text="reliability bench, long", request_id=rid)
            outcome = follow_say(client, rid, sent_ns, sent_ns + int((args.long_s + 30) * 1e9), interrupt_after,
                                 f"{args.long_s:g} s say")
            events = up.events(mark)
            report.details["says"]["long"] = {"events": outcome.events, "up": events,
                                              "interrupt_sent_ns": outcome.interrupt_sent_ns}
            say_figures(report, f"{args.long_s:g} s say", outcome, "speech_interrupted", interrupt_after,
                        TARGET_START_S, events)
    finally:
        for proc in busy:
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            proc.wait(timeout=5)


# --- the run ---------------------------------------------------------------------------------------


def kill_leftovers(up: Up) -> list[int]:
    """Services of this instance still alive after eca up stopped (each runs in its own session)."""
    killed = []
    for pid in sorted(up.all_pids):
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
        except OSError:
            continue
        if up.instance.encode() in cmdline:  # ours (the pid was not reused by another program)
            try:
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
            except ProcessLookupError:
                pass
    return killed


def guarded(phase: str, report: Report, body: Callable[[], None]) -> None:
    """Run a phase; a failure of the bench itself becomes a figure, and the next phase still runs."""
    try:
        body()
    except Exception as exc:
        report.add(phase, "bench failed", "runs", False, "", f"{type(exc).__name__}: {exc}")
        report.details.setdefault("exceptions", []).append(traceback.format_exc())


def run(args: argparse.Namespace, report: Report) -> None:
    from tests.support.bus import eca_command, private_bus_config, running

    workdir = Path(tempfile.mkdtemp(prefix="eca-rel-"))
    try:
        with private_bus_config() as config:
            argv = eca_command("up", "--config", str(config.config_path), "--instance", config.instance,
                               "--headless", "--fps", f"{args.fps:g}", "--quiet")
            say_stderr(f"starting eca up (instance {config.instance})")
            with running(argv, stop_timeout_s=10.0) as (proc, reader):
                up = Up(proc, reader, config.instance)
                try:
                    line = reader.lines[reader.wait_for("[up] ready in", READY_TIMEOUT_S)]
                    report.details["ready_line"] = line
                except TimeoutError:
                    report.add("eca up ready", "not ready", f"within {READY_TIMEOUT_S:g} s", False, "",
                               " | ".join(up.events(0)["notable_lines"][:3]))
                    up.pids()
                    return
                up.pids()
                try:
                    if not args.skip_flood:
                        with child(reliability_command("--role", "monitor", "--config", str(config.config_path),
                                                       "--instance", config.instance, "--seed", str(args.seed)),
                                   stdin=True) as (mon, mon_out):
                            try:
                                mon_out.wait_for("READY", 30.0)
                            except TimeoutError:
                                report.add("flood", "not run", "runs", False, "", "the monitor did not get ready")
                            else:
                                say_stderr(f"warm-up {WARM_UP_S:g} s")
                                wait_until_ns(time.monotonic_ns() + int(WARM_UP_S * 1e9))
                                guarded("flood", report, lambda: flood_phase(args, config, up, mon, mon_out, report))
                    if not args.skip_says:
                        guarded("says", report, lambda: says_phase(args, config, up, workdir, report))
                finally:
                    up.pids()
                    report.details["up_events_whole_run"] = up.events(0)
            killed = kill_leftovers(up)
            if killed:
                report.details["killed_leftover_pids"] = killed
    finally:
        shutil.rmtree(workdir, ignore_errors=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--flood-s", type=float, default=30.0, help="flood duration (s)")
    parser.add_argument("--rate", type=float, default=20_000.0, help="flood messages per second, all senders")
    parser.add_argument("--garbage", type=float, default=0.10, help="fraction of the flood that is garbage")
    parser.add_argument("--senders", type=int, default=1, help="sender processes sharing the rate")
    parser.add_argument("--fps", type=float, default=60.0, help="the renderer's frame rate")
    parser.add_argument("--say-s", type=float, default=60.0, help="length of the say played to its end (s)")
    parser.add_argument("--long-s", type=float, default=600.0, help="length of the say that is interrupted (s)")
    parser.add_argument("--skip-flood", action="store_true", help="skip phases 1 and 2")
    parser.add_argument("--skip-says", action="store_true", help="skip phase 3")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print one JSON object (the table goes to stderr)")
    parser.add_argument("--role", choices=["sender", "monitor"], help=argparse.SUPPRESS)
    parser.add_argument("--config", help=argparse.SUPPRESS)
    parser.add_argument("--instance", help=argparse.SUPPRESS)
    parser.add_argument("--index", type=int, default=0, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.role == "sender":
        return run_sender(args.config, args.instance, args.rate, args.flood_s, args.garbage, args.seed, args.index)
    if args.role == "monitor":
        return run_monitor(args.config, args.instance, args.seed)

    done = run_guarded(lambda report: run(args, report))  # Ctrl-C or SIGTERM: eca up, helpers and files go
    report, host, wall_s = done.report, done.host, done.wall_s
    header = done.header("reliability")
    said = report.details.get("up_events_whole_run", {}).get("notable_lines", [])
    report.print_table(header, sys.stderr if args.json else sys.stdout,
                       [line for line in said if "no audio output" not in line], "eca up said (restarts, errors):")
    if args.json:
        print(json.dumps({
            "bench": "reliability", "machine": host, "wall_s": round(wall_s, 1),
            "options": {k: v for k, v in vars(args).items() if k not in ("role", "config", "instance", "index")},
            **report.as_json(),
        }, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
