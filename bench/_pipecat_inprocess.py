"""Bench part for bench/pipecat.py, phases 1-3: pipecat pipelines in the bench's process against a running eca, with
the face and without it: the first audio frame, the A/V offset and the CPU (see bench/pipecat.py's docstring)."""

from __future__ import annotations

import argparse
import asyncio
import random
import statistics
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

from bench._pipecat_common import (
    AGENT,
    BURST_GAP_S,
    BURST_LEVEL,
    BURST_S,
    CPU_BASELINE_BURSTS,
    EDGE_WINDOW_MS,
    FPS,
    FRAME_MS,
    HEIGHT,
    MAX_SHIFT_MS,
    MOUTH_BOX,
    REPLIES,
    TTS_RATE,
    WIDTH,
    process_cpu_s,
    progress,
    tree_cpu_s,
)
from bench.report import Report, percentile

# --- pipelines ----------------------------------------------------------------------------------------


def pipecat_parts() -> dict[str, Any]:
    """pipecat's classes and the bench's processors built on them (imported late: pipecat may be missing)."""
    from pipecat.frames.frames import Frame, TTSAudioRawFrame
    from pipecat.pipeline.pipeline import Pipeline
    from pipecat.pipeline.worker import PipelineParams, PipelineWorker
    from pipecat.processors.frame_processor import FrameDirection, FrameProcessor
    from pipecat.services.settings import TTSSettings
    from pipecat.services.tts_service import TTSService
    from pipecat.workers.runner import WorkerRunner

    class Output(FrameProcessor):
        """Where the transport would be: notes when each frame arrives (direct mode: no queue)."""

        def __init__(self) -> None:
            super().__init__(enable_direct_mode=True)
            self.seen: list[tuple[int, Frame]] = []
            self.first_audio: asyncio.Future[int] | None = None

        async def process_frame(self, frame: Frame, direction: FrameDirection) -> None:
            await super().process_frame(frame, direction)
            if direction == FrameDirection.DOWNSTREAM:
                now = time.monotonic_ns()
                self.seen.append((now, frame))
                if isinstance(frame, TTSAudioRawFrame) and self.first_audio is not None \
                        and not self.first_audio.done():
                    self.first_audio.set_result(now)
            await self.push_frame(frame, direction)

    class CannedTTS(TTSService):
        """pipecat's TTS machinery speaking audio synthesised before the run."""

        def __init__(self, speech: dict[str, bytes]) -> None:
            super().__init__(push_start_frame=True, push_stop_frames=True, sample_rate=TTS_RATE,
                             settings=TTSSettings(model=None, voice=None, language=None))
            self.speech = speech

        async def run_tts(self, text: str, context_id: str) -> Any:
            pcm = self.speech[text]
            step = TTS_RATE * FRAME_MS // 1000 * 2
            for start in range(0, len(pcm), step):
                yield TTSAudioRawFrame(pcm[start:start + step], TTS_RATE, 1, context_id=context_id)

    return dict(Pipeline=Pipeline, PipelineParams=PipelineParams, PipelineWorker=PipelineWorker,
                WorkerRunner=WorkerRunner, Output=Output, CannedTTS=CannedTTS)


@asynccontextmanager
async def pipeline_running(parts: dict[str, Any], processors: list[Any]) -> AsyncIterator[Any]:
    """A pipeline of `processors` running until the block ends (then an EndFrame and its end)."""
    from pipecat.frames.frames import EndFrame

    worker = parts["PipelineWorker"](parts["Pipeline"](processors), cancel_on_idle_timeout=False,
                                     params=parts["PipelineParams"](audio_out_sample_rate=TTS_RATE))
    started = asyncio.Event()

    @worker.event_handler("on_pipeline_started")
    async def on_started(worker: Any, frame: Any) -> None:
        started.set()

    runner = parts["WorkerRunner"](handle_sigint=False)
    await runner.add_workers(worker)
    task = asyncio.create_task(runner.run())
    try:
        await asyncio.wait_for(started.wait(), 30.0)
        yield worker
    finally:
        await worker.queue_frame(EndFrame())
        try:
            await asyncio.wait_for(task, 30.0)
        except TimeoutError:
            task.cancel()


def face(instance: str) -> Any:
    from eca.services.pipecat import EcaFaceParams, EcaVideoService

    return EcaVideoService(EcaFaceParams(agent=AGENT, instance=instance, width=WIDTH, height=HEIGHT, fps=FPS))


# --- 1. first audio frame ----------------------------------------------------------------------------


async def latency_block(parts: dict[str, Any], instance: str, with_face: bool, speech: dict[str, bytes],
                        replies: int, spacing_s: float) -> list[float]:
    from pipecat.frames.frames import TTSSpeakFrame

    output = parts["Output"]()
    processors = [parts["CannedTTS"](speech), *([face(instance)] if with_face else []), output]
    latencies: list[float] = []
    async with pipeline_running(parts, processors) as worker:
        await asyncio.sleep(0.5)  # the face's first pictures are out: its steady state
        for k in range(replies):
            output.first_audio = asyncio.get_running_loop().create_future()
            queued = time.monotonic_ns()
            await worker.queue_frame(TTSSpeakFrame(REPLIES[k % len(REPLIES)]))
            arrived = await asyncio.wait_for(output.first_audio, 10.0)
            latencies.append((arrived - queued) / 1e6)
            await asyncio.sleep(spacing_s)  # pacing: the reply plays out before the next
    return latencies


def latency_phase(parts: dict[str, Any], instance: str, args: argparse.Namespace, report: Report) -> None:
    from eca.services.processes.audio.tts import EngineSettings, EspeakSpeech

    engine = EspeakSpeech(EngineSettings())
    speech: dict[str, bytes] = {}
    for text in REPLIES:
        samples, rate = engine.speak(text)
        resampled = np.interp(np.arange(round(len(samples) * TTS_RATE / rate)) * rate / TTS_RATE,
                              np.arange(len(samples)), samples)
        speech[text] = (np.clip(resampled, -1, 1) * 32767).astype("<i2").tobytes()
    with_face: list[float] = []
    without: list[float] = []
    for block in "ABBAABBA":
        progress(f"first audio frame: block {block} ({'with' if block == 'A' else 'without'} the face)")
        got = asyncio.run(latency_block(parts, instance, block == "A", speech, args.replies, args.spacing_s))
        (with_face if block == "A" else without).extend(got)
    added = statistics.median(with_face) - statistics.median(without)
    added_p95 = percentile(with_face, 0.95) - percentile(without, 0.95)
    report.add("first audio frame: added by the face (median)", round(added, 2), "<= 20 ms", added <= 20.0, "ms",
               f"{len(with_face)} replies each way, blocks ABBAABBA")
    report.add("first audio frame: with the face (median)", round(statistics.median(with_face), 2), "-", None, "ms",
               f"p95 {percentile(with_face, 0.95):.2f} ms")
    report.add("first audio frame: without (median)", round(statistics.median(without), 2), "-", None, "ms",
               f"p95 {percentile(without, 0.95):.2f} ms")
    report.add("first audio frame: added at p95", round(added_p95, 2), "-", None, "ms")
    report.details["first_audio_ms"] = {"with_face": [round(x, 3) for x in with_face],
                                        "without": [round(x, 3) for x in without]}


# --- 2. A/V offset and 3. CPU -------------------------------------------------------------------------


def voice(samples: int, phase: int) -> np.ndarray:
    t = (np.arange(samples) + phase) / TTS_RATE
    wave = sum(np.sin(2 * np.pi * f * t) / (k + 1) for k, f in enumerate((140, 280, 420, 700, 1100)))
    return (BURST_LEVEL * wave / 2.0 * 32767).astype("<i2")


@dataclass
class AvRun:
    seen: list[tuple[int, Any]]
    bursts: list[np.ndarray]  # each burst's samples
    wall_s: float
    cpu_s: float
    eca_cpu_s: float
    eca_offsets_s: list[float]
    pushed: int
    skipped: int


async def av_block(parts: dict[str, Any], instance: str, eca_pid: int, with_face: bool, gaps_s: list[float]) -> AvRun:
    from pipecat.frames.frames import TTSAudioRawFrame, TTSStartedFrame, TTSStoppedFrame

    output = parts["Output"]()
    the_face = face(instance) if with_face else None
    per_frame = TTS_RATE * FRAME_MS // 1000
    bursts = [voice(round(BURST_S * TTS_RATE), 7919 * i) for i in range(len(gaps_s))]
    async with pipeline_running(parts, [*([the_face] if the_face else []), output]) as worker:
        await asyncio.sleep(0.5)
        cpu0, eca0, t0 = process_cpu_s(), tree_cpu_s(eca_pid), time.monotonic()
        due = time.monotonic()
        for burst, gap_s in zip(bursts, gaps_s, strict=True):
            # A burst at once, in 20 ms frames, as espeak-ng and most TTS services hand over a sentence: the
            # output plays them back to back from the first.
            await worker.queue_frames([TTSStartedFrame(), *(
                TTSAudioRawFrame(burst[start:start + per_frame].tobytes(), TTS_RATE, 1)
                for start in range(0, len(burst), per_frame)), TTSStoppedFrame()])
            due += BURST_S + gap_s
            await asyncio.sleep(max(0.0, due - time.monotonic()))  # onsets on an absolute schedule
        wall = time.monotonic() - t0
        cpu, eca_cpu = process_cpu_s() - cpu0, tree_cpu_s(eca_pid) - eca0
        await asyncio.sleep(0.3)
    return AvRun(output.seen, bursts, wall, cpu, eca_cpu, the_face.eca_offsets_s if the_face else [],
                 the_face.pictures_pushed if the_face else 0, the_face.pictures_skipped if the_face else 0)


def mouth_pixels(frame: Any) -> int:
    width, height = frame.size
    x0, y0, x1, y1 = MOUTH_BOX
    rgb = np.frombuffer(frame.image, np.uint8).reshape(height, width, 3)
    box = rgb[int(y0 * height):int(y1 * height), int(x0 * width):int(x1 * width)].astype(np.int16)
    return int(((box[..., 0] - box[..., 1] > 70) & (box[..., 1] < 90)).sum())


def expected_open(burst: np.ndarray) -> Callable[[float], bool]:
    """The mouth eca's lip-sync gives the burst, offline: open at sample s when its jaw weight is over half
    of its level in the middle of the burst."""
    from eca.agent.lipsync.estimator import mouth_track

    track = mouth_track(burst.astype(np.float32) / 32768.0, TTS_RATE)
    middle = [track.weights_at(s)["say_ah"] for s in range(len(burst) // 3, 2 * len(burst) // 3, 240)]
    half = 0.5 * float(np.median(middle))
    return lambda sample: track.weights_at(sample)["say_ah"] > half


def burst_offsets(run: AvRun) -> tuple[list[float], dict[str, Any]]:
    """Per burst: the shift (ms) of the pictures' push times that best matches their mouths to the sound
    being played; + = the picture shows an earlier moment (video late)."""
    from pipecat.frames.frames import OutputImageRawFrame, TTSAudioRawFrame, TTSStartedFrame

    # When the output plays each burst's sample 0: its frames from their push or the end of the frame before.
    starts: list[int] = []
    heard: list[list[tuple[int, int, int]]] = []  # per burst, each frame: (moment heard, first sample, samples)
    end = 0
    sample = 0
    for t, frame in run.seen:
        if isinstance(frame, TTSStartedFrame):
            heard.append([])
            sample = 0
        elif isinstance(frame, TTSAudioRawFrame) and heard:
            begin = max(t, end)
            n = len(frame.audio) // 2
            heard[-1].append((begin, sample, n))
            sample += n
            end = begin + n * 1_000_000_000 // TTS_RATE
    starts = [h[0][0] for h in heard]
    pictures = [(t, mouth_pixels(f)) for t, f in run.seen if isinstance(f, OutputImageRawFrame)]
    burst_ns = round(BURST_S * 1e9)
    far = [px for t, px in pictures if all(not (s - 0.15e9 < t < s + burst_ns + 0.3e9) for s in starts)]
    inside = [px for t, px in pictures if any(s + 0.08e9 < t < s + burst_ns - 0.05e9 for s in starts)]
    shut, opened = float(np.median(far)), float(np.median(inside))
    threshold = 0.5 * (shut + opened)
    offsets: list[float] = []
    for frames_heard, burst in zip(heard, run.bursts, strict=True):
        is_open = expected_open(burst)
        start, last = frames_heard[0][0], frames_heard[-1][0] + FRAME_MS * 1_000_000

        def expected(moment: float, frames_heard: list[tuple[int, int, int]] = frames_heard,
                     is_open: Callable[[float], bool] = is_open) -> bool:
            before = [frame for frame in frames_heard if frame[0] <= moment]
            if not before:
                return False
            t, first, n = before[-1]
            position = first + (moment - t) * TTS_RATE / 1e9
            return position < first + n and is_open(position)  # past its samples: silence until the next

        near = [(t, px > threshold) for t, px in pictures
                if abs(t - start) <= EDGE_WINDOW_MS * 1e6 or abs(t - last) <= EDGE_WINDOW_MS * 1e6]
        shifts = np.arange(-MAX_SHIFT_MS, MAX_SHIFT_MS + 0.5, 1.0)
        wrong = [sum(shown != expected(t - d * 1e6) for t, shown in near) for d in shifts]
        best = shifts[np.array(wrong) == min(wrong)]
        offsets.append(float(np.median(best)))
    return offsets, {"mouth_pixels_shut": shut, "mouth_pixels_open": opened, "pictures": len(pictures)}


def av_phase(parts: dict[str, Any], instance: str, eca_pid: int, args: argparse.Namespace, report: Report) -> None:
    rng = random.Random(args.seed)
    gaps = [rng.uniform(*BURST_GAP_S) for _ in range(args.bursts)]
    progress(f"A/V offset: {args.bursts} bursts through the face at {WIDTH}x{HEIGHT}, {FPS:g} fps")
    run = asyncio.run(av_block(parts, instance, eca_pid, True, gaps))
    progress(f"CPU baseline: {CPU_BASELINE_BURSTS} bursts through the same pipeline without the face")
    base = asyncio.run(av_block(parts, instance, eca_pid, False, gaps[:CPU_BASELINE_BURSTS]))
    offsets, seen = burst_offsets(run)
    report.details["av"] = {**seen, "burst_offsets_ms": offsets, "gaps_s": [round(g, 3) for g in gaps]}
    med_abs = float(np.median(np.abs(offsets)))
    report.add("A/V offset: median |offset| over bursts", round(med_abs, 1), "<= 15 ms", med_abs <= 15.0, "ms",
               f"{len(offsets)} bursts, pictures judged from pixels")
    report.add("A/V offset: median (+ = video late)", round(float(np.median(offsets)), 1), "-", None, "ms",
               f"p10 {percentile(offsets, 0.1):+.0f}, p90 {percentile(offsets, 0.9):+.0f} ms")
    pictures = [t for t, f in run.seen if type(f).__name__ == "OutputImageRawFrame"]
    rate = (len(pictures) - 1) / ((pictures[-1] - pictures[0]) / 1e9) if len(pictures) > 1 else 0.0
    report.add("pictures pushed per second", round(rate, 2), f">= {0.95 * FPS:g}", rate >= 0.95 * FPS, "fps",
               f"{run.skipped} drawn but replaced before the loop pushed them")
    share = (run.cpu_s / run.wall_s) - (base.cpu_s / base.wall_s)
    report.add("face's CPU share at 30 fps", round(share, 3), "-", None, "cores",
               f"process {run.cpu_s / run.wall_s:.2f} with it, {base.cpu_s / base.wall_s:.2f} without; "
               f"{WIDTH}x{HEIGHT}")
    report.add("eca's own services during it", round(run.eca_cpu_s / run.wall_s, 3), "-", None, "cores",
               "broker, dialogue, gaze, audio (eca up's processes)")
    if run.eca_offsets_s:
        report.add("eca's voice after the pipeline's (median)", round(1000 * statistics.median(run.eca_offsets_s), 1),
                   "-", None, "ms", "eca's DAC time of sample 0 - the transport's, per utterance")
    report.details["cpu"] = {"with_face_s": run.cpu_s, "without_s": base.cpu_s, "wall_with_s": run.wall_s,
                             "wall_without_s": base.wall_s, "eca_s": run.eca_cpu_s}
