"""`EcaVideoService`: an eca face for a pipecat pipeline, placed after the TTS, in the shape of pipecat's
own avatar services (Simli, HeyGen, Tavus), but drawn here, from the pipeline's own audio.

    pipeline = Pipeline([transport.input(), vad, user_turns, llm, tts,
                         EcaVideoService(EcaFaceParams(start_eca=True)),   # the face
                         transport.output()])

What it does with the frames that pass (everything is passed on, in order):
- `TTSAudioRawFrame`: pushed on at once, untouched (audio out = audio in: the same frames, in the same
  order; nothing is held back), then handed to the face's thread, which streams it to eca as a `say`
  with `speech_chunk`s and computes the mouth from it. `TTSStartedFrame` (or a new TTS context id) starts
  a new say, `TTSStoppedFrame` ends it (and a say whose audio has all been heard 0.5 s ago ends anyway);
- `InterruptionFrame`: the mouth closes at once, the picture not yet pushed is dropped (and any drawn
  before the face heard of it), and eca is told to `interrupt` the say (until it acknowledges);
- `UserStartedSpeakingFrame` / `UserStoppedSpeakingFrame`: `user_speech` true / false, so the agent
  listens (eca's listening role and gaze) while the user speaks;
- `EndFrame` waits until the audio already pushed has been played out (its last pictures go with it),
  then stops the face; `CancelFrame` stops it at once. Either stops an eca it started.
And it pushes `OutputImageRawFrame`s (RGB, `width` x `height`, `fps` per second) from its own task.

Timing. The output transport plays the audio frames in real time from when the first arrives, so the
processor knows, for every sample, when the transport plays it (services/pipecat/voice.py). Each picture
is composed for the moment it will be pushed (the measured draw-and-hand-over time ahead) plus
`video_lead_s`, so the mouth in the picture pushed at t is the mouth of the sample the transport plays at
t. pipecat's output transports do not use an image's `pts` (an image is shown when it is written; `pts`
times only non-media frames), so none is set. With `video_out_is_live` the base output transport writes
each image about one frame period after it receives it (its pacing) and SmallWebRTC's video track
sends it on its own 30 fps grid, while audio goes out within its 10-40 ms chunks: the video reaching a
browser trails its audio by a constant of a few tens of ms. `video_lead_s` draws each picture that much
ahead (of the transport's audio timeline) to take that out where a TTS hands its audio over ahead of
time (most do); see docs/pipecat.md for measured values.

Threads. pipecat's loop never touches a ZeroMQ socket: the face's thread (services/pipecat/link.py) owns
the bus sockets and the GL context; the loop hands it audio and events through a queue (with a pipe to
wake it), and it hands back pictures with `call_soon_threadsafe`.
"""

from __future__ import annotations

import asyncio
import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from loguru import logger
from pipecat.frames.frames import (
    CancelFrame,
    EndFrame,
    Frame,
    InterruptionFrame,
    OutputImageRawFrame,
    StartFrame,
    TTSAudioRawFrame,
    TTSStartedFrame,
    TTSStoppedFrame,
    UserStartedSpeakingFrame,
    UserStoppedSpeakingFrame,
)
from pipecat.processors.frame_processor import FrameDirection, FrameProcessor, FrameProcessorSetup

from eca.protocol.codec import is_agent_id
from eca.protocol.endpoints import BusConfig, load_bus_config
from eca.protocol.messages import Ack, Error, Message
from eca.services.pipecat.instance import EcaInstance
from eca.services.pipecat.link import FaceLink, FaceOptions, LinkThread, Picture

NS_PER_S = 1_000_000_000
MAX_DRAIN_WAIT_S = 60.0  # an EndFrame waits at most this long for the pushed audio to be played out


@dataclass(frozen=True)
class EcaFaceParams(FaceOptions):
    """How the face is drawn and which eca it talks to.

    agent: the eca agent id whose face this is.
    instance: the eca instance to connect to (None: the config's, or $ECA_INSTANCE). With `start_eca`,
        the name of the instance to start (None: a private one).
    config_path: eca's runtime config (None: configs/default.toml, or $ECA_CONFIG).
    start_eca: run `eca up` (broker, dialogue, gaze, audio) in the background, stopped with the pipeline.
    video: draw and push pictures; False: only drive eca (another output shows the face).
    width, height, fps: the pictures pushed (the output transport's video_out_* should match).
    video_lead_s: compose each picture this far ahead of the audio pushed with it (0 .. 0.5 s).
    connect_timeout_s: how long to wait for eca's broker (and for `eca up` to be ready).
    command_timeout_s: how long a command (say, interrupt, a tool's) is sent again before giving up.
    seed: the face's idle motion (every random draw of eca is seeded).
    face: "flexor" (the paper's 2D face), "head" (eca's 3D head) or a .glb/.gltf/.vrm file.
    create_agent: make `agent` on the running eca when connecting and remove it at the end (`create_agent`,
        docs/protocol.md "Conversations created at run time"): many bots share one `eca up`, an agent each,
        instead of starting an instance each. Refused when the instance's conversations are all in use.
    like: with `create_agent`, the configured agent whose settings the new one copies ("": the config's template).
    """

    instance: str | None = None
    config_path: str | Path | None = None
    start_eca: bool = False
    connect_timeout_s: float = 10.0
    create_agent: bool = False
    like: str = ""

    def check(self) -> EcaFaceParams:
        """These parameters, checked: ValueError naming the first one out of its range."""
        if not is_agent_id(self.agent) or self.agent == "*":
            raise ValueError(f"agent must be an eca agent id (1-32 of A-Z a-z 0-9 _ -), got {self.agent!r}")
        if not (isinstance(self.width, int) and isinstance(self.height, int)
                and 16 <= self.width <= 4096 and 16 <= self.height <= 4096):
            raise ValueError(f"width and height must be whole numbers of pixels in 16..4096, got "
                             f"{self.width!r} x {self.height!r}")
        if self.width % 2 or self.height % 2:
            raise ValueError(f"width and height must be even (video encoders take 4:2:0), got "
                             f"{self.width}x{self.height}")
        if not 1.0 <= self.fps <= 60.0:
            raise ValueError(f"fps must lie in 1..60, got {self.fps!r}")
        if not 0.0 <= self.video_lead_s <= 0.5:
            raise ValueError(f"video_lead_s must lie in 0..0.5 s, got {self.video_lead_s!r}")
        if self.face != "flexor":
            from eca.services.processes.renderer import check_face  # GL libraries load only here

            check_face(self.face, "face")
        for name in ("connect_timeout_s", "command_timeout_s"):
            if not 0.1 <= getattr(self, name) <= 600:
                raise ValueError(f"{name} must lie in 0.1..600 s, got {getattr(self, name)!r}")
        return self

    def face_options(self) -> FaceOptions:
        """What the link needs of these parameters (the face's own, without how eca is reached)."""
        return FaceOptions(**{f.name: getattr(self, f.name) for f in dataclasses.fields(FaceOptions)})


class FaceNotReady(RuntimeError):
    """A command could not be sent: the face is not connected to eca (yet, with `retry`; or no more)."""

    def __init__(self, reason: str, retry: bool) -> None:
        super().__init__(reason)
        self.retry = retry


class EcaVideoService(FrameProcessor):
    """The eca face as a pipecat processor, placed after the TTS (see the module docstring).

    Pass it `EcaFaceParams`; put it in the pipeline between the TTS and `transport.output()`. Its setup
    (pipecat's, before the StartFrame) connects to eca, starting a private `eca up` with `start_eca`.
    `command()` sends a command for its agent (what `EcaTools` do); `wait_connected()` returns once it
    can. `pictures_pushed`, `pictures_skipped` and `eca_offsets_s` say what it did."""

    def __init__(self, params: EcaFaceParams | None = None, **kwargs: Any) -> None:
        """`params` (default `EcaFaceParams()`: agent ada on the configured instance, 640x480 at 30 fps),
        checked here; `kwargs` go to pipecat's FrameProcessor (a `name`, say)."""
        super().__init__(**kwargs)
        self.params = (params or EcaFaceParams()).check()
        self.instance: EcaInstance | None = None  # the eca this service started, if it did
        self.eca_config: BusConfig | None = None
        self.face_link: FaceLink | None = None  # while connected
        self.stats: FaceLink | None = None  # the latest link, kept after the end for what it counted
        self._thread: LinkThread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._picture: Picture | None = None
        self._picture_ready = asyncio.Event()
        self._pusher: asyncio.Task | None = None
        self._accepting = False  # pictures are pushed between the StartFrame and the end
        self._ended = False  # shut down: a connection still being made is undone when it is there
        self._interrupts = 0  # pictures drawn before the face heard of the latest interruption are stale
        self._context_id: str | None = None
        self._new_utterance = True
        self._heard_end_ns = 0  # when the audio pushed so far has been played out by the transport
        self._handled_siblings: set[int] = set()
        self.pictures_pushed = 0
        self.pictures_skipped = 0  # drawn but replaced by a newer one before the loop could push it
        self._connected = asyncio.Event()  # set once the connection is made, or has failed
        self._connect_error: str | None = None
        self._created: BusConfig | None = None  # the instance this service made its agent on, if it did

    # --- start and stop ---------------------------------------------------------------------------

    async def setup(self, setup: FrameProcessorSetup) -> None:
        """Connect to eca (starting it first with `start_eca`): pipecat sets processors up concurrently
        before the StartFrame, so the pipeline pays for this once, alongside the others' start-up."""
        await super().setup(setup)
        self._loop = asyncio.get_running_loop()
        try:
            await asyncio.to_thread(self._connect)
        except BaseException as exc:
            self._connect_error = f"{self} could not connect to eca: {exc}"
            raise
        finally:
            self._connected.set()

    def _connect(self) -> None:
        p = self.params
        if p.start_eca:
            self.instance = EcaInstance.start(p.instance, p.config_path, timeout_s=max(30.0, p.connect_timeout_s))
            self.eca_config = self.instance.config
        else:
            self.eca_config = load_bus_config(p.config_path, instance=p.instance)
        if p.create_agent:
            self._create_agent(self.eca_config)
        link = FaceLink(self.eca_config, p.face_options(), self._picture_from_thread)
        thread = LinkThread(link)
        try:
            thread.start(timeout_s=p.connect_timeout_s)
        except BaseException:
            self._remove_agent()
            if self.instance is not None:
                self.instance.stop()
                self.instance = None
            try:  # loading the config made the instance's directory; an empty one is no one's
                self.eca_config.runtime_dir.rmdir()
            except OSError:
                pass
            raise
        self.face_link, self._thread, self.stats = link, thread, link
        if self._ended:  # the pipeline ended while this was connecting: what it started goes at once
            thread.stop()
            if self.instance is not None:
                self.instance.stop()
            return
        logger.info(f"{self}: the face of eca agent '{p.agent}' on instance '{self.eca_config.instance}'"
                    + (f", {p.width}x{p.height} at {p.fps:g} fps" if p.video else ", no video"))

    def _create_agent(self, config: BusConfig) -> None:
        """Make this bot's agent on the running eca (with `create_agent`); it goes again at the end."""
        from eca.protocol.client import AgentClient

        p = self.params
        with AgentClient(config, agent=p.agent, source="pipecat-face", timeout_s=p.connect_timeout_s) as client:
            client.wait_applied(client.create_agent(like=p.like), timeout_s=p.connect_timeout_s)
        self._created = config
        logger.info(f"{self}: created eca agent '{p.agent}' on instance '{config.instance}'")

    def _remove_agent(self) -> None:
        config, self._created = self._created, None
        if config is None:
            return
        from eca.protocol.client import AgentClient

        try:
            with AgentClient(config, agent=self.params.agent, source="pipecat-face", timeout_s=5.0) as client:
                client.wait_applied(client.remove_agent(), timeout_s=5.0)
        except Exception as exc:  # eca already gone (stopped first): nothing of the agent is left to remove
            logger.warning(f"{self}: could not remove eca agent '{self.params.agent}': {exc}")

    async def cleanup(self) -> None:
        """pipecat's cleanup (also after a Ctrl-C): stop the face's thread and the eca it started."""
        await super().cleanup()
        await self._shut_down()

    async def _start(self) -> None:
        self._accepting = True
        if self.params.video and self._pusher is None:
            self._pusher = self.create_task(self._push_pictures(), name=f"{self}::pictures")

    async def _shut_down(self) -> None:
        """Stop pushing, stop the face's thread and the eca this service started. Idempotent."""
        self._ended = True
        self._accepting = False
        self._connected.set()  # a command still waiting for the connection learns that there will be none
        if self._pusher is not None:
            await self.cancel_task(self._pusher)
            self._pusher = None
        thread, instance = self._thread, self.instance
        self._thread = None
        self.instance = None
        self.face_link = None
        if thread is not None:
            await asyncio.to_thread(thread.stop)
        await asyncio.to_thread(self._remove_agent)
        if instance is not None:
            await asyncio.to_thread(instance.stop)

    # --- frames -----------------------------------------------------------------------------------

    async def process_frame(self, frame: Frame, direction: FrameDirection) -> None:
        """Pass every frame on, in order, and act on the ones the module docstring lists."""
        await super().process_frame(frame, direction)
        if isinstance(frame, TTSAudioRawFrame) and direction == FrameDirection.DOWNSTREAM:
            pushed_ns = time.monotonic_ns()
            await self.push_frame(frame, direction)  # first: the voice is never held back
            self._on_tts_audio(frame, pushed_ns)
        elif isinstance(frame, StartFrame):
            await self.push_frame(frame, direction)
            await self._start()
        elif isinstance(frame, EndFrame):
            await self._wait_played_out()
            await self._shut_down()
            await self.push_frame(frame, direction)
        elif isinstance(frame, CancelFrame):
            await self._shut_down()
            await self.push_frame(frame, direction)
        elif isinstance(frame, InterruptionFrame):
            await self.push_frame(frame, direction)
            if self._first_of_pair(frame):
                self._interrupt()
        elif isinstance(frame, (UserStartedSpeakingFrame, UserStoppedSpeakingFrame)):
            await self.push_frame(frame, direction)
            if self.face_link is not None and self._first_of_pair(frame):
                self.face_link.submit_user_speaking(isinstance(frame, UserStartedSpeakingFrame))
        elif isinstance(frame, TTSStartedFrame):
            await self.push_frame(frame, direction)
            self._new_utterance = True
        elif isinstance(frame, TTSStoppedFrame):
            await self.push_frame(frame, direction)
            if self.face_link is not None:
                self.face_link.submit_end_of_speech()
            self._new_utterance = True
        else:
            await self.push_frame(frame, direction)

    def _first_of_pair(self, frame: Frame) -> bool:
        """A frame broadcast both ways reaches the face twice when the face sits between its sender and the
        end of the pipeline; only the first of the pair counts."""
        if frame.broadcast_sibling_id in self._handled_siblings:
            self._handled_siblings.discard(frame.broadcast_sibling_id)
            return False
        if frame.broadcast_sibling_id is not None:
            self._handled_siblings.add(frame.id)
            if len(self._handled_siblings) > 1000:
                self._handled_siblings.clear()
        return True

    def _on_tts_audio(self, frame: TTSAudioRawFrame, pushed_ns: int) -> None:
        channels = max(1, frame.num_channels)
        usable = len(frame.audio) // (2 * channels) * 2 * channels
        if usable == 0 or frame.sample_rate <= 0:
            return
        samples = np.frombuffer(frame.audio[:usable], dtype="<i2")
        if channels > 1:  # eca and the lip-sync take mono: the mean of the channels
            samples = samples.reshape(-1, channels).mean(axis=1).round().astype("<i2")
        new = self._new_utterance or frame.context_id != self._context_id
        self._new_utterance = False
        self._context_id = frame.context_id
        start_ns = max(pushed_ns, self._heard_end_ns)
        self._heard_end_ns = start_ns + len(samples) * NS_PER_S // frame.sample_rate
        if self.face_link is not None:
            self.face_link.submit_audio(samples, frame.sample_rate, pushed_ns, new)

    def _interrupt(self) -> None:
        self._picture = None  # drawn before the interruption: its mouth may be open
        self._heard_end_ns = time.monotonic_ns()
        self._new_utterance = True
        if self.face_link is not None:
            self._interrupts += 1  # the face counts the same: its pictures say which it had heard of
            self.face_link.submit_interrupt(time.monotonic_ns(), "interrupted in the pipeline")

    async def _wait_played_out(self) -> None:
        """Until the transport has played the audio pushed so far (pacing to real-time media)."""
        left_s = (self._heard_end_ns - time.monotonic_ns()) / NS_PER_S
        if left_s > 0:
            await asyncio.sleep(min(left_s, MAX_DRAIN_WAIT_S))

    # --- pictures ---------------------------------------------------------------------------------

    def _picture_from_thread(self, picture: Picture) -> None:
        """On the face's thread: hand a drawn picture to the loop."""
        loop = self._loop
        if loop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(self._take_picture, picture)
            except RuntimeError:
                pass  # the loop is closing: the pipeline is over

    def _take_picture(self, picture: Picture) -> None:
        if not self._accepting or picture.interrupts < self._interrupts:
            return  # not started yet, over, or composed before the face knew of the latest interruption
        if self._picture is not None:
            self.pictures_skipped += 1
        self._picture = picture
        self._picture_ready.set()

    async def _push_pictures(self) -> None:
        while True:
            await self._picture_ready.wait()
            self._picture_ready.clear()
            picture, self._picture = self._picture, None
            if picture is None:
                continue
            frame = OutputImageRawFrame(image=picture.rgb, size=(picture.width, picture.height), format="RGB")
            frame.metadata["eca_face"] = {"frame_ns": picture.frame_ns, "drawn_ns": picture.drawn_ns,
                                          "mouth": picture.mouth, "agent": self.params.agent}
            pushed_ns = time.monotonic_ns()
            await self.push_frame(frame)
            self.pictures_pushed += 1
            if self.face_link is not None:
                self.face_link.report_push_latency(pushed_ns - picture.drawn_ns)

    # --- commands (the tools) ---------------------------------------------------------------------

    @property
    def ready_timeout_s(self) -> float:
        """How long a command sent before the face is connected waits for it: starting eca and connecting."""
        p = self.params
        return max(30.0, p.connect_timeout_s) + p.connect_timeout_s if p.start_eca else p.connect_timeout_s

    async def wait_connected(self, timeout_s: float | None = None) -> None:
        """Return once the face is connected to eca (the pipeline's setup connects it). FaceNotReady when it
        is not within `timeout_s` (default `ready_timeout_s`), when connecting failed, or after the end."""
        if self._ended:
            raise FaceNotReady(f"{self} has ended: the pipeline is over", retry=False)
        if self.face_link is None:
            try:
                await asyncio.wait_for(self._connected.wait(), self.ready_timeout_s if timeout_s is None else timeout_s)
            except TimeoutError:
                raise FaceNotReady(f"{self} is not connected to eca yet (it connects when the pipeline starts); "
                                   f"try again in a moment", retry=True) from None
        if self._connect_error is not None:
            raise FaceNotReady(self._connect_error, retry=False)
        if self.face_link is None:
            raise FaceNotReady(f"{self} has ended: the pipeline is over", retry=False)

    async def command(self, msg: Message) -> Ack | Error | None:
        """Send a command for the agent (its `agent` is replaced by this face's, a request id is added when
        it has none) and wait for its acknowledgement: the Ack, the Error that refused it, or None when
        eca did not answer within `command_timeout_s`. A command sent before the face is connected waits
        for it (`wait_connected`), so a bot may call the tools at once, before its pipeline has started.
        ProtocolError for a malformed command; FaceNotReady when the face does not connect in time or has
        ended."""
        await self.wait_connected()
        assert self.face_link is not None
        return await asyncio.wrap_future(self.face_link.submit_command(msg))

    @property
    def eca_offsets_s(self) -> list[float]:
        """Per utterance: how much later eca's master clock plays sample 0 than the pipeline's transport."""
        return list(self.stats.eca_offsets_s) if self.stats is not None else []
