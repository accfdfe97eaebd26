"""The bench's bot, copied by bench/pipecat.py into a temporary folder and run there: the
documented minimal bot (docs/pipecat.md, "A minimal bot": SmallWebRTC, Silero VAD, user turns, espeak-ng, the
face) on the kind of server the example bot runs (FastAPI and uvicorn, POST /api/offer, a free port), with
eca's face (--face) or the same pipeline without it and without video out. On connect it speaks every line of
--text-file.

    python bench_bot.py --text-file TEXT [--face] [--parent PID] [--setup-timeout-s 20]
"""

from __future__ import annotations

import argparse
import asyncio
import ctypes
import importlib.util
import os
import signal
import socket
import sys
import time
from pathlib import Path
from typing import Any

import uvicorn
from fastapi import FastAPI, Request
from loguru import logger
from pipecat.audio.vad.silero import SileroVADAnalyzer
from pipecat.frames.frames import Frame, TTSSpeakFrame
from pipecat.pipeline.pipeline import Pipeline
from pipecat.pipeline.worker import PipelineParams, PipelineWorker
from pipecat.processors.audio.vad_processor import VADProcessor
from pipecat.transports.base_transport import TransportParams
from pipecat.transports.smallwebrtc.connection import SmallWebRTCConnection
from pipecat.transports.smallwebrtc.request_handler import SmallWebRTCRequest, SmallWebRTCRequestHandler
from pipecat.transports.smallwebrtc.transport import SmallWebRTCTransport
from pipecat.turns.user_start import VADUserTurnStartStrategy
from pipecat.turns.user_stop import SpeechTimeoutUserTurnStopStrategy
from pipecat.turns.user_turn_processor import UserTurnProcessor
from pipecat.turns.user_turn_strategies import UserTurnStrategies
from pipecat.workers.runner import WorkerRunner

WIDTH, HEIGHT, FPS = 640, 480, 30


def espeak_tts() -> type:
    """eca's EspeakTTSService, loaded from its file: `from eca.pipecat import EspeakTTSService` imports the
    package eca.services.pipecat and with it the face (numba, moderngl, zmq, scipy), which the bot without a
    face must not carry. Both variants use this same class."""
    spec = importlib.util.find_spec("eca")
    path = Path(spec.origin).parent / "services" / "pipecat" / "tts.py"
    loaded = importlib.util.spec_from_file_location("bench_espeak_tts", path)
    module = importlib.util.module_from_spec(loaded)
    loaded.loader.exec_module(module)
    return module.EspeakTTSService


async def run_bot(connection: SmallWebRTCConnection, lines: list[str], face: Any, tts: type, setup_timeout_s: float,
                  runner: WorkerRunner, active: set[PipelineWorker]) -> None:
    video = dict(video_out_enabled=True, video_out_is_live=True, video_out_width=WIDTH, video_out_height=HEIGHT,
                 video_out_framerate=FPS) if face else {}
    transport = SmallWebRTCTransport(webrtc_connection=connection, params=TransportParams(
        audio_in_enabled=True, audio_out_enabled=True, **video))
    turns = UserTurnProcessor(user_turn_strategies=UserTurnStrategies(
        start=[VADUserTurnStartStrategy()],
        stop=[SpeechTimeoutUserTurnStopStrategy(user_speech_timeout=0.6, wait_for_transcript=False)]))
    processors = [transport.input(), VADProcessor(vad_analyzer=SileroVADAnalyzer()), turns, tts()]
    if face:
        params, service = face
        processors.append(service(params(start_eca=True, width=WIDTH, height=HEIGHT, fps=FPS)))
    processors.append(transport.output())
    # setup_timeout_secs: pipecat gives a pipeline's set-up 20 s by default, which a cold start (eca's start
    # and the face's compile) can pass on a loaded machine; the bench measures how long it takes instead.
    worker = PipelineWorker(Pipeline(processors), params=PipelineParams(audio_out_sample_rate=24_000),
                            cancel_on_idle_timeout=False, setup_timeout_secs=setup_timeout_s)

    @worker.event_handler("on_pipeline_started")
    async def started(worker: PipelineWorker, frame: Frame) -> None:
        print(f"bench bot: pipeline started at {time.monotonic():.6f}", flush=True)

    @transport.event_handler("on_client_connected")
    async def speak(transport: Any, client: Any) -> None:
        await worker.queue_frames([TTSSpeakFrame(line) for line in lines])

    @transport.event_handler("on_client_disconnected")
    async def leave(transport: Any, client: Any) -> None:
        await worker.cancel()

    @worker.event_handler("on_pipeline_finished")
    async def finished(worker: PipelineWorker, frame: Frame) -> None:
        active.discard(worker)
        print("bench bot: session ended", flush=True)

    active.add(worker)
    await runner.add_workers(worker)


async def serve(lines: list[str], face: Any, tts: type, setup_timeout_s: float) -> None:
    runner = WorkerRunner(handle_sigint=False)
    active: set[PipelineWorker] = set()
    handler = SmallWebRTCRequestHandler()
    app = FastAPI()

    @app.get("/")
    async def alive() -> dict[str, str]:
        return {"bot": "bench"}

    @app.post("/api/offer")
    async def offer(request: Request) -> dict[str, Any]:
        body = await request.json()

        async def on_connection(connection: SmallWebRTCConnection) -> None:
            await run_bot(connection, lines, face, tts, setup_timeout_s, runner, active)

        return await handler.handle_web_request(SmallWebRTCRequest(sdp=body["sdp"], type=body["type"]),
                                                on_connection)

    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind(("127.0.0.1", 0))
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning"))
    runner_task = asyncio.create_task(runner.run(auto_end=False))
    print(f"bench bot: port {sock.getsockname()[1]}", flush=True)
    try:
        await server.serve(sockets=[sock])
    finally:  # as the example bot: each session is cancelled (its face stops its eca), then the peers go
        for worker in list(active):
            await worker.cancel(reason="the server is stopping")
        await runner.cancel()
        try:
            await asyncio.wait_for(runner_task, timeout=20.0)
        except (TimeoutError, asyncio.CancelledError):
            runner_task.cancel()
        await handler.close()
        print("bench bot: stopped", flush=True)


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--text-file", required=True)
    parser.add_argument("--face", action="store_true")
    parser.add_argument("--parent", type=int, default=0)
    parser.add_argument("--setup-timeout-s", type=float, default=20.0)
    args = parser.parse_args()
    if args.parent:  # SIGINT when the bench dies, even by SIGKILL: the bot then ends its sessions itself
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGINT)  # PR_SET_PDEATHSIG
        if os.getppid() != args.parent:
            return 1
    logger.remove()  # a deployment logs at INFO; pipecat's default DEBUG would be the bench's cost, not the bot's
    logger.add(sys.stderr, level="INFO")
    face = None
    if args.face:
        from eca.pipecat import EcaFaceParams, EcaVideoService

        face = (EcaFaceParams, EcaVideoService)
    lines = [line for line in Path(args.text_file).read_text().splitlines() if line.strip()]
    try:
        asyncio.run(serve(lines, face, espeak_tts(), args.setup_timeout_s))
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
