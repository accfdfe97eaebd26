"""The pipecat face (eca/services/pipecat): the latency it adds to a reply's first audio frame, the A/V offset
of the frames it pushes, its CPU share at 30 fps, and what a whole bot session costs with it and without it.

Phases 1-3 start `eca up` (broker, dialogue, gaze, audio) on a private instance, as
`EcaVideoService(start_eca=True)` does, and run pipecat pipelines in this process against it; phases 4 and 5
run real bot processes, each starting its own eca per session as a deployment does. Each phase compares the
same thing with the face (A) and without it (B), measured in the same run.

1. First audio frame of a reply. Pipeline `[TTS, face, output]` (A) or `[TTS, output]` (B): the TTS is
   pipecat's own TTSService machinery speaking espeak-ng audio synthesised once before the run (so the
   engine's own time does not blur the comparison), the output a processor that notes when each frame
   arrives. A reply is a TTSSpeakFrame queued into the pipeline; its latency, the time from the queueing
   to the arrival of its first TTSAudioRawFrame at the output. Blocks of `--replies` replies one
   `--spacing-s` apart (a reply has played out before the next), in the order A B B A A B B A, each a fresh
   pipeline, so drift of a shared machine hits both alike. Figure: median(A) - median(B). Target <= 20 ms.
2. A/V offset. Pipeline `[face, output]`, 640x480 at 30 fps. `--bursts` vowel bursts (250 ms of a voice
   with harmonics at 140 Hz, half of full scale; gaps drawn from the seeded generator, 0.45-0.75 s, so the
   onsets fall at every phase of the frame slots) are pushed as TTS frames of 20 ms at real-time pace,
   one utterance each, as a streaming TTS hands them to its output. The output plays each frame from its
   push, or from the end of the one before if that is later (pipecat's output transports do), so the
   moment every sample is heard is known. Each pushed picture is judged from its pixels (the dark inside
   of the open mouth, counted in a box around it): open or shut, half-way between the shut level (pictures
   far from any burst) and the open one (pictures in the middle of bursts). The mouth it should show is
   eca's own lip-sync (eca/agent/lipsync, the same estimator and configuration) of the same samples, run
   offline, open where its jaw weight is over half its level in the burst. Per burst, the shift of the
   pictures' push times that makes the most pictures around its start and end agree with that is found
   (the middle of the best shifts): the burst's offset, + = the picture shows an earlier moment than the
   sound being played (video late). Figure: the median |offset| over bursts. Target <= 15 ms.
3. CPU share at 30 fps. The process's CPU time (all threads: the face's, its GL rasteriser's, the event
   loop's) over the A/V phase, with the face (A) and over the same paced audio without it (B); the share
   of one core is (A - B) / wall time. eca's own services run in their own processes and are reported
   apart (their CPU over the A phase). For information (no target).
4. The whole session. The bench writes a bot into a temporary folder: the documented minimal bot
   (docs/pipecat.md, "A minimal bot": SmallWebRTC, Silero VAD, user turns, espeak-ng,
   `EcaVideoService(start_eca=True)` at 640x480 and 30 fps) on the example bot's kind of server (FastAPI,
   `POST /api/offer`, a free port), logging at INFO; B is the same bot without `EcaVideoService`, without
   video out, and without importing the face (eca's EspeakTTSService is loaded from its file: through
   `eca.pipecat` it would bring the face's modules along). Not examples/pipecat_bot.py itself: it imports
   the face at its top, so a B made from it would carry the face's memory. On connect the bot speaks a text
   long enough to outlast the window, one TTSSpeakFrame per sentence, so A and B do the same TTS and audio
   work. A real WebRTC client in this process (aiortc) connects as eca's page does: audio sendrecv first
   (aiortc's silent track as the microphone, paced in real time), video recvonly second, a data channel;
   it POSTs its offer to /api/offer and decodes every frame it receives, so the bot really encodes VP8
   and Opus. After the first face frame (A) or voice (B) and `--session-settle-s` of start-up, a window of
   `--session-window-s`: CPU as a share of one core of the bot's whole process tree (the bot and every
   descendant, found through /proc: the face's eca guard, `eca up`, broker, dialogue, gaze, audio;
   utime + stime + cutime + cstime of each, so a child that ends meanwhile still counts), and memory: the
   sum of PSS (/proc/PID/smaps_rollup: shared pages split among the processes that map them, also other
   processes of the machine that map the same files) over the tree, sampled every 5 s (median); RSS and
   USS (private pages only: what no other process shares) beside it for information. One bot process per
   run, in the order `--session-order` (A B B A), medians. Figures: with, without, the difference (info).
5. The start. From the client's offer (a session starts on connect) to its first decoded face frame:
   cold, a bot with an empty numba cache (NUMBA_CACHE_DIR, a fresh folder: the face's drawing code is
   compiled in that session), and warm, a new bot with the cache filled (that bot's first session, and
   every A of phase 4); each bot of this phase then serves a next session in the same process. Beside it,
   when the pipeline started (every processor set up: the face's is starting eca and connecting; the bot
   prints its monotonic clock, which on Linux is this process's too), the first voice, and how long the
   compile took. The bots give a pipeline's set-up more than pipecat's 20 s (its default), so that a cold
   start that needs longer is measured; the figure says when it would have failed. Also the time from
   launching a bot until its HTTP server answers (every bot of phases 4 and 5), and how long a session's
   processes take to go once the client leaves. Info.

Figures are printed one per line against their target or their baseline (met / MISSED / info); the bench
always exits 0, it is a measurement. With --json the table goes to stderr and one JSON object to stdout.
Progress lines go to stderr. Nothing is left behind: eca, the bots and everything they started stop with
the bench (also on an error or Ctrl-C; a bot also stops itself when the bench is killed outright, and a
session's end is checked to take its processes with it).

    python bench/pipecat.py [--replies 6] [--spacing-s 0.9] [--bursts 24] [--eca-services dialogue,gaze,audio]
                            [--session-window-s 25] [--session-settle-s 5] [--session-order ABBA]
                            [--skip-latency] [--skip-av] [--skip-start] [--skip-session] [--seed 0] [--json]

A run takes about 5 minutes on 2 cores: eca's start 2 s, latency 80 s, A/V 25 s, its baseline 10 s; the
start 40 s (two bots, one compiling, two sessions each); the sessions 2.5 minutes (four bots, 35 s each).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent
BOT_FILE = REPO / "bench" / "_pipecat_bot.py"  # the bench's bot, copied into a temporary folder and run there
# This script is named like the package it measures: its own folder must not shadow `import pipecat`.
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
sys.path.insert(0, str(REPO))

from bench._pipecat_common import CPU_BASELINE_BURSTS, FPS, HEIGHT, WIDTH, process_cpu_s, progress  # noqa: E402
from bench._pipecat_inprocess import av_phase, latency_phase, pipecat_parts  # noqa: E402
from bench.procs import MEMORY_KINDS, descendants, memory_kib, proc_table  # noqa: E402
from bench.report import Report, run_guarded  # noqa: E402

# --- 4. the whole session and 5. the start: a real bot process with the face and without it ---------------

SESSION_LINES = (  # what the bench's bot says on connect, one TTSSpeakFrame per line, cycled to length
    "Hello! I am Ada, and this is my face.",
    "I will keep talking for a while, so that you can see what a whole session costs.",
    "Every word you hear is spoken by espeak-ng, and my mouth follows the sound itself.",
    "My eyes move the way a person's eyes move in a conversation, with small saccades and blinks.",
    "When you start to speak, I stop and listen to you.",
    "There is no language model here, only a script, so I cannot hear what you say.",
    "The picture you see is drawn thirty times a second, in step with my voice.",
    "That is all for now. Let me say it once more, from the beginning.",
)
WORDS_PER_MINUTE = 160  # EspeakTTSService's default rate: how many words a window needs
VOICE_RMS = 200.0  # a decoded audio frame louder than this (int16 RMS) is voice; the transport's silence is 0
MEMORY_EVERY_S = 5.0  # the tree's memory is sampled this often over the window
BOT_READY_S = 120.0  # launching a bot until its HTTP server answers, at most (imports on a loaded machine)
FIRST_FRAME_S = 180.0  # an offer until the first face frame and voice, at most (a cold compile on 2 cores)
SESSION_END_S = 30.0  # the client leaving until the session's processes are gone, at most
STOP_S = 30.0  # SIGINT until the bot has exited, at most; then what is left of its tree gets SIGKILL
STARTED_LINE = "bench bot: pipeline started at "
COMPILED_LINE = "the face's drawing code is compiled ("  # eca's line when numba compiled rather than loaded



def process_label(pid: int, root: int) -> str:
    """What a process of a bot's tree is, for the breakdown: the bot, or which of eca's processes."""
    if pid == root:
        return "bot"
    try:
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace").split("\0")
    except OSError:
        return "gone"
    if any(a.endswith("guard.py") for a in argv):
        return "eca guard"
    if "eca.services.processes.run" in argv:
        return f"eca {argv[argv.index('eca.services.processes.run') + 1]}"
    if "eca.services.tools.cli" in argv and "up" in argv:
        return "eca up"
    return Path(argv[0]).name or "?"


@dataclass
class TreeSample:
    cpu_ticks: dict[str, int]  # per label
    memory_kib: dict[str, dict[str, int]]  # per kind (pss, rss, uss), per label
    pids: int


def tree_sample(root: int, memory: bool) -> TreeSample:
    table = proc_table()
    cpu: dict[str, int] = {}
    mem: dict[str, dict[str, int]] = {kind: {} for kind in MEMORY_KINDS}
    tree = descendants(root, table)
    for pid in tree:
        label = process_label(pid, root)
        cpu[label] = cpu.get(label, 0) + table[pid].cpu_ticks
        if memory:
            for kind, kib in (memory_kib(pid) or dict.fromkeys(MEMORY_KINDS, 0)).items():
                mem[kind][label] = mem[kind].get(label, 0) + kib
    return TreeSample(cpu, mem, len(tree))


class WebRTCClient:
    """A browser's side of a session, in this process: aiortc's peer connection offers what eca's page
    offers (audio sendrecv with a microphone, video recvonly, a data channel), POSTs the offer to the bot's
    /api/offer and decodes every frame it receives, so the bot really encodes VP8 and Opus for it. The
    microphone is aiortc's silent track, paced in real time: the bot's VAD runs on it, and hears no one."""

    def __init__(self) -> None:
        from aiortc import RTCPeerConnection
        from aiortc.mediastreams import AudioStreamTrack

        self.pc = RTCPeerConnection()
        self.pc.addTransceiver(AudioStreamTrack(), direction="sendrecv")
        self.pc.addTransceiver("video", direction="recvonly")
        self.pc.createDataChannel("messages")
        self.pc.on("track", self._on_track)
        self.offered = 0.0
        self.frames: list[float] = []  # when each video frame was decoded
        self.audio: list[tuple[float, bool]] = []  # each audio frame: when it was decoded, and if voiced
        self.size = (0, 0)
        self.first_frame = asyncio.Event()
        self.first_voice = asyncio.Event()
        self._consumers: list[asyncio.Task[None]] = []

    def _on_track(self, track: Any) -> None:
        self._consumers.append(asyncio.ensure_future(self._consume(track)))

    async def _consume(self, track: Any) -> None:
        from aiortc.mediastreams import MediaStreamError

        try:
            while True:
                frame = await track.recv()
                now = time.monotonic()
                if track.kind == "video":
                    if not self.frames:
                        self.size = (frame.width, frame.height)
                        self.first_frame.set()
                    self.frames.append(now)
                else:
                    samples = frame.to_ndarray().astype(np.float32)
                    voiced = float(np.sqrt(np.mean(samples * samples))) > VOICE_RMS
                    self.audio.append((now, voiced))
                    if voiced:
                        self.first_voice.set()
        except MediaStreamError:
            return  # the connection closed

    async def connect(self, url: str) -> float:
        """Offer, POST, answer; returns the seconds from sending the offer to setting the answer."""
        import aiohttp
        from aiortc import RTCSessionDescription

        await self.pc.setLocalDescription(await self.pc.createOffer())  # gathers the candidates: the whole offer
        self.offered = time.monotonic()
        offer = {"sdp": self.pc.localDescription.sdp, "type": self.pc.localDescription.type}
        async with aiohttp.ClientSession() as http, http.post(f"{url}api/offer", json=offer) as response:
            response.raise_for_status()
            answer = await response.json()
        await self.pc.setRemoteDescription(RTCSessionDescription(sdp=answer["sdp"], type=answer["type"]))
        return time.monotonic() - self.offered

    async def since_offer(self, event: asyncio.Event, what: str, timeout_s: float) -> float:
        """Seconds from the offer to `event`'s first frame (the first face frame, or the first voice)."""
        try:
            await asyncio.wait_for(event.wait(), timeout_s)
        except TimeoutError:
            raise TimeoutError(f"no {what} reached the client within {timeout_s:g} s of its offer") from None
        first = self.frames[0] if event is self.first_frame else next(t for t, voiced in self.audio if voiced)
        return first - self.offered

    def window(self, t0: float, t1: float) -> tuple[float, float]:
        """Video frames decoded per second, and the share of audio frames that were voice, in [t0, t1]."""
        frames = sum(t0 <= t <= t1 for t in self.frames)
        audio = [voiced for t, voiced in self.audio if t0 <= t <= t1]
        return frames / (t1 - t0), (sum(audio) / len(audio) if audio else 0.0)

    async def close(self) -> None:
        await self.pc.close()
        for task in self._consumers:
            task.cancel()
        await asyncio.gather(*self._consumers, return_exceptions=True)


@dataclass
class Bot:
    proc: subprocess.Popen[bytes]
    reader: Any  # eca's LineReader of its output
    face: bool
    launched: float
    url: str = ""
    http_s: float = 0.0  # launching it until its HTTP server answered
    left_behind: list[str] = field(default_factory=list)

    def wait_line(self, needle: str, timeout_s: float, start: int = 0) -> int:
        """The index of the first line from `start` on that contains `needle`; an error when the bot ends or
        `timeout_s` passes first."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                return self.reader.wait_for(needle, max(0.01, min(0.5, deadline - time.monotonic())), start)
            except TimeoutError:
                if self.proc.poll() is not None or time.monotonic() >= deadline:
                    state = "ended" if self.proc.poll() is not None else "still runs"
                    raise RuntimeError(f"the bench's bot said no {needle!r} (it {state}); its last lines:\n"
                                       + "\n".join(self.reader.lines[-15:])) from None

    def tree(self) -> list[tuple[int, int, str]]:
        """Its descendants now: (pid, start time, label) each."""
        table = proc_table()
        return [(pid, table[pid].start, process_label(pid, self.proc.pid))
                for pid in descendants(self.proc.pid, table) if pid != self.proc.pid]


def alive(processes: list[tuple[int, int, str]]) -> list[tuple[int, int, str]]:
    table = proc_table()
    return [p for p in processes if p[0] in table and table[p[0]].start == p[1] and table[p[0]].state != "Z"]


def wait_gone(processes: list[tuple[int, int, str]], timeout_s: float) -> list[tuple[int, int, str]]:
    """Polls until every process has ended (a session's eca stops in order: about a second); what is left."""
    deadline = time.monotonic() + timeout_s
    while (left := alive(processes)) and time.monotonic() < deadline:
        time.sleep(0.05)
    return left


def wait_http(bot: Bot) -> None:
    """Polls the bot's page until it answers (connection refused until uvicorn listens)."""
    import urllib.error
    import urllib.request

    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))  # loopback: never a proxy
    deadline = time.monotonic() + BOT_READY_S
    while True:
        try:
            with opener.open(bot.url, timeout=2.0) as response:
                if response.status == 200:
                    return
        except (urllib.error.URLError, OSError):
            pass
        if bot.proc.poll() is not None or time.monotonic() >= deadline:
            raise RuntimeError(f"the bench's bot did not answer at {bot.url}; its last lines:\n"
                               + "\n".join(bot.reader.lines[-15:]))
        time.sleep(0.01)


def stop_bot(bot: Bot) -> None:
    """SIGINT, as Ctrl-C in a terminal: the bot cancels its sessions, whose faces stop their eca. Whatever of
    its tree outlives it (nothing should: eca's guard also stops an eca whose starter died) gets SIGKILL, by
    pid, and is noted."""
    tree = bot.tree()
    if bot.proc.poll() is None:
        bot.proc.send_signal(signal.SIGINT)
        try:
            bot.proc.wait(timeout=STOP_S)
        except subprocess.TimeoutExpired:
            bot.left_behind.append(f"the bot did not stop within {STOP_S:g} s")
            os.killpg(bot.proc.pid, signal.SIGKILL)  # its own session: the bot and what shares its group
            bot.proc.wait(timeout=10.0)
    for pid, _, label in wait_gone(tree, SESSION_END_S):
        bot.left_behind.append(f"{label} (pid {pid})")
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    if bot.proc.stdout is not None:
        bot.proc.stdout.close()


def bot_env(cache_dir: Path) -> dict[str, str]:
    """The environment of the bench's bots: this clone first on the path (not eca's own subprocess_env, which
    puts the folder of the package `eca` there, where eca/pipecat.py would hide pipecat itself), and
    NUMBA_CACHE_DIR: the face's compiled drawing code in the bench's own cache (empty for a cold start)."""
    return {**os.environ, "PYTHONUNBUFFERED": "1", "NUMBA_CACHE_DIR": str(cache_dir),
            "PYTHONPATH": os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH", "")) if p)}


@contextmanager
def bot_running(folder: Path, face: bool, cache_dir: Path, left_behind: list[str]) -> Iterator[Bot]:
    """The bench's bot launched (with the face or without), until its HTTP server answers; stopped, with
    everything it started, when the block ends (also on an error or Ctrl-C). What had to be killed because it
    outlived the bot goes into `left_behind`."""
    from eca.services.tools.child_processes import LineReader

    env = bot_env(cache_dir)
    argv = [sys.executable, str(folder / "bench_bot.py"), "--text-file", str(folder / "text.txt"),
            "--parent", str(os.getpid()), "--setup-timeout-s", str(FIRST_FRAME_S), *(["--face"] if face else [])]
    launched = time.monotonic()
    # Its own session: a Ctrl-C in the bench's terminal is the bench's to handle, which stops the bot in order.
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                            env=env, cwd=folder, start_new_session=True)
    bot = Bot(proc, LineReader(proc.stdout), face, launched)
    try:
        line = bot.reader.lines[bot.wait_line("bench bot: port ", BOT_READY_S)]
        bot.url = f"http://127.0.0.1:{int(line.rsplit(' ', 1)[1])}/"
        wait_http(bot)
        bot.http_s = time.monotonic() - launched
        yield bot
    finally:
        stop_bot(bot)
        left_behind.extend(bot.left_behind)


async def end_session(bot: Bot, client: WebRTCClient, lines_before: int) -> float:
    """The client leaves; returns the seconds until the bot's session has ended and every process it started
    for it (the face's eca) is gone."""
    tree = bot.tree()
    left_at = time.monotonic()
    await client.close()
    await asyncio.to_thread(bot.wait_line, "bench bot: session ended", SESSION_END_S, lines_before)
    left = await asyncio.to_thread(wait_gone, tree, SESSION_END_S)
    if left:
        raise RuntimeError(f"the session ended, but not its processes: {', '.join(p[2] for p in left)}")
    return time.monotonic() - left_at


@dataclass
class Start:
    """One session's start: seconds from the client's offer."""

    answer_s: float  # the bot's answer is set
    started_s: float  # the pipeline has started: every processor is set up (the face: eca started, connected)
    first_voice_s: float
    first_frame_s: float | None  # the bot without the face sends no video
    size: tuple[int, int]
    compile_s: float | None  # eca's notice that the face's drawing code took this long to get ready (past 0.5 s:
    # a compile, when numba's cache was empty; a load from the cache on a busy machine says so too)
    end_s: float = 0.0  # the client leaving until the session's processes were gone


async def start_session(bot: Bot, client: WebRTCClient, lines_before: int) -> Start:
    answer_s = await client.connect(bot.url)
    first_voice = await client.since_offer(client.first_voice, "voice", FIRST_FRAME_S)
    first_frame = await client.since_offer(client.first_frame, "face frame", FIRST_FRAME_S) if bot.face else None
    # The bot prints its monotonic clock (the same clock as this process's, on Linux) when its pipeline started.
    line = bot.reader.lines[await asyncio.to_thread(bot.wait_line, STARTED_LINE, 5.0, lines_before)]
    compiled = [line for line in bot.reader.lines[lines_before:] if COMPILED_LINE in line]
    compile_s = float(compiled[0].split(COMPILED_LINE, 1)[1].split()[0]) if compiled else None
    return Start(answer_s, float(line.rsplit(" ", 1)[1]) - client.offered, first_voice, first_frame, client.size,
                 compile_s)


async def two_sessions(bot: Bot) -> list[Start]:
    """A first session of the bot's process, ended; then the next one in the same process."""
    starts: list[Start] = []
    for _ in range(2):
        client = WebRTCClient()
        lines_before = len(bot.reader.lines)
        try:
            start = await start_session(bot, client, lines_before)
        except BaseException:
            await client.close()  # the bot's stop takes what is left with it
            raise
        start.end_s = await end_session(bot, client, lines_before)
        starts.append(start)
    return starts


@dataclass
class SessionRun:
    face: bool
    http_s: float
    start: Start
    window_s: float
    cpu_cores: dict[str, float]  # per label of the bot's tree: CPU seconds per second over the window
    memory_mib: dict[str, dict[str, float]]  # per kind (pss, rss, uss), per label: the median over the samples
    pss_trend_mib: list[float]  # the tree's PSS at each sample: does it grow over the window?
    processes: int
    client_fps: float
    voice_share: float
    client_cpu_cores: float  # this process (the client: decoding, aiortc) meanwhile

    @property
    def cpu(self) -> float:
        return sum(self.cpu_cores.values())

    def memory(self, kind: str) -> float:
        return sum(self.memory_mib[kind].values())


async def measured_session(bot: Bot, window_s: float, settle_s: float) -> SessionRun:
    client = WebRTCClient()
    lines_before = len(bot.reader.lines)
    root = bot.proc.pid
    try:
        start = await start_session(bot, client, lines_before)
        await asyncio.sleep(settle_s)  # pacing: past the start-up (eca's start, the first sentences' TTS)
        t0, first, client0 = time.monotonic(), tree_sample(root, False), process_cpu_s()
        samples = [await asyncio.to_thread(tree_sample, root, True)]
        while (left := t0 + window_s - time.monotonic()) > 0:
            await asyncio.sleep(min(left, MEMORY_EVERY_S))  # pacing: memory samples across the window
            if time.monotonic() < t0 + window_s - 0.5:
                samples.append(await asyncio.to_thread(tree_sample, root, True))
        last, t1, client1 = tree_sample(root, False), time.monotonic(), process_cpu_s()
        samples.append(await asyncio.to_thread(tree_sample, root, True))
        fps, voice_share = client.window(t0, t1)
    except BaseException:
        await client.close()  # the bot's stop takes what is left with it
        raise
    start.end_s = await end_session(bot, client, lines_before)
    ticks = os.sysconf("SC_CLK_TCK")
    labels = set(first.cpu_ticks) | set(last.cpu_ticks)
    cpu = {label: (last.cpu_ticks.get(label, 0) - first.cpu_ticks.get(label, 0)) / ticks / (t1 - t0)
           for label in labels}
    memory: dict[str, dict[str, float]] = {}
    for kind in MEMORY_KINDS:
        names = {label for s in samples for label in s.memory_kib[kind]}
        memory[kind] = {label: statistics.median(s.memory_kib[kind].get(label, 0) for s in samples) / 1024
                        for label in names}
    trend = [sum(s.memory_kib["pss"].values()) / 1024 for s in samples]
    return SessionRun(bot.face, bot.http_s, start, t1 - t0, cpu, memory, trend, max(s.pids for s in samples), fps,
                      voice_share, (client1 - client0) / (t1 - t0))


def fill_numba_cache(cache_dir: Path) -> None:
    """Compile the face's drawing code into `cache_dir`, as `eca warm-up` does for an install."""
    subprocess.run([sys.executable, "-c", "from eca.services.processes.renderer.kernels import warm_up; warm_up()"],
                   env=bot_env(cache_dir), check=True, timeout=600, stdout=subprocess.DEVNULL)


def eca_share(values: dict[str, float]) -> float:
    return sum(v for label, v in values.items() if label.startswith("eca"))


def start_phase(folder: Path, cache_dir: Path, left_behind: list[str]) -> dict[str, tuple[float, list[Start]]]:
    """A bot with the face whose numba cache is empty (cold), then one with it filled (warm); each serves a
    first session and then the next one in the same process. Per kind: (launch to HTTP answering, starts)."""
    got: dict[str, tuple[float, list[Start]]] = {}
    for kind in ("cold", "warm"):
        progress(f"start: a bot with the face, its numba cache {'empty' if kind == 'cold' else 'filled'} ({kind}); "
                 "a first session, then the next one")
        with bot_running(folder, True, cache_dir, left_behind) as bot:
            got[kind] = (bot.http_s, asyncio.run(two_sessions(bot)))
    return got


def session_phase(folder: Path, cache_dir: Path, args: argparse.Namespace, left_behind: list[str]) -> list[SessionRun]:
    runs: list[SessionRun] = []
    for k, variant in enumerate(args.session_order):
        face = variant == "A"
        progress(f"session {k + 1}/{len(args.session_order)}: {variant}, the bot {'with' if face else 'without'} "
                 f"the face ({args.session_settle_s:g} s start-up, {args.session_window_s:g} s measured)")
        with bot_running(folder, face, cache_dir, left_behind) as bot:
            runs.append(asyncio.run(measured_session(bot, args.session_window_s, args.session_settle_s)))
    return runs


def bot_phases(args: argparse.Namespace, report: Report) -> None:
    try:
        import aiohttp  # noqa: F401
        import aiortc  # noqa: F401
    except ImportError as exc:
        report.add("session phases", "skipped", "aiortc", False, "", f"{exc}: pipecat's webrtc extra brings them")
        return
    with tempfile.TemporaryDirectory(prefix="eca-pipecat-bench-") as tmp:
        folder, cache_dir = Path(tmp), Path(tmp) / "numba-cache"
        cache_dir.mkdir()
        shutil.copyfile(BOT_FILE, folder / "bench_bot.py")  # run from outside the repository, as a user's bot
        words = (args.session_window_s + args.session_settle_s + 40.0) * WORDS_PER_MINUTE / 60.0
        lines: list[str] = []
        while sum(len(line.split()) for line in lines) < words:
            lines.append(SESSION_LINES[len(lines) % len(SESSION_LINES)])
        (folder / "text.txt").write_text("\n".join(lines) + "\n")
        starts: dict[str, tuple[float, list[Start]]] = {}
        runs: list[SessionRun] = []
        left_behind: list[str] = []

        def say_left_behind() -> None:  # whatever outlived its bot was killed; it is said, also after a failure
            report.add("processes that outlived their bot", len(left_behind), "-", None, "",
                       "; ".join(left_behind)[:200] or "none: each session's end and each bot's stop took them along")
            report.details["left_behind"] = left_behind

        try:
            if not args.skip_start:
                starts = start_phase(folder, cache_dir, left_behind)
            if not args.skip_session:
                if args.skip_start:
                    progress("filling the bench's numba cache (eca's warm-up), so that every session bot starts warm")
                    fill_numba_cache(cache_dir)
                runs = session_phase(folder, cache_dir, args, left_behind)
        except BaseException:
            say_left_behind()
            raise
    if runs:
        session_figures(runs, report)
    start_figures(starts, runs, report)
    say_left_behind()


def session_figures(runs: list[SessionRun], report: Report) -> None:
    with_face = [r for r in runs if r.face]
    without = [r for r in runs if not r.face]
    med = statistics.median
    cpu_a, cpu_b = med(r.cpu for r in with_face), med(r.cpu for r in without)
    pss_a, pss_b = med(r.memory("pss") for r in with_face), med(r.memory("pss") for r in without)
    rss_a, rss_b = med(r.memory("rss") for r in with_face), med(r.memory("rss") for r in without)
    uss_a, uss_b = med(r.memory("uss") for r in with_face), med(r.memory("uss") for r in without)
    order = "".join("A" if r.face else "B" for r in runs)
    window = f"{med(r.window_s for r in runs):.0f} s windows, {order}, medians"
    report.add("session CPU, bot and children: added by the face", round(cpu_a - cpu_b, 3), "-", None, "cores",
               f"with - without; {window}")
    report.add("session CPU: with the face", round(cpu_a, 3), "-", None, "cores",
               f"bot {med(r.cpu_cores.get('bot', 0) for r in with_face):.2f} + eca's processes "
               f"{med(eca_share(r.cpu_cores) for r in with_face):.2f}; baseline: without")
    report.add("session CPU: without the face", round(cpu_b, 3), "-", None, "cores",
               f"bot and its children; client (this process) {med(r.client_cpu_cores for r in runs):.2f} cores")
    report.add("session memory (PSS): added by the face", round(pss_a - pss_b, 1), "-", None, "MiB",
               f"RSS {rss_a - rss_b:+.0f}, USS {uss_a - uss_b:+.0f} MiB; summed over the process tree")
    report.add("session memory (PSS): with the face", round(pss_a, 1), "-", None, "MiB",
               f"bot {med(r.memory_mib['pss'].get('bot', 0) for r in with_face):.0f} + eca's processes "
               f"{med(eca_share(r.memory_mib['pss']) for r in with_face):.0f} MiB "
               f"({max(r.processes for r in with_face)} processes); RSS {rss_a:.0f}, USS {uss_a:.0f} MiB")
    report.add("session memory (PSS): without the face", round(pss_b, 1), "-", None, "MiB",
               f"RSS {rss_b:.0f}, USS {uss_b:.0f} MiB; baseline")
    sizes = {f"{r.start.size[0]}x{r.start.size[1]}" for r in with_face}
    report.add("face frames decoded at the client", round(med(r.client_fps for r in with_face), 2), f"{FPS:g} sent",
               None, "fps", f"{', '.join(sorted(sizes))}, VP8 over loopback")
    report.add("bot's voice during the window: with the face", round(med(r.voice_share for r in with_face), 2),
               "-", None, "", f"share of decoded audio frames; without {med(r.voice_share for r in without):.2f}")
    report.details["sessions"] = [{
        "face": r.face, "http_s": round(r.http_s, 3), "answer_s": round(r.start.answer_s, 3),
        "started_s": round(r.start.started_s, 3), "first_voice_s": round(r.start.first_voice_s, 3),
        "first_frame_s": None if r.start.first_frame_s is None else round(r.start.first_frame_s, 3),
        "window_s": round(r.window_s, 2), "cpu_cores": {k: round(v, 4) for k, v in sorted(r.cpu_cores.items())},
        **{f"{kind}_mib": {k: round(v, 1) for k, v in sorted(r.memory_mib[kind].items())} for kind in MEMORY_KINDS},
        "pss_trend_mib": [round(v, 1) for v in r.pss_trend_mib], "processes": r.processes,
        "client_fps": round(r.client_fps, 2), "voice_share": round(r.voice_share, 3),
        "client_cpu_cores": round(r.client_cpu_cores, 3), "session_end_s": round(r.start.end_s, 2)}
        for r in runs]


def start_figures(starts: dict[str, tuple[float, list[Start]]], runs: list[SessionRun], report: Report) -> None:
    med = statistics.median
    try:
        from pipecat.pipeline.worker import SETUP_TIMEOUT_SECS as setup_limit_s
    except ImportError:
        setup_limit_s = 20.0
    launches_a = [r.http_s for r in runs if r.face] + [http_s for http_s, _ in starts.values()]
    launches_b = [r.http_s for r in runs if not r.face]
    if launches_a:
        note = f"median of {len(launches_a)}"
        if launches_b:
            note += f"; baseline without the face {med(launches_b):.2f} s (median of {len(launches_b)})"
        report.add("bot launch to HTTP answering: with the face", round(med(launches_a), 2), "-", None, "s", note)
    elif launches_b:
        report.add("bot launch to HTTP answering: without the face", round(med(launches_b), 2), "-", None, "s")
    warm = ([starts["warm"][1][0]] if "warm" in starts else []) + [r.start for r in runs if r.face]
    if "cold" in starts:
        cold = starts["cold"][1][0]
        compiled = f"compiled in {cold.compile_s:.1f} s" if cold.compile_s is not None else "no compile line seen"
        over = (f"; over pipecat's default set-up limit ({setup_limit_s:g} s): with it the session fails"
                if cold.started_s > setup_limit_s else "")
        report.add("first face frame after the offer: cold", round(cold.first_frame_s or 0.0, 2), "-", None, "s",
                   f"empty numba cache, {compiled}; pipeline set up at {cold.started_s:.1f} s{over}")
    if warm:
        report.add("first face frame after the offer: warm", round(med(s.first_frame_s or 0.0 for s in warm), 2),
                   "-", None, "s", f"a new bot, numba cache filled; median of {len(warm)}; pipeline set up at "
                                   f"{med(s.started_s for s in warm):.2f} s")
    if starts:
        later = [s[1] for _, s in starts.values()]
        report.add("first face frame after the offer: next session",
                   round(med(s.first_frame_s or 0.0 for s in later), 2), "-", None, "s",
                   f"the same bot process, after its first session; median of {len(later)}")
        report.details["start"] = {kind: {"http_s": round(http_s, 3), "sessions": [
            {k: round(v, 3) if isinstance(v, float) else v for k, v in s.__dict__.items()} for s in ss]}
                                   for kind, (http_s, ss) in starts.items()}
    without = [r.start for r in runs if not r.face]
    if warm and without:
        report.add("pipeline set up after the offer: with the face", round(med(s.started_s for s in warm), 2), "-",
                   None, "s", f"warm; baseline without the face {med(s.started_s for s in without):.2f} s: the face's "
                              "set-up (eca's start) comes first")
        report.add("first voice after the offer: with the face", round(med(s.first_voice_s for s in warm), 2), "-",
                   None, "s", f"warm; baseline without the face {med(s.first_voice_s for s in without):.2f} s")
    ends = [s.end_s for _, ss in starts.values() for s in ss] + [r.start.end_s for r in runs if r.face]
    if ends:
        report.add("client leaving to the session's processes gone", round(max(ends), 2), "-", None, "s",
                   f"the face's eca stops with its session; the longest of {len(ends)}")


# --- the run ------------------------------------------------------------------------------------------


def run(args: argparse.Namespace, report: Report) -> None:
    try:
        parts = pipecat_parts()
        from eca.services.pipecat.instance import EcaInstance
    except ImportError as exc:
        report.add("pipecat", "missing", "installed", False, "", f"{exc}; pip install 'eca[pipecat]'")
        return
    if not (args.skip_latency and args.skip_av):
        progress(f"starting eca (eca up: broker, {', '.join(args.eca_services)}) on a private instance")
        instance = EcaInstance.start(timeout_s=90.0, services=args.eca_services)
        try:
            if not args.skip_latency:
                latency_phase(parts, instance.config.instance, args, report)
            if not args.skip_av:
                av_phase(parts, instance.config.instance, instance.proc.pid, args, report)
        finally:
            instance.stop()
            report.details["eca_up_errors"] = [line for line in instance.lines
                                               if "ERROR" in line or "Traceback" in line]
    if not (args.skip_start and args.skip_session):  # the bots start their own eca, one per session
        bot_phases(args, report)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--replies", type=int, default=6, help="first audio frame: replies per block (6)")
    parser.add_argument("--spacing-s", type=float, default=0.9, help="first audio frame: between replies (s)")
    parser.add_argument("--bursts", type=int, default=24, help="A/V: vowel bursts (24)")
    parser.add_argument("--skip-latency", action="store_true", help="skip the first-audio-frame phase")
    parser.add_argument("--skip-av", action="store_true", help="skip the A/V and CPU phase")
    parser.add_argument("--skip-start", action="store_true", help="skip the bot start phase (cold and warm)")
    parser.add_argument("--skip-session", action="store_true", help="skip the whole-session cost phase")
    parser.add_argument("--session-window-s", type=float, default=25.0,
                        help="whole session: seconds measured per bot (25)")
    parser.add_argument("--session-settle-s", type=float, default=5.0,
                        help="whole session: seconds of start-up left out first, after the first face frame (5)")
    parser.add_argument("--session-order", default="ABBA",
                        help="whole session: the bots in turn, A with the face, B without (ABBA)")
    parser.add_argument("--eca-services", type=lambda text: tuple(text.split(",")),
                        default=("dialogue", "gaze", "audio"),
                        help="what eca up starts beside the broker (default dialogue,gaze,audio)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print one JSON object (the table goes to stderr)")
    args = parser.parse_args(argv)
    if args.replies < 2 or args.bursts < CPU_BASELINE_BURSTS or not 0.3 <= args.spacing_s <= 10:
        parser.error(f"--replies >= 2, --bursts >= {CPU_BASELINE_BURSTS}, --spacing-s in 0.3..10")
    if not 5 <= args.session_window_s <= 600 or not 0 <= args.session_settle_s <= 60 \
            or set(args.session_order) != {"A", "B"}:
        parser.error("--session-window-s in 5..600, --session-settle-s in 0..60, --session-order of A and B, both")
    # pipecat's own deprecation notices (about its internals, some raised under an `always` filter, from
    # the repr of a frame in its debug output) are not the bench's figures.
    shown = warnings.showwarning
    warnings.showwarning = lambda message, category, *rest, **kw: (
        None if issubclass(category, DeprecationWarning) else shown(message, category, *rest, **kw))
    try:
        from loguru import logger  # pipecat logs every frame processor's life at DEBUG

        logger.remove()
        logger.add(sys.stderr, level="WARNING")
    except ImportError:
        pass  # no pipecat: the run says so
    done = run_guarded(lambda report: run(args, report))  # Ctrl-C or SIGTERM unwinds: eca stops
    report, host, wall_s = done.report, done.host, done.wall_s
    header = done.header("pipecat face", f"{WIDTH}x{HEIGHT} at {FPS:g} fps")
    report.print_table(header, sys.stderr if args.json else sys.stdout, value_width=28)
    if args.json:
        print(json.dumps({"bench": "pipecat", "machine": host, "wall_s": round(wall_s, 1), "options": vars(args),
                          **report.as_json()}, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
