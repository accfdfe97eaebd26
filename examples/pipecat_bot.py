"""A pipecat voice bot with eca as its face: open the page, speak, and the face listens, answers, changes
its expression and can be interrupted. Runs with no API key and no network.

    pip install 'eca-face[pipecat]'
    python examples/pipecat_bot.py            # then open http://127.0.0.1:7860/ and press Connect

The page at / (eca.pipecat.client_page()) is a small WebRTC client of the bot's SmallWebRTC offer
endpoint (pipecat's peer-to-peer WebRTC transport): the face and the voice come in, the microphone goes
out. pipecat's prebuilt client is served too, at /client/, but it loads a device manager from Daily's
servers, so it connects only where the browser reaches the internet.

The pipeline, per browser that connects:

    transport.input() -> Silero VAD -> user turns -> scripted "LLM" -> espeak-ng TTS -> eca face -> transport.output()

- Silero VAD (as pipecat ships it, the ONNX model inside the package) finds the user's speech; the user
  turn processor turns it into UserStarted/StoppedSpeakingFrames and interrupts the bot when the user
  speaks over it (barge-in);
- the scripted "LLM" answers each finished user turn with the next line of a short script (it cannot
  hear words: there is no speech recognition offline), and some lines first change the face's emotion
  or head through the same tools a real model calls (eca/services/pipecat/tools.py);
- espeak-ng speaks (eca/services/pipecat/tts.py);
- `EcaVideoService` starts a private eca (`eca up`: broker, dialogue, gaze, audio) for the session, turns
  the bot's audio into eca's streamed say, the user's turns into eca's listening state, and pushes the
  face's pictures with the voice (eca/services/pipecat/face.py); the session's end stops that eca.

With OPENAI_API_KEY set (and no --offline), the script and the VAD-only turns give way to pipecat's
OpenAI speech-to-text and LLM, with the face's tools offered to the model; the voice stays espeak-ng.
Daily or LiveKit instead of SmallWebRTC: see "Use eca as the face of a pipecat bot" in the README.

    python examples/pipecat_bot.py [--host 127.0.0.1] [--port 7860] [--eca-instance NAME] [--agent ada]
                                   [--size 640x480] [--fps 30] [--video-lead-s 0] [--no-greeting] [--offline]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import socket
import sys
import uuid
from dataclasses import dataclass
from typing import Any

import uvicorn
from fastapi import FastAPI, HTTPException, Request
from fastapi.responses import HTMLResponse
from loguru import logger
from pipecat.audio.vad.silero import SileroVADAnalyzer
from pipecat.frames.frames import Frame, TTSSpeakFrame, UserStoppedSpeakingFrame
from pipecat.pipeline.pipeline import Pipeline
from pipecat.pipeline.worker import PipelineParams, PipelineWorker
from pipecat.processors.audio.vad_processor import VADProcessor
from pipecat.processors.frame_processor import FrameDirection, FrameProcessor
from pipecat.transports.base_transport import TransportParams
from pipecat.transports.smallwebrtc.connection import SmallWebRTCConnection
from pipecat.transports.smallwebrtc.request_handler import (
    IceCandidate,
    SmallWebRTCPatchRequest,
    SmallWebRTCRequest,
    SmallWebRTCRequestHandler,
)
from pipecat.transports.smallwebrtc.transport import SmallWebRTCTransport
from pipecat.turns.user_start import VADUserTurnStartStrategy
from pipecat.turns.user_stop import SpeechTimeoutUserTurnStopStrategy
from pipecat.turns.user_turn_processor import UserTurnProcessor
from pipecat.turns.user_turn_strategies import UserTurnStrategies
from pipecat.workers.runner import WorkerRunner
from pipecat_ai_small_webrtc_prebuilt.frontend import SmallWebRTCPrebuiltUI

from eca.pipecat import EcaFaceParams, EcaTools, EcaVideoService, EspeakTTSService, client_page

SAMPLE_RATE = 24_000  # the pipeline's output rate: espeak-ng's 22,050 Hz is resampled to it


@dataclass(frozen=True)
class Line:
    text: str
    tool: str = ""  # a face tool called before the line is spoken
    arguments: dict[str, Any] | None = None


GREETING = Line("Hello! I am Ada. Say something, and I will answer you.", "set_emotion",
                {"name": "happy", "intensity": 0.7})
SCRIPT = (
    Line("That is interesting. Tell me more about it.", "set_emotion", {"name": "surprised", "intensity": 0.6}),
    Line("I see. You can interrupt me at any time: just start speaking while I talk, and I will stop and "
         "listen to you. It works in the middle of a long sentence like this one, too.", "move_head",
         {"turn": 0.0, "nod": 0.0, "tilt": 0.3}),
    Line("Oh no. That sounds disappointing.", "set_emotion", {"name": "disappointed", "intensity": 0.8}),
    Line("Well, I am glad we talked. Thank you!", "set_emotion", {"name": "happy", "intensity": 1.0}),
    Line("Let us start again. What would you like to talk about?", "set_emotion", {"name": "natural"}),
)


class ScriptedReplies(FrameProcessor):
    """The offline stand-in for an LLM: at the end of each user turn, the next line of the script (after
    its face tool, if it has one); the greeting when the user connects."""

    def __init__(self, tools: EcaTools, script: tuple[Line, ...] = SCRIPT, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.tools = tools
        self.script = script
        self.turns = 0

    async def say(self, line: Line) -> None:
        if line.tool:
            result = await self.tools.call(line.tool, line.arguments)
            logger.info(f"bot: {line.tool}({line.arguments}) -> {result}")
        logger.info(f"bot: reply {self.turns}: {line.text}")
        await self.push_frame(TTSSpeakFrame(line.text))

    async def process_frame(self, frame: Frame, direction: FrameDirection) -> None:
        await super().process_frame(frame, direction)
        await self.push_frame(frame, direction)
        if isinstance(frame, UserStoppedSpeakingFrame) and direction == FrameDirection.DOWNSTREAM:
            line = self.script[self.turns % len(self.script)]
            self.turns += 1
            await self.say(line)


def transport_for(connection: SmallWebRTCConnection, args: argparse.Namespace) -> SmallWebRTCTransport:
    width, height = args.size
    return SmallWebRTCTransport(webrtc_connection=connection, params=TransportParams(
        audio_in_enabled=True, audio_out_enabled=True, video_out_enabled=True, video_out_is_live=True,
        video_out_width=width, video_out_height=height, video_out_framerate=round(args.fps)))


def face_for(args: argparse.Namespace) -> EcaVideoService:
    width, height = args.size
    return EcaVideoService(EcaFaceParams(agent=args.agent, instance=args.eca_instance,
                                         start_eca=args.eca_instance is None, width=width, height=height,
                                         fps=args.fps, video_lead_s=args.video_lead_s))


def offline_pipeline(transport: SmallWebRTCTransport, face: EcaVideoService) -> tuple[Pipeline, ScriptedReplies]:
    scripted = ScriptedReplies(EcaTools(face))
    turns = UserTurnProcessor(user_turn_strategies=UserTurnStrategies(
        start=[VADUserTurnStartStrategy()],
        stop=[SpeechTimeoutUserTurnStopStrategy(user_speech_timeout=0.6, wait_for_transcript=False)]))
    return Pipeline([transport.input(), VADProcessor(vad_analyzer=SileroVADAnalyzer()), turns, scripted,
                     EspeakTTSService(), face, transport.output()]), scripted


def hosted_services() -> dict[str, Any]:
    """What the hosted path uses (imported only there): pipecat's context aggregators and OpenAI services."""
    from pipecat.processors.aggregators.llm_context import LLMContext
    from pipecat.processors.aggregators.llm_response_universal import (
        LLMContextAggregatorPair,
        LLMUserAggregatorParams,
    )
    from pipecat.services.openai.llm import OpenAILLMService
    from pipecat.services.openai.stt import OpenAISTTService

    return dict(LLMContext=LLMContext, LLMContextAggregatorPair=LLMContextAggregatorPair,
                LLMUserAggregatorParams=LLMUserAggregatorParams, OpenAILLMService=OpenAILLMService,
                OpenAISTTService=OpenAISTTService)


def hosted_pipeline(transport: SmallWebRTCTransport, face: EcaVideoService) -> Pipeline:
    """With OPENAI_API_KEY: OpenAI's speech recognition and model, the face's tools offered to it."""
    hosted = hosted_services()
    key = os.environ["OPENAI_API_KEY"]
    tools = EcaTools(face)
    context = hosted["LLMContext"]([{"role": "system", "content": (
        "You are Ada, a friendly voice assistant with an animated face. Answer in one or two short spoken "
        "sentences. Show your feelings with set_emotion and move your head with move_head when it fits.")}],
        tools=tools.tools_schema())
    aggregators = hosted["LLMContextAggregatorPair"](context, user_params=hosted["LLMUserAggregatorParams"](
        vad_analyzer=SileroVADAnalyzer()))
    return Pipeline([transport.input(), hosted["OpenAISTTService"](api_key=key), aggregators.user(),
                     hosted["OpenAILLMService"](api_key=key), EspeakTTSService(), face, transport.output(),
                     aggregators.assistant()])


async def run_bot(connection: SmallWebRTCConnection, args: argparse.Namespace, runner: WorkerRunner,
                  active: set[PipelineWorker]) -> None:
    transport = transport_for(connection, args)
    face = face_for(args)
    hosted = bool(os.environ.get("OPENAI_API_KEY")) and not args.offline
    scripted: ScriptedReplies | None = None
    if hosted:
        pipeline = hosted_pipeline(transport, face)
    else:
        pipeline, scripted = offline_pipeline(transport, face)
    worker = PipelineWorker(pipeline, params=PipelineParams(audio_out_sample_rate=SAMPLE_RATE),
                            cancel_on_idle_timeout=False)

    @transport.event_handler("on_client_connected")
    async def on_client_connected(transport: Any, client: Any) -> None:
        logger.info("bot: a browser connected")
        if scripted is not None and args.greeting:
            await scripted.say(GREETING)

    @transport.event_handler("on_client_disconnected")
    async def on_client_disconnected(transport: Any, client: Any) -> None:
        logger.info("bot: the browser left")
        await worker.cancel()

    @worker.event_handler("on_pipeline_finished")
    async def on_pipeline_finished(worker: PipelineWorker, frame: Frame) -> None:
        active.discard(worker)

    active.add(worker)
    await runner.add_workers(worker)


def make_app(args: argparse.Namespace, runner: WorkerRunner, active: set[PipelineWorker]) -> FastAPI:
    app = FastAPI()
    handler = SmallWebRTCRequestHandler()  # no ICE servers: host candidates, for loopback or a LAN
    sessions: set[str] = set()

    @app.get("/")
    async def page() -> HTMLResponse:
        return HTMLResponse(client_page())

    app.mount("/client", SmallWebRTCPrebuiltUI)

    @app.post("/start")
    async def start(request: Request) -> dict[str, Any]:
        """The prebuilt client's first call: a session, and no ICE servers (nothing beyond this host)."""
        session_id = str(uuid.uuid4())
        sessions.add(session_id)
        return {"sessionId": session_id, "iceConfig": {"iceServers": []}}

    async def offer(body: dict[str, Any]) -> dict[str, Any]:
        try:
            request = SmallWebRTCRequest(sdp=body["sdp"], type=body["type"], pc_id=body.get("pc_id"),
                                         restart_pc=body.get("restart_pc"))
        except (KeyError, TypeError):
            raise HTTPException(status_code=400, detail="an offer is {sdp, type[, pc_id, restart_pc]}") from None

        async def on_connection(connection: SmallWebRTCConnection) -> None:
            await run_bot(connection, args, runner, active)

        answer = await handler.handle_web_request(request, on_connection)
        if answer is None:
            raise HTTPException(status_code=500, detail="no answer to the offer")
        return answer

    async def candidates(body: dict[str, Any]) -> dict[str, str]:
        try:
            patch = SmallWebRTCPatchRequest(pc_id=body["pc_id"],
                                            candidates=[IceCandidate(**c) for c in body.get("candidates", [])])
        except (KeyError, TypeError):
            raise HTTPException(status_code=400, detail="a patch is {pc_id, candidates}") from None
        await handler.handle_patch_request(patch)
        return {"status": "success"}

    @app.post("/api/offer")
    async def post_offer(request: Request) -> dict[str, Any]:
        return await offer(await request.json())

    @app.patch("/api/offer")
    async def patch_offer(request: Request) -> dict[str, str]:
        return await candidates(await request.json())

    @app.post("/sessions/{session_id}/api/offer")
    async def post_session_offer(session_id: str, request: Request) -> dict[str, Any]:
        if session_id not in sessions:
            raise HTTPException(status_code=404, detail="unknown session: POST /start first")
        return await offer(await request.json())

    @app.patch("/sessions/{session_id}/api/offer")
    async def patch_session_offer(session_id: str, request: Request) -> dict[str, str]:
        if session_id not in sessions:
            raise HTTPException(status_code=404, detail="unknown session: POST /start first")
        return await candidates(await request.json())

    app.state.handler = handler
    return app


async def serve(args: argparse.Namespace) -> None:
    runner = WorkerRunner(handle_sigint=False)
    active: set[PipelineWorker] = set()  # the sessions' pipelines still running
    app = make_app(args, runner, active)
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((args.host, args.port))
    except OSError as exc:  # taken, or not an address of this machine: say so, no traceback
        sock.close()
        raise SystemExit(f"pipecat bot: cannot listen on {args.host}:{args.port}: {exc.strerror or exc}") from None
    port = sock.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning"))
    runner_task = asyncio.create_task(runner.run(auto_end=False))
    print(f"pipecat bot: open http://{args.host}:{port}/ and press Connect", flush=True)
    try:
        await server.serve(sockets=[sock])
    finally:
        # Each session's pipeline is cancelled (its face stops the eca it started), then the peers go.
        for worker in list(active):
            await worker.cancel(reason="the server is stopping")
        await runner.cancel()
        try:
            await asyncio.wait_for(runner_task, timeout=20.0)
        except (TimeoutError, asyncio.CancelledError):
            runner_task.cancel()
        await app.state.handler.close()
        print("pipecat bot: stopped", flush=True)


def parse_size(text: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"a size is WIDTHxHEIGHT, e.g. 640x480; got {text!r}") from None
    return width, height


def port_number(text: str) -> int:
    try:
        port = int(text)
    except ValueError:
        port = -1
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"a port is a whole number in 0..65535, got {text!r}")
    return port


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--host", default="127.0.0.1", help="where to listen (default 127.0.0.1)")
    parser.add_argument("--port", type=port_number, default=7860, help="port (0: a free one; default 7860)")
    parser.add_argument("--eca-instance", default=None,
                        help="drive this running eca instance (default: start a private one per session)")
    parser.add_argument("--agent", default="ada", help="the eca agent (default ada)")
    parser.add_argument("--size", type=parse_size, default=(640, 480), help="video size (default 640x480)")
    parser.add_argument("--fps", type=float, default=30.0, help="video frames per second (default 30)")
    parser.add_argument("--video-lead-s", type=float, default=0.0, help="draw the face this far ahead (s)")
    parser.add_argument("--no-greeting", dest="greeting", action="store_false", help="do not greet on connect")
    parser.add_argument("--offline", action="store_true", help="the script even when OPENAI_API_KEY is set")
    args = parser.parse_args(argv)
    try:
        EcaFaceParams(agent=args.agent, width=args.size[0], height=args.size[1], fps=args.fps,
                      video_lead_s=args.video_lead_s).check()
    except ValueError as exc:
        parser.error(str(exc))
    try:
        asyncio.run(serve(args))
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
