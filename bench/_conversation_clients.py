"""The synthetic visitors of bench/conversations.py: a helper process holding many aiortc pages of a per-visitor
instance (`eca up --web --per-visitor`), each with a conversation of its own, driven by JSON lines on stdin and
answering JSON lines on stdout (one answer per command).

Each visitor does what the product page does (eca/services/processes/web/static/app.js): `POST /conversation`
for an agent and its key, then an offer with the microphone's section first and, for its agent, either only an
audio section, `draw_here` and the "eca-face" data channel (the page draws the face: `--draw browser`) or a video
and an audio section (the server draws it: `--draw server`). What it receives is recorded where it arrives, per
RTP packet (arrival time, RTP timestamp, sequence number, payload size, marker) and per data-channel message;
nothing is decoded: the server's work per visitor is the same, and this process's CPU goes to what a browser's
network stack would do, not to decoding pictures and sound nobody hears (bench/web.py's load process does the
same). Whether the voice is sounding is read from the Opus payload's size: libopus codes a 20 ms frame of
digital silence in 3 bytes, and any sound (speech, a tone, even -60 dBFS hiss) in tens to hundreds.

The microphone is pre-encoded: the user's sentence (a WAV the bench made with espeak-ng) is encoded to Opus once,
and each visitor's track sends, every 20 ms on its own pace, the packet for that instant of its conversation's
cycle: the sentence at `user_at_s` of every `cycle_s` (shifted by the visitor's phase), digital silence
otherwise. The server decodes it and runs its voice-activity detector on it as on a browser's microphone.

    python bench/_conversation_clients.py --url URL --draw browser|server --mic WAV --epoch-ns NS
                                          [--cycle-s 8] [--user-at-s 0] [--fps 30] [--width 640] [--height 480]
                                          [--realtime-priority 0]

The visitors run on the event loop the server's web service runs on (uvloop where it is installed).

Commands: {"op": "hello"}, {"op": "add", "visitors": [{"index", "phase_s"}, ...]}, {"op": "window", "t0", "t1",
"gap_ms", "silence_bytes", "split_packets"}, {"op": "close"}. Closing stdin closes every visitor and exits.
"""

from __future__ import annotations

import argparse
import asyncio
import fractions
import gc
import json
import struct
import sys
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import aiohttp
import aiortc.rtcrtpreceiver
import av
import numpy as np
import soundfile as sf
from aiortc import MediaStreamTrack, RTCConfiguration, RTCPeerConnection, RTCSessionDescription
from aiortc.codecs.opus import OpusEncoder
from aiortc.rtcrtpreceiver import RTCRtpReceiver
from aiortc.rtcsctptransport import RTCSctpTransport

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # run as a script: the repository's bench package

from bench._stdio import say, stdin_lines  # noqa: E402
from eca.services.processes.realtime import RealtimeSettings, ask_for_realtime  # noqa: E402
from eca.services.processes.web.mic_decoding import decode_on_loop  # noqa: E402

FRAME_NS = 20_000_000
OPUS_RATE = 48_000
OPUS_FRAME = 960  # samples per 20 ms packet
CONNECT_TIMEOUT_S = 30.0
CONCURRENCY = 4  # visitors arriving at once
LAG_TICK_S = 0.010
FACE_KIND, VOICE_CLOCK_KIND = 1, 2  # eca/services/processes/web/browser_face.py FRAME, VOICE_CLOCK
FACE_SEQ = struct.Struct("<I")  # the frame's sequence number, at byte 4 of its 16-byte header


class NullDecoder:
    """Takes each encoded frame and drops it (what arrived was recorded at the packet)."""

    def decode(self, encoded_frame: Any) -> list[Any]:
        return []


aiortc.rtcrtpreceiver.get_decoder = lambda codec: NullDecoder()  # type: ignore[attr-defined, assignment, return-value]


def drop_on_loop(receiver: RTCRtpReceiver) -> None:
    """The receiver's complete frames dropped where they are handled, as the web service decodes its microphones
    (web/mic_decoding.py), not handed to a decoder thread of their own that would decode nothing: each handover
    wakes that thread and takes the interpreter's lock from the visitors' event loop. (Where aiortc is not the
    one expected, its thread takes them, as before, and says so.)"""
    decode_on_loop(receiver, lambda codec: NullDecoder())


_handle_rtp = RTCRtpReceiver._handle_rtp_packet


async def _recorded_rtp(self: RTCRtpReceiver, packet: Any, arrival_time_ms: int) -> None:
    """Every RTP packet a visitor's receiver gets, noted as it arrives, then handled as aiortc does."""
    record = self.__dict__.get("_bench_record")
    if record is not None:
        record(packet)
    await _handle_rtp(self, packet, arrival_time_ms)


RTCRtpReceiver._handle_rtp_packet = _recorded_rtp  # type: ignore[method-assign]


# --- the face frames' acknowledgements ------------------------------------------------------------------------
# aiortc acknowledges every SCTP packet with data at once; a browser delays its SACKs as RFC 4960 6.2 says: one
# for every second packet with data, or 200 ms after one not yet acknowledged, and at once when data came out of
# order or twice. Chromium's dcSCTP does (measured against the web service: 435 SACKs for 864 packets of face
# frames). A visitor acknowledges as a browser does, so the server handles the acknowledgements a page sends it.
SACK_EVERY_PACKETS = 2
SACK_DELAY_S = 0.2
_send_sack = RTCSctpTransport._send_sack


@dataclass
class _DelayedSack:
    unacknowledged: int = 0
    timer: asyncio.TimerHandle | None = None


async def _delayed_sack(self: RTCSctpTransport) -> None:
    state: _DelayedSack = self.__dict__.setdefault("_bench_sack", _DelayedSack())
    state.unacknowledged += 1
    if state.unacknowledged < SACK_EVERY_PACKETS and not (self._sack_misordered or self._sack_duplicates):
        if state.timer is None:  # _sack_needed stays set: the next packet's handling comes back here
            state.timer = asyncio.get_running_loop().call_later(
                SACK_DELAY_S, lambda: asyncio.ensure_future(_sack_now(self, state)))
        return
    await _sack_now(self, state)


async def _sack_now(self: RTCSctpTransport, state: _DelayedSack) -> None:
    if state.timer is not None:
        state.timer.cancel()
        state.timer = None
    if state.unacknowledged and self._association_state == RTCSctpTransport.State.ESTABLISHED:
        state.unacknowledged = 0
        await _send_sack(self)


RTCSctpTransport._send_sack = _delayed_sack  # type: ignore[method-assign]


# --- the microphone -------------------------------------------------------------------------------------


def encode_speech(wav: str) -> tuple[list[bytes], bytes]:
    """The sentence as Opus packets of 20 ms (through aiortc's own encoder), and a packet of digital silence."""
    samples, rate = sf.read(wav, dtype="int16")
    if samples.ndim > 1:
        samples = samples[:, 0]
    encoder = OpusEncoder()
    packets: list[bytes] = []
    step = max(1, rate // 50)
    tail = np.zeros(rate // 2, np.int16)  # the sentence's last packets come out with the silence after it
    whole = np.concatenate([samples, tail])
    for start in range(0, len(whole), step):
        part = whole[start:start + step]
        frame = av.AudioFrame.from_ndarray(part.reshape(1, -1), format="s16", layout="mono")
        frame.sample_rate = rate
        frame.pts = start
        frame.time_base = fractions.Fraction(1, rate)
        payloads, _ = encoder.encode(frame)
        packets.extend(payloads)
    silence = next((p for p in reversed(packets) if len(p) <= 8), b"\xf8\xff\xfe")
    while packets and len(packets[-1]) <= 8:
        packets.pop()  # the sentence ends with its last sounding packet; silence follows from the track
    return packets, silence


class MicTrack(MediaStreamTrack):
    """A visitor's microphone: pre-encoded Opus packets, one per 20 ms, the sentence at its turn of the cycle.
    With `dtx` (the server's answer asks `usedtx=1`, as a browser honours it), silence is sent as a browser's
    Opus encoder sends it then: one packet every 400 ms, none between (the RTP timestamps jump)."""

    DTX_EVERY = 20  # frames: libopus' DTX sends a frame every 400 ms of silence

    kind = "audio"

    def __init__(self, speech: list[bytes], silence: bytes, epoch_ns: int, phase_ns: int, cycle_ns: int,
                 user_at_ns: int) -> None:
        super().__init__()
        self.speech, self.silence = speech, silence
        self.epoch_ns, self.phase_ns, self.cycle_ns, self.user_at_ns = epoch_ns, phase_ns, cycle_ns, user_at_ns
        self._start_ns: int | None = None
        self._k = 0
        self.dtx = False
        self._quiet = 0  # silent frames in a row

    async def recv(self) -> av.Packet:  # type: ignore[type-arg]
        if self._start_ns is None:
            self._start_ns = time.monotonic_ns()
        while True:
            due = self._start_ns + self._k * FRAME_NS
            wait_ns = due - time.monotonic_ns()
            if wait_ns > 0:
                await asyncio.sleep(wait_ns / 1e9)  # pacing to real time, as a microphone does
            at = (due - self.epoch_ns - self.phase_ns - self.user_at_ns) % self.cycle_ns
            i = at // FRAME_NS
            k = self._k
            self._k += 1
            self._quiet = 0 if i < len(self.speech) else self._quiet + 1
            if not self.dtx or not self._quiet or self._quiet % self.DTX_EVERY == 1:
                break  # every frame of speech; of silence the first, then one every 400 ms
        packet = av.Packet(self.speech[i] if i < len(self.speech) else self.silence)
        packet.pts = k * OPUS_FRAME
        packet.time_base = fractions.Fraction(1, OPUS_RATE)
        return packet


def asks_dtx(sdp: str, mid: str | None) -> bool:
    """Whether the answer's section `mid` asks for Opus' discontinuous transmission (`usedtx=1`)."""
    for section in sdp.split("m=")[1:]:
        if f"a=mid:{mid}\r\n" in section + "\r\n":
            return "usedtx=1" in section
    return False


# --- a visitor ----------------------------------------------------------------------------------------------


@dataclass
class Received:
    """What one receiver got: per RTP packet (arrival, RTP timestamp, sequence number, payload size, marker,
    SSRC)."""

    packets: deque[tuple[float, int, int, int, int, int]] = field(default_factory=deque)

    def add(self, packet: Any) -> None:
        self.packets.append((time.monotonic(), packet.timestamp, packet.sequence_number, len(packet.payload),
                             packet.marker, packet.ssrc))


@dataclass
class Visitor:
    index: int
    phase_s: float
    pc: RTCPeerConnection
    agent: str = ""
    key: str = ""
    voice: Received = field(default_factory=Received)
    video: Received = field(default_factory=Received)
    messages: deque[tuple[float, int, int]] = field(default_factory=deque)  # (arrival, kind, seq)
    connect_s: float = 0.0
    ended_at: float | None = None  # when its connection failed or closed
    ended_as: str = ""

    def on_message(self, message: object) -> None:
        if isinstance(message, bytes) and len(message) >= 8:
            self.messages.append((time.monotonic(), message[2], FACE_SEQ.unpack_from(message, 4)[0]))

    def on_state(self) -> None:
        state = self.pc.connectionState
        if state in ("failed", "closed") and self.ended_at is None:
            self.ended_at, self.ended_as = time.monotonic(), state


async def post(session: aiohttp.ClientSession, url: str, body: dict[str, Any]) -> tuple[int, Any]:
    async with session.post(url, json=body) as response:
        text = await response.text()
        try:
            return response.status, json.loads(text)
        except json.JSONDecodeError:
            return response.status, text


async def arrive(session: aiohttp.ClientSession, args: argparse.Namespace, index: int, phase_s: float,
                 speech: list[bytes], silence: bytes) -> tuple[Visitor | None, dict[str, Any]]:
    """One visitor: its conversation, its offer, connected. (None, why) when any step is refused."""
    t0 = time.monotonic()
    async with aiohttp.ClientSession(timeout=session.timeout, cookie_jar=aiohttp.CookieJar(unsafe=True)) as page:
        # cookies of its own, as a browser's page has: behind a load balancer its sticky cookie keeps it on its host
        return await _arrive(page, args, index, phase_s, speech, silence, t0)


async def _arrive(session: aiohttp.ClientSession, args: argparse.Namespace, index: int, phase_s: float,
                  speech: list[bytes], silence: bytes, t0: float) -> tuple[Visitor | None, dict[str, Any]]:
    status, made = await post(session, args.url + "conversation", {})
    if status != 201:
        return None, {"index": index, "step": "conversation", "status": status, "error": str(made)[:300]}
    visitor = Visitor(index, phase_s, RTCPeerConnection(RTCConfiguration(iceServers=[])), made["agent"], made["key"])
    pc = visitor.pc
    pc.on("connectionstatechange", visitor.on_state)
    mic = pc.addTransceiver(MicTrack(speech, silence, args.epoch_ns, int(phase_s * 1e9), int(args.cycle_s * 1e9),
                                     int(args.user_at_s * 1e9)), direction="sendonly")  # first, as the page does
    sections = []
    if args.draw == "browser":
        channel = pc.createDataChannel("eca-face", ordered=False, maxRetransmits=0)
        channel.on("message", visitor.on_message)
    else:
        sections.append((pc.addTransceiver("video", direction="recvonly"), "video"))
    sections.append((pc.addTransceiver("audio", direction="recvonly"), "audio"))
    await pc.setLocalDescription(await pc.createOffer())
    body = {"type": "offer", "sdp": pc.localDescription.sdp, "token": None, "agents": [visitor.agent],
            "video": {"width": args.width, "height": args.height, "fps": args.fps},
            "streams": [{"mid": t.mid, "agent": visitor.agent, "kind": k} for t, k in sections],
            "mic_mid": mic.mid, "draw_here": [visitor.agent] if args.draw == "browser" else [], "key": visitor.key}
    status, answer = await post(session, args.url + "offer", body)
    if status != 200:
        await pc.close()
        return None, {"index": index, "agent": visitor.agent, "step": "offer", "status": status,
                      "error": str(answer)[:300]}
    await pc.setRemoteDescription(RTCSessionDescription(sdp=answer["sdp"], type="answer"))
    mic_track = mic.sender.track
    if isinstance(mic_track, MicTrack):
        mic_track.dtx = asks_dtx(answer["sdp"], mic.mid)
    for transceiver, kind in sections:
        transceiver.receiver.__dict__["_bench_record"] = (visitor.voice if kind == "audio" else visitor.video).add
        drop_on_loop(transceiver.receiver)  # its track exists now, and it starts receiving once connected
    deadline = time.monotonic() + CONNECT_TIMEOUT_S
    while pc.connectionState != "connected" and time.monotonic() < deadline and visitor.ended_at is None:
        await asyncio.sleep(0.05)  # polling the connection's state
    if pc.connectionState != "connected":
        state = pc.connectionState
        await pc.close()
        return None, {"index": index, "agent": visitor.agent, "step": "connect", "status": state,
                      "error": f"not connected within {CONNECT_TIMEOUT_S:g} s"}
    visitor.connect_s = time.monotonic() - t0
    return visitor, {}


# --- what a window shows -------------------------------------------------------------------------------------


def voice_stats(received: Received, t0: float, t1: float, gap_s: float, silence_bytes: int,
                split_packets: int, lags: np.ndarray) -> dict[str, Any]:
    """The voice between t0 and t1: arrival gaps, RTP timestamp jumps, lost packets, and its sounding runs (the
    agent's turns): each run's packets that sound and the frames inside it that are silent or missing (holes).

    A voice may pause in silence (the server skips silent frames for a page that draws the face: its RTP
    timestamps then jump by whole frames): everything is judged on the RTP clock. A gap is a packet that
    arrived more than `gap_s - 20 ms` later than its RTP time after the one before it says (for a voice that
    never pauses: packets over `gap_s` apart); a jump is a timestamp step that is not a whole number of frames,
    or fewer frames than packets; a run ends at `split_packets` frames of silence, sent or skipped.

    A gap during which this process's own loop stalled (a tick of `lags`, (time, lateness) rows, ending within
    it or just after it, late by at least half the gap) is counted apart: the packets may have been on time."""
    rows = [p for p in received.packets if t0 <= p[0] <= t1]
    out: dict[str, Any] = {"packets": len(rows), "gaps": 0, "gaps_client_stalled": 0, "max_gap_ms": 0.0,
                           "max_gap_client_on_time_ms": 0.0, "ts_jumps": 0, "lost": 0, "runs": [],
                           "skipped_frames": 0}
    if len(rows) < 2:
        return out
    arrivals = np.array([r[0] for r in rows])
    ts = np.array([r[1] for r in rows], dtype=np.int64)
    seq = np.array([r[2] for r in rows], dtype=np.int64)
    ts_steps = (np.diff(ts) + (1 << 32)) % (1 << 32)
    seq_steps = (np.diff(seq) + (1 << 16)) % (1 << 16)
    frame_steps = ts_steps // OPUS_FRAME
    late = np.diff(arrivals) - ts_steps / OPUS_RATE  # how much later than its RTP time after the one before
    is_gap = late > gap_s - OPUS_FRAME / OPUS_RATE
    out["gaps"] = int(np.sum(is_gap))
    out["max_gap_ms"] = round(float(late.max() + OPUS_FRAME / OPUS_RATE) * 1e3, 1)
    on_time = 0.0
    for i in np.flatnonzero(is_gap).tolist():
        a, b = float(arrivals[i]), float(arrivals[i + 1])
        near = lags[(lags[:, 0] >= a) & (lags[:, 0] <= b + 0.1), 1] if lags.size else np.empty(0)
        if near.size and near.max() >= 0.5 * float(late[i]):
            out["gaps_client_stalled"] += 1
        else:
            on_time = max(on_time, float(late[i]) + OPUS_FRAME / OPUS_RATE)
    out["max_gap_client_on_time_ms"] = round(on_time * 1e3, 1)
    out["ts_jumps"] = int(np.sum((ts_steps % OPUS_FRAME != 0) | (frame_steps < np.maximum(seq_steps, 1))))
    out["lost"] = int(np.sum(np.maximum(seq_steps - 1, 0)))
    out["skipped_frames"] = int(np.sum(np.maximum(frame_steps - np.maximum(seq_steps, 1), 0)))
    # each packet's frame number on the RTP clock; a frame with no packet is silence (skipped or lost)
    frames = np.concatenate(([0], np.cumsum(frame_steps)))
    runs: list[tuple[int, int, int, int]] = []
    start: int | None = None
    last, holes, count = 0, 0, 0
    for i, row in enumerate(rows):
        if row[3] <= silence_bytes:
            continue
        if start is not None and frames[i] - frames[last] - 1 >= split_packets:
            runs.append((start, last, count, holes))
            start = None
        if start is None:
            start, holes, count = i, 0, 0
        else:
            holes += int(frames[i] - frames[last] - 1)  # silent frames, sent or not, inside the run
        count += 1
        last = i
    # a run touching the window's edges is cut: only whole runs are judged, those that began and ended (a
    # silence of `split_packets` frames, sent or not) inside it
    edge_s = split_packets * OPUS_FRAME / OPUS_RATE + 0.1
    if start is not None and t1 - float(arrivals[last]) >= edge_s:
        runs.append((start, last, count, holes))
    out["runs"] = [{"t": round(float(arrivals[a]), 3), "sounding": c, "holes": h,
                    "span_ms": round(float((int(ts[b]) - int(ts[a])) % (1 << 32)) / OPUS_RATE * 1e3 + 20, 1)}
                   for a, b, c, h in runs if float(arrivals[a]) - t0 >= edge_s]
    return out


def face_stats(visitor: Visitor, t0: float, t1: float) -> dict[str, Any]:
    frames = [(t, s) for t, kind, s in visitor.messages if kind == FACE_KIND and t0 <= t <= t1]
    clocks = sum(1 for t, kind, _ in visitor.messages if kind == VOICE_CLOCK_KIND and t0 <= t <= t1)
    out: dict[str, Any] = {"frames": len(frames), "fps": round(len(frames) / (t1 - t0), 2), "voice_clocks": clocks}
    if len(frames) >= 2:
        times = np.array([t for t, _ in frames])
        out["max_gap_ms"] = round(float(np.diff(times).max()) * 1e3, 1)
        seqs = [s for _, s in frames]
        out["seq_skipped"] = int(sum(max(0, (b - a) % (1 << 32) - 1) for a, b in zip(seqs, seqs[1:], strict=False)
                                     if (b - a) % (1 << 32) < 1 << 31))
    return out


def video_stats(received: Received, t0: float, t1: float) -> dict[str, Any]:
    """Pictures received (a marker bit ends each), on the main stream (RTX, another SSRC, left out)."""
    rows = [p for p in received.packets if t0 <= p[0] <= t1]
    if not rows:
        return {"frames": 0, "fps": 0.0}
    ssrcs: dict[int, int] = {}
    for r in rows:
        ssrcs[r[5]] = ssrcs.get(r[5], 0) + 1
    main = max(ssrcs, key=lambda s: ssrcs[s])
    ends = [r[0] for r in rows if r[5] == main and r[4]]
    out: dict[str, Any] = {"frames": len(ends), "fps": round(len(ends) / (t1 - t0), 2)}
    if len(ends) >= 2:
        out["max_gap_ms"] = round(float(np.diff(np.array(ends)).max()) * 1e3, 1)
    return out


def trim(visitor: Visitor, before: float) -> None:
    for queue_ in (visitor.voice.packets, visitor.video.packets, visitor.messages):
        while queue_ and queue_[0][0] < before:
            queue_.popleft()


# --- the process -------------------------------------------------------------------------------------------


class LoopLag:
    """How late this process's event loop wakes (a 10 ms tick): a late visitor's packets arrive late too."""

    def __init__(self) -> None:
        self.samples: deque[tuple[float, float]] = deque()

    async def run(self) -> None:
        while True:
            before = time.monotonic()
            await asyncio.sleep(LAG_TICK_S)  # the tick whose lateness is measured
            now = time.monotonic()
            self.samples.append((now, now - before - LAG_TICK_S))

    def rows(self, t0: float, t1: float) -> np.ndarray:
        """(time, lateness) of the ticks between t0 and t1, as an n x 2 array."""
        got = [(t, lag) for t, lag in self.samples if t0 <= t <= t1]
        return np.array(got, dtype=float).reshape(-1, 2)

    def window(self, t0: float, t1: float) -> dict[str, float]:
        lags = self.rows(t0, t1)[:, 1]
        while self.samples and self.samples[0][0] < t0 - 5.0:
            self.samples.popleft()
        if lags.size == 0:
            return {}
        return {"p99_ms": round(float(np.percentile(lags, 99)) * 1e3, 1), "max_ms": round(float(lags.max()) * 1e3, 1),
                "stalled_over_60ms": int(np.sum(lags > 0.060))}


async def add_visitors(session: aiohttp.ClientSession, args: argparse.Namespace, specs: list[dict[str, Any]],
                       speech: list[bytes], silence: bytes, visitors: list[Visitor]) -> tuple[list[Any], list[Any]]:
    """Visitors arriving, CONCURRENCY at a time: those connected (added to `visitors`) and those refused."""
    added: list[dict[str, Any]] = []
    failed: list[dict[str, Any]] = []
    gate = asyncio.Semaphore(CONCURRENCY)

    async def one(spec: dict[str, Any]) -> None:
        async with gate:
            try:
                visitor, why = await arrive(session, args, spec["index"], spec["phase_s"], speech, silence)
            except Exception as exc:  # a visitor that fails is reported, the others go on
                visitor, why = None, {"index": spec["index"], "step": "exception",
                                      "error": f"{type(exc).__name__}: {exc}"[:300]}
        if visitor is None:
            failed.append(why)
        else:
            visitors.append(visitor)
            added.append({"index": visitor.index, "agent": visitor.agent, "connect_s": round(visitor.connect_s, 2)})

    await asyncio.gather(*(one(spec) for spec in specs))
    return added, failed


async def serve(args: argparse.Namespace) -> None:
    lines = stdin_lines()
    speech, silence = encode_speech(args.mic)
    visitors: list[Visitor] = []
    lag = LoopLag()
    lag_task = asyncio.ensure_future(lag.run())

    async with aiohttp.ClientSession(timeout=aiohttp.ClientTimeout(total=60)) as session:
        try:
            while (line := await lines.get()) is not None:
                if not line:
                    continue
                cmd = json.loads(line)
                op = cmd.get("op")
                if op == "hello":
                    say({"op": "hello", "speech_packets": len(speech), "silence_bytes": len(silence),
                         "scheduling": args.scheduling})
                elif op == "add":
                    added, failed = await add_visitors(session, args, cmd["visitors"], speech, silence, visitors)
                    # a browser's network stack has no collector that stops it: what the visitors hold leaves the
                    # cyclic collector's view, as the server's services do with theirs (heap.freeze_startup_objects)
                    gc.collect()
                    gc.freeze()
                    say({"op": "add", "added": added, "failed": failed})
                elif op == "window":
                    t0, t1 = cmd["t0"], cmd["t1"]
                    lags = lag.rows(t0 - 1.0, t1 + 1.0)
                    per = []
                    for v in visitors:
                        row: dict[str, Any] = {
                            "index": v.index, "agent": v.agent, "state": v.pc.connectionState,
                            "ended_at": v.ended_at, "ended_as": v.ended_as,
                            "voice": voice_stats(v.voice, t0, t1, cmd["gap_ms"] / 1e3, cmd["silence_bytes"],
                                                 cmd["split_packets"], lags)}
                        if args.draw == "browser":
                            row["face"] = face_stats(v, t0, t1)
                        else:
                            row["video"] = video_stats(v.video, t0, t1)
                        per.append(row)
                        trim(v, t0)
                    say({"op": "window", "visitors": per, "loop_lag": lag.window(t0, t1)})
                elif op == "close":
                    for v in visitors:
                        await v.pc.close()
                    say({"op": "close", "closed": len(visitors)})
                    visitors.clear()
                else:
                    say({"op": op, "error": "unknown command"})
        finally:
            lag_task.cancel()
            for v in visitors:
                await v.pc.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--url", required=True)
    parser.add_argument("--draw", choices=("browser", "server"), required=True)
    parser.add_argument("--mic", required=True, help="the user's sentence (WAV)")
    parser.add_argument("--epoch-ns", type=int, required=True, help="the conversations' time zero (monotonic ns)")
    parser.add_argument("--cycle-s", type=float, default=8.0)
    parser.add_argument("--user-at-s", type=float, default=0.0)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--realtime-priority", type=int, default=0,
                        help="run at SCHED_RR this priority, as the server's voice path does (0: ordinary)")
    args = parser.parse_args(argv)
    # before the loop makes a thread: they inherit it
    args.scheduling = ask_for_realtime("visitors", RealtimeSettings(args.realtime_priority, ("visitors",))) or ""
    # the same event loop as the server's web service (web/event_loop.py): the visitors stand for browsers, whose
    # network stacks are not Python's, so the machine's CPU goes to the server's side as far as it can
    from eca.services.processes.web.event_loop import new_event_loop

    with asyncio.Runner(loop_factory=new_event_loop) as runner:
        runner.run(serve(args))
    return 0


if __name__ == "__main__":
    sys.exit(main())
