"""Conversations per machine: how many visitors, each in a conversation of its own that talks and listens in turn,
one machine carries with every voice and face whole; and what each added conversation costs the server.

Starts `eca up --web --per-visitor --face head --web-draw browser --silent-audio --web-port 0` on a private
instance (a copy of the default config with its own runtime directory, as the tests make; services dialogue,
gaze, audio and web, no renderer) and brings N synthetic visitors to it in steps (`--steps`, default 0, 1, 2,
3, 5, 10, 20, ..., 60: fine where a loaded 2-core machine gives out, coarse up to the shipped limit). The
visitors are aiortc pages in `--client-procs` helper processes of their own (bench/_conversation_clients.py;
each its own process group, killed afterwards), never in this process, which only measures and speaks for the
agents. Each visitor does what the product page does: `POST /conversation` (an agent of its own and a key),
then an offer with its microphone's section first and, for its agent, the voice only, `draw_here` and the
"eca-face" data channel on which the server sends the face frames at the asked rate (`--fps`, 30 as the page
asks by default) and the voice clocks.

Every conversation is spoken to and speaks, in turn, on a cycle of `--cycle-s` shifted by a phase of its own
(seeded): at 0 the visitor's microphone says a sentence (espeak-ng, made once; pre-encoded to Opus and sent in
real time; digital silence otherwise, sent as a browser's Opus encoder sends it when the server's answer asks
`usedtx=1`: one packet every 400 ms), which the server's voice-activity detector turns into the user's turn
(`user_speech` on the bus); `--agent-gap-s` after the sentence this process makes the agent speak (a `Say` with
`--agent-s` of a synthetic voice, 24 kHz PCM inline, published on the bus as a dialogue manager would), which
the audio service plays and the web service sends as the visitor's Opus voice track.

Per step, after `--settle-s`, a window of `--hold-s`:
- the server (the `eca up` process tree: supervisor, broker, dialogue, gaze, audio, web; /proc/PID/stat utime +
  stime; smaps_rollup PSS and RSS at the window's end): CPU as a share of one core, memory;
- the clients: their processes' CPU; per visitor, from every RTP packet as it arrived (nothing decoded: libopus
  codes a 20 ms frame of digital silence in 3 bytes, any sound in tens or hundreds, so the payload's size says
  whether the voice sounds; a voice to a page that draws the face pauses in silence, its RTP timestamps jumping
  over the frames not sent, so all of it is judged on the RTP clock): no packet arrives more than `--gap-ms`
  later than its RTP time says, their RTP timestamps run on in whole frames and none is lost; each of the
  agent's turns arrives whole (one sounding run as long as what was said, within 3 packets, with no silent or
  missing frame inside it) and every turn said early enough in the window arrived; each of the user's turns was
  heard (a `user_speech` start on the bus for that agent); the face frames arrive at the asked rate within 10 %;
  the connection stays up. The helper's event-loop lag is shown beside (a late client loop delays what it
  receives);
- the supervisor's restarts, the web service's viewers closed, speech interrupted or failed, and every
  service's longest heartbeat silence;
- the web service's own count (GET /health's `voice`, before and after the window) of the voice frames it handed
  over more than 20 and 60 ms after their time: a gap the visitor saw that the server counted too is the server's.
The server's voice path (broker, audio, web) runs at real-time priority where the system allows it ([realtime] in
eca/configs/default.toml; each service says so as it starts, and the report shows it). The visitors stand for
browsers on other machines; here they share the server's two cores, where an ordinary-priority visitor would starve
behind a real-time server (its loop stalled, every gap its own), so they run at the server's priority
(`--ordinary-visitors` keeps them ordinary).
A step passes when all of it holds for every visitor; the figure is the largest N that passed. The server's
CPU and memory per added conversation are the slopes of a line fitted over the passing steps (N = 0, the
baseline, measured in the same run, among them; over every step measured when fewer than two passed: a
starved server's CPU then reads low), and beside them the slope from N = 1 on (the first conversation also
starts the face frames' loop). The machine's load (`uptime`) before and after, and the
machine's whole CPU busy share in each window (other work on a shared machine shows there).

Then the same with the faces drawn by the server (`--web-draw server`): each visitor an offer with a video and an
audio section and no `draw_here`; its pictures counted as they arrive (a marker bit ends each), not decoded.
Its steps are `--server-steps` (default 0, 1, 2, 3, 4): each conversation there is a face drawn with GL and
encoded to VP8 for it alone. A path stops after `--stop-after` failed steps in a row.

Limits the bench changes in its private config, said in the report: the shipped `[web] max_viewers` (16) refuses
the 17th page whatever `[conversations] max` says, so the bench raises it to `--max-viewers` (64); `0` keeps the
shipped one. `[conversations] max` stays the shipped 60 unless `--max-conversations` is given; when the last step
reaches it, one visitor more is sent to see it told busy. When all visitors have left, the bench checks that
every conversation is removed and how much memory the server gives back.

Figures are printed one per line against their target (met / MISSED / info); the bench always exits 0, it is a
measurement. Progress goes to stderr. With --json the table goes to stderr and one JSON object to stdout, as the
last line.

    python bench/conversations.py [--paths browser,server] [--steps 0,1,2,3,5,10,20,30,40,50,60]
                                  [--server-steps 0,1,2,3,4] [--hold-s 20] [--settle-s 5] [--fps 30]
                                  [--client-procs 2] [--cycle-s 8] [--agent-s 2.5] [--gap-ms 60]
                                  [--max-viewers 64] [--max-conversations N] [--stop-after 2] [--web-workers 1]
                                  [--ordinary-visitors]
                                  [--seed 0] [--json]

With `--web-workers K` (K > 1) the instance runs K web worker processes (`eca up --web-workers K`, docs/web.md) and
the visitors come to a real HAProxy in front of them (the shipped eca/configs/haproxy.cfg, as tests/support/haproxy.py
renders it), whose CPU and memory count as the server's.

A run takes up to about 9 minutes on 2 cores when every step passes (each eca start 10-20 s; per step the
visitors' arrival, the settle and the hold); where steps fail a path stops early (3-4 minutes in all on a
loaded machine). `--hold-s 10 --settle-s 3` roughly halves it.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from bench.procs import MEMORY_KINDS, descendants, eca_label, memory_kib, proc_table  # noqa: E402
from bench.report import Report, run_guarded  # noqa: E402
from eca.services.tools.child_processes import LineReader, eca_command, subprocess_env  # noqa: E402

READY_TIMEOUT_S = 90.0
HELPER = Path(__file__).resolve().parent / "_conversation_clients.py"
USER_SENTENCE = "Hello, what will the weather be like tomorrow?"
AGENT_RATE = 24_000  # the agent's voice, as a TTS hands it over (pipecat's default output rate)
AGENT_LEVEL = 0.3
SILENCE_BYTES = 8  # an Opus payload this small is digital silence (libopus: 3 bytes a 20 ms frame)
SPLIT_PACKETS = 15  # 300 ms of silence ends a sounding run
TURN_SLACK_PACKETS = 3  # a whole agent turn sounds at least its length less this many packets
FPS_TOLERANCE = 0.10
ADD_TIMEOUT_S = 240.0
SHIPPED_MAX_VIEWERS = 16
TARGET_N = 50
TARGET_CPU_PCT = 2.0
TARGET_MB = 30.0
MIB = 1024 * 1024


def progress(line: str) -> None:
    print(f"[conversations] {line}", file=sys.stderr, flush=True)


# --- /proc ------------------------------------------------------------------------------------------------


def machine_busy() -> tuple[int, int]:
    """(busy, total) jiffies of the whole machine, from /proc/stat."""
    values = [int(x) for x in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    idle = values[3] + (values[4] if len(values) > 4 else 0)
    total = sum(values[:8])
    return total - idle, total


def uptime() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True, timeout=5).stdout.strip()
    except (OSError, subprocess.TimeoutExpired):
        return "load average: " + ", ".join(f"{x:.2f}" for x in os.getloadavg())


# --- what is said ---------------------------------------------------------------------------------------------


def user_sentence(folder: Path) -> tuple[Path, float]:
    """The user's sentence, spoken by espeak-ng once: its WAV and length."""
    import soundfile as sf

    wav = folder / "user.wav"
    subprocess.run(["espeak-ng", "-w", str(wav), USER_SENTENCE], check=True, capture_output=True)
    info = sf.info(str(wav))
    return wav, info.frames / info.samplerate


def agent_voice(seconds: float, rng: random.Random) -> bytes:
    """A synthetic voice that sounds throughout (every 20 ms of it is far from digital silence): harmonics of a
    140 Hz voice with a slow vibrato, its level moving by seeded syllables of 150-300 ms between 40 and 100 %."""
    n = round(seconds * AGENT_RATE)
    t = np.arange(n) / AGENT_RATE
    f0 = 140.0 * (1 + 0.03 * np.sin(2 * np.pi * 5.0 * t))
    phase = 2 * np.pi * np.cumsum(f0) / AGENT_RATE
    wave = sum(np.sin(k * phase) / k for k in range(1, 8))
    envelope = np.empty(n)
    at = 0
    while at < n:
        length = round(rng.uniform(0.15, 0.30) * AGENT_RATE)
        level = rng.uniform(0.4, 1.0)
        envelope[at:at + length] = level
        at += length
    smooth = round(0.03 * AGENT_RATE)
    envelope = np.convolve(envelope, np.ones(smooth) / smooth, mode="same")
    fade = np.minimum(1.0, np.minimum(np.arange(n), np.arange(n)[::-1]) / (0.01 * AGENT_RATE) + 0.2)
    signal_ = wave / np.abs(wave).max() * envelope * fade * AGENT_LEVEL
    pcm: bytes = (signal_ * 32767).astype("<i2").tobytes()
    return pcm


# --- the bus: the agents' turns and what the services say -------------------------------------------------------


@dataclass
class BusLog:
    says: list[tuple[float, str]] = field(default_factory=list)  # (sent, agent)
    user_turns: list[tuple[float, str, bool]] = field(default_factory=list)  # (received, agent, speaking)
    speech: list[tuple[float, str, str, str]] = field(default_factory=list)  # (received, agent, type, detail)
    errors: list[tuple[float, str, str]] = field(default_factory=list)
    created: list[tuple[float, int]] = field(default_factory=list)  # the agents list: (received, created count)
    beats: dict[str, float] = field(default_factory=dict)  # service -> last heartbeat
    silences: list[tuple[float, str, float]] = field(default_factory=list)  # (ended, service, seconds) over 0.5 s


class Driver:
    """A thread with the bus: speaks for every agent on its cycle (`Say`) and notes the user's turns, the agents'
    speech events, errors, the agents list and heartbeats."""

    SPEECH = ("speech_started", "speech_finished", "speech_interrupted", "speech_failed")

    def __init__(self, config: Any, pcm: bytes, epoch: float, cycle_s: float, agent_at_s: float) -> None:
        self.config, self.pcm = config, pcm
        self.epoch, self.cycle_s, self.agent_at_s = epoch, cycle_s, agent_at_s
        self.log = BusLog()
        self.lock = threading.Lock()
        self._next: dict[str, float] = {}  # agent -> when its next turn is said
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True, name="bus-driver")
        self.failure: str | None = None

    def add(self, agent: str, phase_s: float) -> None:
        now = time.monotonic()
        first = self.epoch + phase_s + self.agent_at_s
        first += math.ceil(max(0.0, now + 0.5 - first) / self.cycle_s) * self.cycle_s
        with self.lock:
            self._next[agent] = first

    def drop_all(self) -> None:
        with self.lock:
            self._next.clear()

    def __enter__(self) -> Driver:
        self._thread.start()
        if not self._ready.wait(20.0):
            raise RuntimeError(f"the bench's bus driver did not start: {self.failure}")
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=10)

    def _run(self) -> None:
        import zmq

        from eca.protocol.bus import Publisher, Subscriber
        from eca.protocol.messages import AgentsState, Error, Heartbeat, Say

        ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
        pub = Publisher(ctx, self.config, "bench-conversations")
        sub = Subscriber(ctx, self.config, ["event.", "state.*.agents", "error.", "sys."])
        count = 0
        try:
            pub.wait_ready(10.0)
            sub.wait_ready(10.0)
            self._ready.set()
            while not self._stop.is_set():
                now = time.monotonic()
                with self.lock:
                    due = [a for a, t in self._next.items() if t <= now]
                    for agent in due:
                        self._next[agent] += self.cycle_s
                    upcoming = min(self._next.values(), default=now + 0.05)
                for agent in due:
                    count += 1
                    pub.publish(Say(agent=agent, request_id=f"bench-{count}", pcm=self.pcm, sample_rate=AGENT_RATE,
                                    to=["user"]))
                    with self.lock:
                        self.log.says.append((time.monotonic(), agent))
                timeout_ms = max(0, min(50, int((upcoming - time.monotonic()) * 1000)))
                if not sub.socket.poll(timeout_ms):
                    continue
                for frames in sub.read_frames(2000):
                    topic = frames[0].decode("ascii", "replace")
                    kind = topic.rsplit(".", 1)[-1]
                    if topic.startswith("event.") and kind not in self.SPEECH and kind != "user_speech":
                        continue  # saccades, nods, acks: not decoded
                    got = sub.accept(frames)
                    msg = got.message if got is not None else None
                    if msg is None:
                        continue
                    at = time.monotonic()
                    with self.lock:
                        if kind == "user_speech":
                            self.log.user_turns.append((at, msg.agent, bool(getattr(msg, "speaking", False))))
                        elif kind in self.SPEECH:
                            detail = getattr(msg, "reason", "") or f"{getattr(msg, 'played_s', 0.0):.2f}"
                            self.log.speech.append((at, msg.agent, kind, detail))
                        elif isinstance(msg, AgentsState):
                            self.log.created.append((at, len(msg.created)))
                        elif isinstance(msg, Error):
                            self.log.errors.append((at, msg.agent, f"{msg.kind}: {msg.reason}"[:200]))
                        elif isinstance(msg, Heartbeat):
                            last = self.log.beats.get(msg.service)
                            if last is not None and at - last > 0.5:
                                self.log.silences.append((at, msg.service, at - last))
                            self.log.beats[msg.service] = at
        except Exception as exc:  # said in the report: the bench's own failure
            self.failure = f"{type(exc).__name__}: {exc}"
        finally:
            pub.close()
            sub.close()
            ctx.term()


# --- the helpers (bench/_conversation_clients.py) --------------------------------------------------------------


@dataclass
class Helper:
    proc: subprocess.Popen[bytes]
    reader: LineReader
    scheduling: str = ""  # what it said of real-time scheduling in its hello

    def ask(self, cmd: dict[str, Any], timeout_s: float) -> dict[str, Any]:
        assert self.proc.stdin is not None
        start = len(self.reader.lines)
        self.proc.stdin.write((json.dumps(cmd) + "\n").encode())
        self.proc.stdin.flush()
        deadline = time.monotonic() + timeout_s
        while True:
            index = self.reader.wait_for('"op": ', max(0.1, deadline - time.monotonic()), start)
            line = self.reader.lines[index]
            start = index + 1
            try:
                got = json.loads(line)
            except json.JSONDecodeError:
                continue  # a line aiortc or a library printed
            if isinstance(got, dict) and got.get("op") == cmd["op"]:
                return dict(got)

    def cpu_s(self) -> float:
        table = proc_table()
        return sum(table[p].own_ticks for p in descendants(self.proc.pid, table)) / os.sysconf("SC_CLK_TCK")


@contextmanager
def helpers(count: int, url: str, draw: str, wav: Path, epoch: float, args: argparse.Namespace,
            realtime_priority: int = 0) -> Iterator[list[Helper]]:
    """`count` helper processes, each its own process group, killed (the group) afterwards; at SCHED_RR
    `realtime_priority` where that is not 0 (and the system allows it: each says in its hello)."""
    started: list[Helper] = []
    try:
        for _ in range(count):
            argv = [sys.executable, str(HELPER), "--url", url, "--draw", draw, "--mic", str(wav),
                    "--epoch-ns", str(int(epoch * 1e9)), "--cycle-s", str(args.cycle_s), "--user-at-s", "0",
                    "--fps", str(args.fps), "--width", str(args.width), "--height", str(args.height),
                    "--realtime-priority", str(realtime_priority)]
            proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                    env=subprocess_env(), cwd=REPO, start_new_session=True)
            started.append(Helper(proc, LineReader(proc.stdout)))
        for h in started:
            h.scheduling = str(h.ask({"op": "hello"}, 60.0).get("scheduling") or "the ordinary priority")
        yield started
    finally:
        for h in started:
            try:
                assert h.proc.stdin is not None
                h.proc.stdin.close()  # it closes its visitors and exits
                h.proc.wait(timeout=10)
            except (OSError, subprocess.TimeoutExpired):
                pass
            try:
                os.killpg(h.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            h.proc.wait(timeout=5)


# --- the instance ----------------------------------------------------------------------------------------------


@dataclass
class Instance:
    config: Any
    proc: subprocess.Popen[bytes]
    reader: LineReader
    url: str
    web_pid: int
    max_conversations: int
    max_viewers: int
    balancer_pid: int | None = None  # with several web workers: the HAProxy in front of them (counted as server)
    worker_urls: tuple[str, ...] = ()  # each web worker's own address (its GET /health)
    scheduling: dict[str, str] = field(default_factory=dict)  # service -> what it said of real-time scheduling
    realtime_priority: int = 0  # the SCHED_RR priority the server's voice path runs at (0: the ordinary priority)


@contextmanager
def eca_up(draw: str, args: argparse.Namespace) -> Iterator[Instance]:
    from tests.support.bus import private_bus_config, running

    extra = (f"[heartbeat]\ninterval_s = 0.25\ntimeout_s = {args.heartbeat_timeout_s}\n"
             if args.heartbeat_timeout_s else "")
    with private_bus_config(services=["dialogue", "gaze", "audio"], extra=extra) as config:
        text = config.config_path.read_text()
        shipped = re.search(r"^\[conversations\][^\[]*?^max = (\d+)", text, re.MULTILINE | re.DOTALL)
        assert shipped, "the config has a [conversations] max"
        max_conversations = int(shipped.group(1))
        if args.max_conversations is not None:
            text = re.sub(r"^(\[conversations\][^\[]*?^max = )\d+", rf"\g<1>{args.max_conversations}", text, count=1,
                          flags=re.MULTILINE | re.DOTALL)
            max_conversations = args.max_conversations
        viewers = re.search(r"^max_viewers = (\d+)", text, re.MULTILINE)
        assert viewers, "the config has a [web] max_viewers"
        max_viewers = int(viewers.group(1))
        if args.max_viewers:
            text = re.sub(r"^max_viewers = \d+", f"max_viewers = {args.max_viewers}", text, count=1,
                          flags=re.MULTILINE)
            max_viewers = args.max_viewers
        config.config_path.write_text(text)
        workers = args.web_workers
        if workers > 1:
            from tests.support.haproxy import free_ports

            port = free_ports(workers)
        else:
            port = 0
        argv = eca_command("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet",
                           "--web", "--web-port", str(port), "--per-visitor", "--face", "head", "--web-draw", draw,
                           "--silent-audio", *(["--web-workers", str(workers)] if workers > 1 else []))
        progress(f"starting eca up --web --per-visitor --face head --web-draw {draw} --silent-audio"
                 f"{f' --web-workers {workers} (behind HAProxy)' if workers > 1 else ''} "
                 f"(instance {config.instance}; [conversations] max {max_conversations}, [web] max_viewers "
                 f"{max_viewers})")
        with running(argv, stop_timeout_s=15.0) as (proc, reader), ExitStack() as stack:
            try:
                reader.wait_for("[up] ready in", READY_TIMEOUT_S)
                lines = [reader.lines[reader.wait_for(f"[{name}] INFO serving http://", 20.0)]
                         for name in ["web", *(f"web-{i}" for i in range(2, workers + 1))]]
                ready = reader.lines[reader.wait_for("[web] INFO ready (pid", 20.0)]
            except TimeoutError:
                said = [x for x in reader.lines if re.search(r"ERROR|Error|not restarted", x)]
                raise RuntimeError(f"eca up was not ready within {READY_TIMEOUT_S:g} s: "
                                   f"{' | '.join(said[-3:]) or 'no error printed'}") from None
            urls = [m.group(1) for line in lines if (m := re.search(r"(http://\S+/)", line))]
            # [realtime] (eca/configs/default.toml): each service on the voice's path says how it runs, before ready
            scheduling = {m.group(1): m.group(2) for line in reader.lines
                          if (m := re.match(r"\[([\w-]+)\] INFO (real-time scheduling.*)", line))}
            granted = [int(m.group(1)) for said in scheduling.values() if (m := re.search(r": SCHED_RR (\d+)$", said))]
            priority = min(granted) if granted and len(granted) == len(scheduling) else 0
            pid = re.search(r"ready \(pid (\d+)\)", ready)
            assert len(urls) == workers and pid is not None
            balancer_pid = None
            url = urls[0]
            if workers > 1:  # visitors come to HAProxy, which spreads them over the workers (docs/web.md)
                from tests.support.haproxy import balancer

                servers = [(f"w{i}", u.removeprefix("http://").rstrip("/")) for i, u in enumerate(urls, 1)]
                lb = stack.enter_context(balancer(servers, check_inter_ms=1000))
                url, balancer_pid = lb.url, lb.process.pid
            yield Instance(config, proc, reader, url, int(pid.group(1)), max_conversations, max_viewers,
                           balancer_pid, tuple(urls), scheduling, priority)


def post_conversation(url: str) -> tuple[int, Any]:
    import urllib.error
    import urllib.request

    request = urllib.request.Request(url + "conversation", data=b"{}", headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(request, timeout=20) as response:
            return response.status, json.loads(response.read())
    except urllib.error.HTTPError as exc:
        body = exc.read()
        try:
            return exc.code, json.loads(body)
        except json.JSONDecodeError:
            return exc.code, body.decode("utf-8", "replace")


def server_voice_timing(inst: Instance) -> dict[str, float]:
    """How late the web workers have handed their voice frames over so far (GET /health's `voice`, summed over the
    workers; the latest is the largest)."""
    import urllib.error
    import urllib.request

    total = {"frames": 0.0, "late_20ms": 0.0, "late_60ms": 0.0, "max_late_ms": 0.0}
    for url in inst.worker_urls:
        try:
            with urllib.request.urlopen(url + "health", timeout=10) as response:
                voice = json.loads(response.read())["voice"]
        except urllib.error.HTTPError as exc:  # 503: full or not ready, the same JSON
            voice = json.loads(exc.read())["voice"]
        for key in ("frames", "late_20ms", "late_60ms"):
            total[key] += voice[key]
        total["max_late_ms"] = max(total["max_late_ms"], voice["max_late_ms"])
    return total


# --- one step ---------------------------------------------------------------------------------------------------


@dataclass
class Step:
    n: int
    connected: int = 0
    failed: list[dict[str, Any]] = field(default_factory=list)
    server_cpu_pct: float = 0.0
    server_cpu_by: dict[str, float] = field(default_factory=dict)
    pss_mb: float = 0.0
    rss_mb: float = 0.0
    mem_by: dict[str, float] = field(default_factory=dict)
    client_cpu_pct: float = 0.0
    machine_busy_pct: float = 0.0
    bench_cpu_pct: float = 0.0
    load: list[float] = field(default_factory=list)
    problems: dict[str, int] = field(default_factory=dict)  # what failed, visitors (or events) each
    examples: dict[str, str] = field(default_factory=dict)
    rates: list[float] = field(default_factory=list)
    max_voice_gap_ms: float = 0.0
    voice_gaps: int = 0
    voice_gaps_client_stalled: int = 0  # of them, while the client's own loop stalled as long
    max_gap_client_on_time_ms: float = 0.0  # the longest gap while the client's loop ran on time
    agent_turns: tuple[int, int] = (0, 0)  # (whole, said early enough to be judged)
    user_turns: tuple[int, int] = (0, 0)  # (heard, expected at least)
    loop_lag_ms: float = 0.0
    # the web service's own count over the window: voice frames it handed over more than 20 / 60 ms after their time
    server_voice: dict[str, float] = field(default_factory=dict)
    connect_s: float = 0.0
    passed: bool = False

    def problem(self, what: str, example: str) -> None:
        self.problems[what] = self.problems.get(what, 0) + 1
        self.examples.setdefault(what, example)


def server_sample(inst: Instance) -> tuple[dict[str, float], dict[str, dict[str, int]]]:
    """CPU seconds and memory of each process of the instance, by label."""
    table = proc_table()
    ticks = os.sysconf("SC_CLK_TCK")
    cpu, mem = {}, {}
    pids = descendants(inst.proc.pid, table)
    if inst.balancer_pid is not None and inst.balancer_pid in table:
        pids = [*pids, *descendants(inst.balancer_pid, table)]
    for pid in pids:
        label = "haproxy" if pid == inst.balancer_pid else eca_label(pid, inst.proc.pid)
        key = label if label not in cpu else f"{label}-{pid}"
        cpu[key] = table[pid].own_ticks / ticks
        mem[key] = memory_kib(pid) or dict.fromkeys(MEMORY_KINDS, 0)
    return cpu, mem


def expected_starts(epoch: float, phase_s: float, cycle_s: float, offset_s: float, lo: float, hi: float) -> int:
    """How many of a conversation's cycle instants (epoch + phase + offset + k cycle) fall within [lo, hi]."""
    base = epoch + phase_s + offset_s
    first = math.ceil((lo - base) / cycle_s)
    last = math.floor((hi - base) / cycle_s)
    return max(0, last - first + 1)


def measure(step: Step, inst: Instance, hs: list[Helper], driver: Driver, visitors: dict[int, dict[str, Any]],
            args: argparse.Namespace, user_s: float, restarts_before: int) -> None:
    """The window of one step: the server's and the clients' CPU and memory, and every visitor's voice and face."""
    cpu0, _ = server_sample(inst)
    voice0 = server_voice_timing(inst)
    helpers0 = [h.cpu_s() for h in hs]
    busy0 = machine_busy()
    bench0 = os.times()
    t0 = time.monotonic()
    mem_samples: list[dict[str, dict[str, int]]] = []
    while time.monotonic() < t0 + args.hold_s:
        time.sleep(min(5.0, t0 + args.hold_s - time.monotonic()))  # the window's length, sampling memory
        mem_samples.append(server_sample(inst)[1])
    t1 = time.monotonic()
    cpu1, mem1 = server_sample(inst)
    voice1 = server_voice_timing(inst)
    helpers1 = [h.cpu_s() for h in hs]
    busy1 = machine_busy()
    bench1 = os.times()
    span = t1 - t0
    step.server_voice = {key: voice1[key] - voice0[key] for key in ("frames", "late_20ms", "late_60ms")}
    step.server_voice["max_late_ms_so_far"] = voice1["max_late_ms"]
    step.server_cpu_by = {k: round(100 * (cpu1[k] - cpu0[k]) / span, 1) for k in cpu1 if k in cpu0}
    step.server_cpu_pct = round(sum(step.server_cpu_by.values()), 1)
    step.pss_mb = round(sum(m["pss"] for m in mem1.values()) / 1024, 1)
    step.rss_mb = round(sum(m["rss"] for m in mem1.values()) / 1024, 1)
    step.mem_by = {k: round(m["pss"] / 1024, 1) for k, m in mem1.items()}
    step.client_cpu_pct = round(100 * (sum(helpers1) - sum(helpers0)) / span, 1)
    step.machine_busy_pct = round(100 * (busy1[0] - busy0[0]) / max(1, busy1[1] - busy0[1]) * (os.cpu_count() or 1),
                                  1)
    step.bench_cpu_pct = round(100 * (bench1.user + bench1.system - bench0.user - bench0.system) / span, 1)
    step.load = [round(x, 2) for x in os.getloadavg()]
    restarts = [x for x in inst.reader.lines if "restarting in" in x or "not restarted" in x]
    if len(restarts) > restarts_before:
        step.problem("a service restarted", restarts[restarts_before][:160])
    if inst.proc.poll() is not None:
        step.problem("eca up exited", f"exit status {inst.proc.returncode}")

    windows = [h.ask({"op": "window", "t0": t0, "t1": t1, "gap_ms": args.gap_ms, "silence_bytes": SILENCE_BYTES,
                      "split_packets": SPLIT_PACKETS}, 60.0) for h in hs]
    step.loop_lag_ms = max((w.get("loop_lag", {}).get("max_ms", 0.0) for w in windows), default=0.0)
    rows = [row for w in windows for row in w["visitors"]]
    with driver.lock:
        says = list(driver.log.says)
        user_turns = list(driver.log.user_turns)
        speech = list(driver.log.speech)
        silences = [s for s in driver.log.silences if t0 <= s[0] <= t1 + 1.0]
    turn_packets = round(args.agent_s / 0.02) - TURN_SLACK_PACKETS
    whole_turns = judged_turns = heard = expected_min = 0
    rate = args.fps
    for row in rows:
        agent = row["agent"]
        where = f"visitor {row['index']} ({agent})"
        if row["state"] != "connected" or row["ended_at"] is not None:
            step.problem("connection lost", f"{where}: {row['state']}")
        voice = row["voice"]
        step.max_voice_gap_ms = max(step.max_voice_gap_ms, voice["max_gap_ms"])
        if args.draw == "server" and voice["packets"] < 0.9 * span / 0.02:
            # a voice that never pauses in silence (to a page that shows video) sends a packet every 20 ms; one
            # that pauses is judged by its turns below
            step.problem("voice packets missing", f"{where}: {voice['packets']} in {span:.1f} s")
        step.voice_gaps += voice["gaps"]
        step.voice_gaps_client_stalled += voice["gaps_client_stalled"]
        step.max_gap_client_on_time_ms = max(step.max_gap_client_on_time_ms, voice["max_gap_client_on_time_ms"])
        if voice["gaps"]:
            step.problem(f"voice gap over {args.gap_ms:g} ms", f"{where}: {voice['gaps']} gaps ("
                         f"{voice['gaps_client_stalled']} while its client's loop stalled), longest "
                         f"{voice['max_gap_ms']} ms")
        if voice["ts_jumps"] or voice["lost"]:
            step.problem("voice timestamps jump or packets lost", f"{where}: {voice['ts_jumps']} jumps, "
                                                                   f"{voice['lost']} lost")
        runs = voice["runs"]
        for run in runs:
            if run["holes"] or run["sounding"] < turn_packets:
                step.problem("agent turn not whole", f"{where}: {run['sounding']} sounding packets "
                                                      f"(of {turn_packets + TURN_SLACK_PACKETS}), {run['holes']} "
                                                      "silent inside")
        whole = sum(1 for r in runs if not r["holes"] and r["sounding"] >= turn_packets)
        said = sum(1 for t, a in says if a == agent and t0 + 0.5 <= t <= t1 - args.agent_s - 1.5)
        whole_turns += min(whole, said)
        judged_turns += said
        if whole < said:
            step.problem("agent turn missing", f"{where}: {whole} whole of {said} said")
        phase = visitors[row["index"]]["phase_s"]
        lo = expected_starts(driver.epoch, phase, args.cycle_s, 0.0, t0, t1 - 1.2)
        hi = expected_starts(driver.epoch, phase, args.cycle_s, 0.0, t0 - 1.0, t1)
        got = sum(1 for t, a, speaking in user_turns if a == agent and speaking and t0 <= t <= t1)
        heard += got
        expected_min += lo
        if not lo <= got <= hi:
            step.problem("user turn not heard as one", f"{where}: {got} turn starts heard, {lo}..{hi} spoken")
        if args.draw == "browser":
            fps = row["face"]["fps"]
            if abs(fps - rate) > FPS_TOLERANCE * rate:
                step.problem("face frame rate off", f"{where}: {fps:.1f} fps of {rate:g}")
        else:
            fps = row["video"]["fps"]
            if abs(fps - rate) > FPS_TOLERANCE * rate:
                step.problem("video frame rate off", f"{where}: {fps:.1f} fps of {rate:g}")
        step.rates.append(fps)
    step.agent_turns = (whole_turns, judged_turns)
    step.user_turns = (heard, expected_min)
    agents = {row["agent"] for row in rows}
    for t, agent, kind, detail in speech:
        if t0 <= t <= t1 and agent in agents and kind in ("speech_interrupted", "speech_failed"):
            step.problem(kind.replace("_", " "), f"{agent}: {detail}")
    for _, service, seconds in silences:
        if seconds > 1.0:
            step.problem("a service silent over 1 s", f"{service}: {seconds:.1f} s")
    if len(rows) != step.n:
        step.problem("visitors missing", f"{len(rows)} of {step.n} connected")
    step.passed = not step.problems


def run_path(draw: str, steps: list[int], args: argparse.Namespace, report: Report, wav: Path, user_s: float,
             pcm: bytes) -> None:
    label = "browser-drawn" if draw == "browser" else "server-drawn"
    details: dict[str, Any] = {"steps": []}
    report.details[label] = details
    rng = random.Random(f"{args.seed}-{draw}")
    agent_at_s = user_s + args.agent_gap_s
    with eca_up(draw, args) as inst, ExitStack() as stack:
        epoch = time.monotonic()
        driver = stack.enter_context(Driver(inst.config, pcm, epoch, args.cycle_s, agent_at_s))
        # The visitors stand for browsers on other machines. Here they share the server's cores, and at the ordinary
        # priority a server whose voice path runs real-time would starve them (their loops stalled, the gaps theirs):
        # they run at its priority, unless --ordinary-visitors.
        visitor_priority = 0 if args.ordinary_visitors else inst.realtime_priority
        hs = stack.enter_context(helpers(args.client_procs, inst.url, draw, wav, epoch, args, visitor_priority))
        details.update({"max_conversations": inst.max_conversations, "max_viewers": inst.max_viewers,
                        "url": inst.url, "web_workers": args.web_workers,
                        "scheduling": {"server": inst.scheduling, "visitors": sorted({h.scheduling for h in hs})}})

        def said(line: str) -> str:
            return line.removeprefix("real-time scheduling").lstrip(": ")

        report.add(f"{label}: scheduling",
                   f"SCHED_RR {inst.realtime_priority}" if inst.realtime_priority else "ordinary", "-", None, "",
                   "the server's voice path ([realtime]): " + (", ".join(f"{k} {said(v)}"
                                                                 for k, v in sorted(inst.scheduling.items()))
                                                       or "nothing said (no [realtime] services)")
                   + f"; the visitors: {', '.join(sorted({said(h.scheduling) for h in hs}))}")
        visitors: dict[int, dict[str, Any]] = {}
        done: list[Step] = []
        failed_in_a_row = 0
        for n in steps:
            step = Step(n)
            if n > inst.max_conversations:
                progress(f"{label}: N={n} is over [conversations] max {inst.max_conversations}; not measured")
                break
            new: list[dict[str, Any]] = [{"index": i, "phase_s": round(rng.uniform(0, args.cycle_s), 3)}
                                         for i in range(len(visitors), n)]
            t_add = time.monotonic()
            if new:
                progress(f"{label}: {len(new)} visitors arrive (to N={n})")
                by_helper: dict[int, list[dict[str, Any]]] = {}
                for spec in new:
                    by_helper.setdefault(spec["index"] % len(hs), []).append(spec)
                answers: dict[int, dict[str, Any]] = {}

                def add(k: int, specs: list[dict[str, Any]], answers: dict[int, dict[str, Any]] = answers) -> None:
                    answers[k] = hs[k].ask({"op": "add", "visitors": specs}, ADD_TIMEOUT_S)

                threads = [threading.Thread(target=add, args=(k, specs)) for k, specs in by_helper.items()]
                for th in threads:
                    th.start()
                for th in threads:
                    th.join()
                for k in by_helper:
                    answer = answers.get(k, {"added": [], "failed": [{"error": "the helper did not answer"}]})
                    step.failed.extend(answer["failed"])
                    for got in answer["added"]:
                        spec = next(s for s in new if s["index"] == got["index"])
                        visitors[got["index"]] = {**spec, "agent": got["agent"], "connect_s": got["connect_s"]}
                        driver.add(got["agent"], spec["phase_s"])
                if step.failed:
                    progress(f"{label}: {len(step.failed)} visitors refused or failed: {step.failed[0]}")
            step.connected = len(visitors)
            step.connect_s = round(time.monotonic() - t_add, 1)
            restarts_before = sum(1 for x in inst.reader.lines if "restarting in" in x or "not restarted" in x)
            time.sleep(args.settle_s)  # past the arrival's own work and the first turns
            progress(f"{label}: N={n}: measuring {args.hold_s:g} s")
            measure(step, inst, hs, driver, visitors, argparse.Namespace(**{**vars(args), "draw": draw}), user_s,
                    restarts_before)
            for f in step.failed:
                step.problem("visitor refused or failed", f"{f.get('step')}: {f.get('status')} {f.get('error')}")
            step.passed = not step.problems
            done.append(step)
            details["steps"].append({k: v for k, v in step.__dict__.items() if k != "rates"}
                                    | {"face_fps_min": min(step.rates, default=None),
                                       "face_fps_median": float(np.median(step.rates)) if step.rates else None})
            progress(f"{label}: N={n}: {'ok' if step.passed else 'FAILED ' + ', '.join(step.problems)}; server "
                     f"{step.server_cpu_pct:.0f} % CPU, {step.pss_mb:.0f} MB PSS; clients {step.client_cpu_pct:.0f} %;"
                     f" machine busy {step.machine_busy_pct:.0f} % (of {100 * (os.cpu_count() or 1)})")
            failed_in_a_row = 0 if step.passed else failed_in_a_row + 1
            if failed_in_a_row >= args.stop_after:
                progress(f"{label}: {failed_in_a_row} failed steps in a row; stopping this path")
                break
        # one visitor more than the instance's conversations: told busy?
        beyond = None
        if done and done[-1].connected >= inst.max_conversations:
            beyond = post_conversation(inst.url)
            details["beyond_max"] = {"status": beyond[0], "answer": beyond[1]}
        # everyone leaves: every conversation removed, memory given back
        t_leave = time.monotonic()
        before_leave = server_sample(inst)[1]
        for h in hs:
            h.ask({"op": "close"}, 60.0)
        driver.drop_all()
        left_s = None
        deadline = t_leave + 40.0
        while time.monotonic() < deadline:
            with driver.lock:
                latest = driver.log.created[-1] if driver.log.created else None
            if latest is not None and latest[0] > t_leave and latest[1] == 0:
                left_s = latest[0] - t_leave
                break
            time.sleep(0.2)  # polling the agents list the driver keeps
        with driver.lock:
            remaining = driver.log.created[-1][1] if driver.log.created else None
        time.sleep(3.0)  # what the services give back once the conversations are gone
        after = server_sample(inst)[1]
        details["left"] = {"seconds": left_s, "remaining": remaining,
                           "pss_mb_before": round(sum(m["pss"] for m in before_leave.values()) / 1024, 1),
                           "pss_mb_after": round(sum(m["pss"] for m in after.values()) / 1024, 1)}
        said = [x for x in inst.reader.lines if re.search(r"ERROR|Traceback|restarting in|not restarted|exited", x)]
        details["up_said"] = said[-20:]
        details["tracebacks"] = tracebacks(inst.reader.lines)
        details["restarts"] = [x for x in inst.reader.lines if "restarting in" in x or "not restarted" in x]
        details["viewers_closed_silent"] = sum(1 for x in inst.reader.lines if "no answer for" in x)
        closing = [x for x in inst.reader.lines if "closing it" in x or "not connected after" in x]
        details["viewers_closed"] = {"count": len(closing), "lines": closing[:10]}
        details["bus_errors"] = [e for e in driver.log.errors][:20]
        if driver.failure:
            report.add(f"{label}: bus driver", "failed", "runs", False, "", driver.failure)
    figures(label, draw, done, details, inst_max=(inst.max_conversations, inst.max_viewers), report=report,
            beyond=beyond, args=args)


def tracebacks(lines: list[str], most: int = 6) -> list[dict[str, Any]]:
    """The distinct tracebacks the instance printed (by their last line), each whole and how often it came."""
    found: dict[str, dict[str, Any]] = {}
    for i, line in enumerate(lines):
        if "Traceback (most recent call last)" not in line:
            continue
        prefix = line.split("Traceback", 1)[0]
        block = [line]
        for nxt in lines[i + 1:i + 80]:
            if not nxt.startswith(prefix):
                continue  # another service's line in between
            block.append(nxt)
            if not nxt[len(prefix):].startswith(" "):
                break  # the exception's own line ends it
        key = block[-1]
        if key in found:
            found[key]["count"] += 1
        elif len(found) < most:
            found[key] = {"count": 1, "before": lines[i - 1] if i else "", "lines": block}
    return list(found.values())


def fit(points: list[tuple[float, float]]) -> tuple[float, float] | None:
    """Slope and intercept of the least-squares line."""
    xs = [p[0] for p in points]
    if len(set(xs)) < 2:
        return None
    slope, intercept = np.polyfit(np.asarray(xs, float), np.asarray([p[1] for p in points], float), 1)
    return float(slope), float(intercept)


def figures(label: str, draw: str, done: list[Step], details: dict[str, Any], inst_max: tuple[int, int],
            report: Report, beyond: tuple[int, Any] | None, args: argparse.Namespace) -> None:
    cores = os.cpu_count() or 1
    for s in done:
        fps = (f"face {min(s.rates):.1f}-{max(s.rates):.1f} fps" if draw == "browser" else
               f"video {min(s.rates):.1f}-{max(s.rates):.1f} fps") if s.rates else "no frames"
        note = (f"server {s.server_cpu_pct:.0f} % CPU, {s.pss_mb:.0f} MB PSS; clients {s.client_cpu_pct:.0f} %; "
                f"machine busy {s.machine_busy_pct:.0f}/{100 * cores} %, load {s.load[0]:g}; {fps}; agent turns "
                f"whole {s.agent_turns[0]}/{s.agent_turns[1]}; user turns heard {s.user_turns[0]} (>= "
                f"{s.user_turns[1]}); voice gaps {s.voice_gaps} ({s.voice_gaps_client_stalled} while the client "
                f"stalled), longest {s.max_voice_gap_ms:.0f} ms ({s.max_gap_client_on_time_ms:.0f} ms with the client "
                f"on time); client loop lag max {s.loop_lag_ms:.0f} ms")
        if s.server_voice.get("frames"):
            v = s.server_voice
            note += (f"; the server handed {v['late_20ms']:.0f} of {v['frames']:.0f} voice frames over more than 20 ms "
                     f"late, {v['late_60ms']:.0f} more than 60 ms")
        if s.problems:
            note += "; " + "; ".join(f"{k} x{v} (e.g. {s.examples[k]})" for k, v in s.problems.items())
        report.add(f"{label}: N={s.n}", "ok" if s.passed else "FAILED", "all hold", None, "", note)
    passed = [s for s in done if s.passed]
    best = max((s.n for s in passed), default=None)
    first_fail = next((s for s in done if not s.passed), None)
    limited = ("; ".join(f"{k} x{v}" for k, v in first_fail.problems.items()) if first_fail else
               "every step measured passed")
    if draw == "browser":
        report.add(f"{label}: largest N with every voice and face whole", best if best is not None else "none",
                   f">= {TARGET_N}", best is not None and best >= TARGET_N, "conversations",
                   f"first failing step N={first_fail.n}: {limited}" if first_fail else limited)
    else:
        report.add(f"{label}: largest N with every voice and face whole", best if best is not None else "none", "-",
                   None, "conversations",
                   f"first failing step N={first_fail.n}: {limited}" if first_fail else limited)
    basis = passed if len({s.n for s in passed}) >= 2 else done
    basis_note = "over the passing steps" if basis is passed else "over every step (fewer than 2 passed)"
    cpu = fit([(s.connected, s.server_cpu_pct) for s in basis])
    pss = fit([(s.connected, s.pss_mb) for s in basis])
    rss = fit([(s.connected, s.rss_mb) for s in basis])
    client = fit([(s.connected, s.client_cpu_pct) for s in basis])
    target_cpu = f"<= {TARGET_CPU_PCT:g} %" if draw == "browser" else "-"
    target_mb = f"<= {TARGET_MB:g} MB" if draw == "browser" else "-"
    if cpu is not None:
        report.add(f"{label}: server CPU per added conversation", round(cpu[0], 2), target_cpu,
                   cpu[0] <= TARGET_CPU_PCT if draw == "browser" else None, "% of a core",
                   f"line {basis_note}; at N=0 {cpu[1]:.1f} %")
        # the same line for each process: which one a conversation costs (and which grows faster than a line)
        names = sorted({k for s in basis for k in s.server_cpu_by})
        slopes = {k: f[0] for k in names if (f := fit([(s.connected, s.server_cpu_by.get(k, 0.0)) for s in basis]))}
        if slopes:
            ranked = sorted(slopes.items(), key=lambda kv: -kv[1])
            report.add(f"{label}: server CPU per added conversation, by process", round(ranked[0][1], 2), "-", None,
                       "% of a core", "the largest; " + ", ".join(f"{k} {v:.2f}" for k, v in ranked))
    if pss is not None:
        report.add(f"{label}: server PSS per added conversation", round(pss[0], 2), target_mb,
                   pss[0] <= TARGET_MB if draw == "browser" else None, "MB", f"line {basis_note}; at N=0 "
                                                                             f"{pss[1]:.0f} MB")
    if rss is not None:
        report.add(f"{label}: server RSS per added conversation", round(rss[0], 2), "-", None, "MB",
                   "shared pages counted once per process")
    later = [s for s in basis if s.n >= 1]
    marginal = fit([(s.connected, s.server_cpu_pct) for s in later])
    marginal_mb = fit([(s.connected, s.pss_mb) for s in later])
    if marginal is not None and marginal_mb is not None:
        report.add(f"{label}: server CPU per conversation after the first", round(marginal[0], 2), "-", None,
                   "% of a core", f"line over the steps from N=1 ({', '.join(str(s.n) for s in later)}); the first "
                   "also starts the face frames' loop")
        report.add(f"{label}: server PSS per conversation after the first", round(marginal_mb[0], 2), "-", None,
                   "MB", "the same steps")
    if client is not None:
        report.add(f"{label}: client CPU per added conversation", round(client[0], 2), "-", None, "% of a core",
                   f"the synthetic visitors ({args.client_procs} processes), on the same {cores} cores")
    top = next((s for s in done if s.n == best), None) if best is not None else None
    if top is not None:
        busiest = sorted(top.server_cpu_by.items(), key=lambda kv: -kv[1])[:4]
        report.add(f"{label}: at N={top.n}: server + clients CPU", round(top.server_cpu_pct + top.client_cpu_pct),
                   "-", None, f"% of {100 * cores}", f"server {top.server_cpu_pct:.0f} % ("
                   + ", ".join(f"{k} {v:.0f}" for k, v in busiest) + f"), clients {top.client_cpu_pct:.0f} %, "
                   f"machine busy {top.machine_busy_pct:.0f} % (other work included)")
    left = details.get("left", {})
    report.add(f"{label}: conversations left after every visitor left", left.get("remaining", "?"), "0",
               left.get("remaining") == 0, "", f"removed within {left['seconds']:.1f} s" if left.get("seconds")
               is not None else "the agents list did not come back to none within 40 s")
    if left:
        report.add(f"{label}: server PSS after all left", left["pss_mb_after"], "-", None, "MB",
                   f"{left['pss_mb_before']:.0f} MB with the visitors, "
                   f"{done[0].pss_mb if done and done[0].n == 0 else float('nan'):.0f} MB at N=0 before")
    if beyond is not None:
        status, answer = beyond
        report.add(f"{label}: a visitor beyond [conversations] max {inst_max[0]}", status, "503 busy",
                   status == 503, "", str(answer.get("error") if isinstance(answer, dict) else answer)[:120])
    restarts = details.get("restarts", [])
    if restarts:
        report.add(f"{label}: services restarted by the supervisor", len(restarts), "0", False, "",
                   f"e.g. {restarts[0][:150]}")
    for tb in details.get("tracebacks", []):
        report.add(f"{label}: traceback in eca up's output", tb["count"], "0", False, "x",
                   f"{tb['before'][:80]} ... {tb['lines'][-1][:160]}")
    closed = details.get("viewers_closed", {})
    if closed.get("count"):
        report.add(f"{label}: viewers the server closed", closed["count"], "0", False, "",
                   f"{details.get('viewers_closed_silent', 0)} as silent (no receiver report for [web] "
                   f"silent_timeout_s); e.g. {closed['lines'][0][:140]}")


def parse_steps(text: str) -> list[int]:
    steps = sorted({int(x) for x in text.split(",") if x.strip()})
    if not steps or steps[0] < 0:
        raise argparse.ArgumentTypeError("steps: visitor counts, e.g. 0,5,10")
    return steps


def run(args: argparse.Namespace, report: Report) -> None:
    report.details["uptime_before"] = uptime()
    progress(f"machine: {report.details['uptime_before']}")
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory(prefix="eca-conv-") as folder:
        wav, user_s = user_sentence(Path(folder))
        if user_s + args.agent_gap_s + args.agent_s + 0.8 > args.cycle_s:
            raise ValueError(f"--cycle-s {args.cycle_s:g} is too short for the user's {user_s:.1f} s, the gap "
                             f"{args.agent_gap_s:g} s and the agent's {args.agent_s:g} s")
        pcm = agent_voice(args.agent_s, rng)
        report.details["turns"] = {"user_s": round(user_s, 2), "agent_at_s": round(user_s + args.agent_gap_s, 2),
                                   "agent_s": args.agent_s, "cycle_s": args.cycle_s}
        for path in args.paths:
            steps = args.steps if path == "browser" else args.server_steps
            try:
                run_path(path, steps, args, report, wav, user_s, pcm)
            except Exception as exc:  # one path failing leaves the other's figures
                import traceback

                report.add(f"{path}-drawn path", "bench failed", "runs", False, "",
                           f"{type(exc).__name__}: {exc}"[:200])
                report.details.setdefault("exceptions", []).append(traceback.format_exc())
                progress(f"{path}-drawn path failed: {type(exc).__name__}: {exc}")
    report.details["uptime_after"] = uptime()
    shipped_note = (f"the shipped {SHIPPED_MAX_VIEWERS} refuses the 17th page (503) whatever [conversations] max "
                    f"says; this run: {args.max_viewers or SHIPPED_MAX_VIEWERS}")
    report.add("[web] max_viewers in this run", args.max_viewers or SHIPPED_MAX_VIEWERS, "-", None, "", shipped_note)
    report.add("web workers", args.web_workers, "-", None, "",
               "one web process" if args.web_workers == 1 else
               f"eca up --web-workers {args.web_workers}, HAProxy in front (its CPU and memory counted as server's); "
               "[web] max_viewers is per worker")
    report.add("load before", report.details["uptime_before"].split("load average:")[-1].strip(), "-", None, "",
               "uptime: 1, 5, 15 min")
    report.add("load after", report.details["uptime_after"].split("load average:")[-1].strip(), "-", None, "",
               "uptime: 1, 5, 15 min")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--paths", type=lambda t: [p for p in t.split(",") if p], default=["browser", "server"],
                        help="which paths, in order: browser (faces drawn by the pages), server (video)")
    parser.add_argument("--steps", type=parse_steps, default=parse_steps("0,1,2,3,5,10,20,30,40,50,60"),
                        help="visitor counts of the browser-drawn path")
    parser.add_argument("--server-steps", type=parse_steps, default=parse_steps("0,1,2,3,4"),
                        help="visitor counts of the server-drawn path")
    parser.add_argument("--hold-s", type=float, default=20.0, help="each step's measuring window (s)")
    parser.add_argument("--settle-s", type=float, default=5.0, help="after the visitors arrive, before measuring")
    parser.add_argument("--fps", type=float, default=30.0, help="the face rate each visitor asks (the page's default)")
    parser.add_argument("--width", type=int, default=640, help="the face size a visitor asks (video)")
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--client-procs", type=int, default=2, help="helper processes holding the visitors")
    parser.add_argument("--ordinary-visitors", action="store_true",
                        help="keep the visitors at the ordinary priority when the server's voice path runs real-time")
    parser.add_argument("--cycle-s", type=float, default=8.0, help="one user turn and one agent turn (s)")
    parser.add_argument("--agent-s", type=float, default=2.5, help="the agent's turn (s)")
    parser.add_argument("--agent-gap-s", type=float, default=1.2,
                        help="from the end of the user's sentence to the agent's Say (the VAD ends the turn after "
                             "0.6 s)")
    parser.add_argument("--gap-ms", type=float, default=60.0, help="a voice gap: packets further apart than this")
    parser.add_argument("--max-viewers", type=int, default=64,
                        help=f"[web] max_viewers in the private config (0: the shipped {SHIPPED_MAX_VIEWERS})")
    parser.add_argument("--max-conversations", type=int, default=None,
                        help="[conversations] max in the private config (default: the shipped one)")
    parser.add_argument("--heartbeat-timeout-s", type=float, default=0.0,
                        help="[heartbeat] timeout_s in the private config (0: the shipped 1.5 s)")
    parser.add_argument("--stop-after", type=int, default=2, help="stop a path after this many failed steps in a row")
    parser.add_argument("--web-workers", type=int, default=1,
                        help="web worker processes (eca up --web-workers); more than 1 puts HAProxy in front, as "
                             "docs/web.md says, and counts it as server")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print one JSON object (the table goes to stderr)")
    args = parser.parse_args(argv)

    done = run_guarded(lambda report: run(args, report))  # Ctrl-C or SIGTERM: eca up and the helpers stop
    report, host, wall_s = done.report, done.host, done.wall_s
    out = sys.stderr if args.json else sys.stdout
    said = [x for path in ("browser-drawn", "server-drawn") for x in report.details.get(path, {}).get("up_said", [])]
    report.print_table(done.header("conversations per machine", "eca up --web --per-visitor --face head "
                                   "--silent-audio, synthetic aiortc visitors"), out, said,
                       "eca up said (errors, restarts):", value_width=30)
    if args.json:
        print(json.dumps({"bench": "conversations", "machine": host, "wall_s": round(wall_s, 1),
                          "options": vars(args), **report.as_json()}, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
