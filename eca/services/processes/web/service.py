"""The web service: the live agent in a person's browser, over WebRTC (`eca up --web`, `eca web`).

One process, two loops. The service's own loop (this thread, like every eca service) follows the bus,
draws each watched agent's face headless at every frame slot, once however many viewers watch it, and
hands the pictures and the agents' voice blocks (`stream.<agent>.voice`, from the audio service: the
master clock) to the feeds; it also publishes what the pages send (their commands, the microphone's
turns and audio). An asyncio loop on a second thread serves the page and the WebRTC peers
(services/processes/web/server.py, viewers.py), whose tracks take from the feeds. Nothing is drawn while no one
watches.
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import logging
import math
import os
import queue
import shlex
import statistics
import sys
import threading
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
from aiohttp import web

from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import AgentsState, CreateAgent, Error, Message, RemoveAgent, VoiceBlock
from eca.services.processes.renderer import (
    Drawers,
    HeadlessContextError,
    OffscreenCanvas,
    Stage,
    YuvTarget,
    agent_faces,
)
from eca.services.processes.runtime import CannotStart, Rejected, Service
from eca.services.processes.scene.bus_scene import BusScenes
from eca.services.processes.scene.schedule import FrameSchedule
from eca.services.processes.web.conversations import Busy, Conversation, Conversations
from eca.services.processes.web.encoding import EncodedStreams
from eca.services.processes.web.event_loop import EventLoopThread
from eca.services.processes.web.face_frames import FaceFrames
from eca.services.processes.web.feeds import FrameFeed, Picture, VoiceFeed
from eca.services.processes.web.ice_gathering import check_interfaces
from eca.services.processes.web.janus import JanusError, check_server
from eca.services.processes.web.options import WebOptions, WebOptionsError, add_arguments, options_from
from eca.services.processes.web.server import make_app
from eca.services.processes.web.sfu import MAX_DATA_BYTES, SfuError, SfuPublisher
from eca.services.processes.web.viewers import Viewers, ViewRequest

MAX_SUBMITTED = 10_000  # messages from the pages waiting for the bus loop; past that they are dropped
_WAIT_S = 0.01  # the loop's longest wait while viewers watch: how soon a page's command goes out
# A commanded change (emotion, head, role, eye mode) is drawn at once rather than at the next frame slot,
# by drawing that slot early, but never sooner than this share of a frame period after the last frame:
# the frame rate stays the schedule's, however fast commands come.
EARLY_GAP = 0.25
CREATE_TIMEOUT_S = 10.0  # a page waits this long for its conversation's agent at most
REAP_EVERY_NS = 250_000_000  # how often ended conversations are looked for


@dataclass(frozen=True)
class DrawPlan:
    """What the viewers ask for: which agents drawn here (video) and which drawn by their pages (face frames), at
    what size and rate (the largest asked)."""

    agents: tuple[str, ...]
    width: int
    height: int
    fps: float
    drawn_by_pages: tuple[str, ...] = ()


class WebService(Service):
    name = "web"

    def __init__(self, config: BusConfig, options: WebOptions | None = None, **kwargs: Any) -> None:
        options = (options or WebOptions()).check()
        self.name = options.service_name  # "web", or "web-i" for a further worker: its heartbeats and log say which
        super().__init__(config, **kwargs)
        self.options = options
        instance_agents = config.agents
        self.agent_ids: list[str] = list(self.options.agents or instance_agents)
        unknown = [a for a in self.agent_ids if a not in instance_agents]
        if unknown:
            raise WebOptionsError(f"[web] agents {unknown} are not agents of this instance "
                                  f"({', '.join(instance_agents)})")
        self.frames = FrameFeed()
        self.encoded = EncodedStreams(self.frames.next_after, self.clock)
        self.voices = {a: VoiceFeed() for a in self.agent_ids}
        self.scenes = BusScenes(self, self.agent_ids)
        try:
            self.faces = dict(zip(self.agent_ids, agent_faces(config.raw, self.agent_ids, self.options.face),
                                  strict=True))
        except ValueError as exc:
            raise WebOptionsError(str(exc)) from None
        self.face_frames = FaceFrames(self.faces, (self.options.width, self.options.height), self.clock)
        self._check_drawing_mode()
        self.conversations: Conversations | None = None
        if self.options.per_visitor:
            self.conversations = Conversations(self.options.connect_timeout_s, self.options.conversation_prefix)
            self.scenes.on_agents = self._on_agents  # before the service connects: the list is subscribed
            self.handle(Error, self._on_error)
        self._creates: queue.SimpleQueue[str] = queue.SimpleQueue()  # conversations' agents to create
        self._left: set[int] = set()  # viewers gone since the bus loop last looked (their conversations end)
        self._gone: deque[str] = deque(maxlen=256)  # agents dropped lately: what still comes for them is dropped
        self._swept = False  # what a previous run of this service left is removed at the first agents list
        self._next_reap_ns = 0
        self.handle(VoiceBlock, self.on_voice)
        self._submitted: queue.SimpleQueue[Message] = queue.SimpleQueue()
        self._warm_up = threading.Event()
        self._no_gl: str | None = None  # why drawing cannot be made ready here, once that is known
        self._lock = threading.Lock()
        self._watching: dict[int, ViewRequest] = {}
        # What the viewers ask for is worked out again only when what it is made of changes (the pages watching,
        # the agents, whether drawing works here): the bus loop wakes hundreds of times a second with many
        # conversations, and a pass over every page's request cost 15-20 us a wake at N = 32-50.
        self._plan_inputs = 0  # bumped (under _lock) at each such change
        self._asked: tuple[int, DrawPlan | None] = (-1, None)  # (_plan_inputs then, the plan worked out)
        self._plan: DrawPlan | None = None
        self._schedule: FrameSchedule | None = None
        self._last_frame_ns = -(1 << 62)  # the time the last frame drawn is shown
        self._draw_times: deque[int] = deque(maxlen=31)
        self._canvas: OffscreenCanvas | None = None
        self._yuv: YuvTarget | None = None
        self._drawers: Drawers | None = None
        self._stages: dict[str, Stage] = {}
        self._events: EventLoopThread | None = None
        self._runner: web.AppRunner | None = None
        self.viewers: Viewers | None = None
        try:  # fail fast too: [web.ice] interfaces that name nothing here leave no address to offer
            self._missing_interfaces = check_interfaces(self.options.ice)
        except ValueError as exc:
            raise WebOptionsError(str(exc)) from None
        self.sfu: SfuPublisher | None = None  # with [web] sfu: the faces published into Janus (web/sfu.py)
        if self.options.sfu is not None:
            try:  # fail fast: a Janus that does not answer now is a wrong URL far more often than a late one
                check_server(self.options.sfu)
            except JanusError as exc:
                raise WebOptionsError(f"--sfu: {exc}") from None
        self.port = self.options.listen_port  # the one bound, once serving (for port 0: whichever was free)
        self.url = ""

    @classmethod
    def from_args(cls, config: BusConfig, argv: list[str], **kwargs: Any) -> WebService:
        # Software GL (Mesa's llvmpipe) rasterizes on a thread per core by default; at a web face's
        # size that costs more CPU than it saves time (measured: 6.1 -> 3.9 ms of CPU a frame at
        # 640x480, the same wall time), CPU the encoders and a browser on the same machine need. A
        # GPU driver ignores this, and a user's own setting wins.
        os.environ.setdefault("LP_NUM_THREADS", "1")
        parser = argparse.ArgumentParser(prog="python -m eca.services.processes.run web", add_help=False,
                                         exit_on_error=False)
        add_arguments(parser)
        parser.add_argument("--web-worker", type=int, default=None)  # `eca up` starts worker i as service web-i
        try:
            args, unknown = parser.parse_known_args(argv)
            if unknown:
                raise WebOptionsError(f"unknown web arguments: {shlex.join(unknown)}")
            return cls(config, options_from(dict(config.raw.get("web", {})), args), **kwargs)
        except (argparse.ArgumentError, WebOptionsError) as exc:
            print(f"[web] ERROR {exc}", file=sys.stderr)
            raise SystemExit(2) from None

    def subscriptions(self) -> list[str]:
        return self.scenes.subscriptions() + [f"stream.{a}.voice" for a in self.agent_ids]

    def _check_drawing_mode(self) -> None:
        if self.options.draw == "browser":
            server_only = [a for a in self.agent_ids if not self.face_frames.drawable(a)]
            if server_only:
                raise WebOptionsError(f"[web] draw = \"browser\" needs a 3D face for every agent; "
                                      f"{', '.join(server_only)} {'has' if len(server_only) == 1 else 'have'} the 2D "
                                      "face, which only the server draws: give --web-face head (or a .glb/.vrm "
                                      "file) or [faces]")

    @property
    def gl_at_start(self) -> bool:
        """Whether drawing is made ready before the service reports ready: only when every page gets video (draw
        = "server"). Otherwise it is made ready when a page is first asked for and may want video (a 2D face, a
        browser without WebGL), while that page loads: an instance at rest holds no GL context nor the 2D
        face's compiled code (some 200 MB), and pages that draw the faces themselves never make it load."""
        # an SFU watches from the start, and wants video unless pages draw every face
        return self.options.draw == "server" or (self.options.sfu is not None and self.options.draw != "browser")

    def expect_viewer(self) -> None:
        """A page was asked for (called on the event loop's thread): get drawing ready, if any page may want
        video, before its offer comes."""
        if self.options.draw != "browser":
            self._warm_up.set()

    # --- what the viewers need (called on the event loop's thread) ------------------------------

    def voice(self, agent: str) -> VoiceFeed:
        return self.voices[agent]

    def sfu_info(self) -> dict[str, Any] | None:
        """Where pages watch through Janus (GET /config's "sfu"), or None without an SFU."""
        return self.sfu.page_info() if self.sfu is not None else None

    def face_slot(self, agent: str) -> int:
        return self.face_frames.slots[agent]

    def watch(self, viewer: int, request: ViewRequest) -> None:
        with self._lock:
            self._watching[viewer] = request
            self._plan_inputs += 1
        if self.conversations is not None:
            for agent in request.agents:
                self.conversations.watched(agent, viewer)

    def unwatch(self, viewer: int) -> None:
        with self._lock:
            self._watching.pop(viewer, None)
            self._left.add(viewer)
            self._plan_inputs += 1

    # --- conversations per visitor (web/conversations.py) ------------------------------------------

    async def create_conversation(self) -> Conversation:
        """A conversation of its own for a page (on the event loop): its agent created and served. Busy when
        none can be made."""
        assert self.conversations is not None
        conversation = self.conversations.begin(self.clock.now_ns(), asyncio.get_running_loop())
        self._creates.put(conversation.agent)
        assert conversation.created is not None
        try:
            await asyncio.wait_for(asyncio.shield(conversation.created), CREATE_TIMEOUT_S)
        except TimeoutError:
            raise Busy("the instance did not make a conversation in time; try again later") from None
        return conversation

    def _on_agents(self, m: AgentsState) -> None:
        """The dialogue service's list of agents (bus loop): serve our conversations' new agents, drop those it no
        longer lists."""
        assert self.conversations is not None
        if not self._swept:
            self._swept = True
            left = self.conversations.left_behind(m.created)
            if left:
                self.log.info("removing %d conversation(s) a previous run of this service left: %s", len(left),
                              ", ".join(left[:8]) + (" ..." if len(left) > 8 else ""))
            for agent in left:
                self.publish(RemoveAgent(agent=agent, request_id=f"web-{agent}-left"))
        became, gone = self.conversations.listed(set(m.agents), len(m.created), m.max_created)
        for conversation in became:
            like = m.like[m.created.index(conversation.agent)] if conversation.agent in m.created else ""
            self._serve_agent(conversation.agent, like)
            self.conversations.ready(conversation)
        for agent in gone:
            self._drop_agent(agent)

    def _on_error(self, m: Error) -> None:
        if self.conversations is not None and self.conversations.is_conversation(m.agent):
            self.conversations.refused(m.agent, m.reason)
            self._unsubscribe(f"error.{m.agent}.")

    def _serve_agent(self, agent: str, like: str) -> None:
        if agent in self.voices:
            return
        template = like if like in self.faces else self.agent_ids[0]
        self.faces[agent] = self.faces[template]
        self.voices[agent] = VoiceFeed()
        self.face_frames.add(agent, self.faces[agent])
        self.scenes.add_agent(agent)
        self.agent_ids.append(agent)
        self._plan_inputs_changed()
        assert self.sub is not None
        self.sub.subscribe(f"stream.{agent}.voice")
        self._unsubscribe(f"error.{agent}.")
        self.log.info("conversation %s: agent created (like %s)", agent, template)

    def _drop_agent(self, agent: str) -> None:
        if agent not in self.voices:
            return
        self._gone.append(agent)
        self.scenes.remove_agent(agent)
        self.voices.pop(agent, None)
        self.faces.pop(agent, None)
        self.face_frames.remove(agent)
        self.frames.forget(agent)
        if agent in self.agent_ids:
            self.agent_ids.remove(agent)
            self._plan_inputs_changed()
        self._unsubscribe(f"stream.{agent}.voice")
        if self._events is not None and self.viewers is not None:
            self._events.loop.call_soon_threadsafe(self.viewers.close_watching, agent)
        self.log.info("conversation %s: agent removed", agent)

    def _unsubscribe(self, prefix: str) -> None:
        if self.sub is not None:
            self.sub.unsubscribe(prefix)

    def _tend_conversations(self, now: int) -> None:
        """Create what pages asked for; remove the conversations whose pages left or never came."""
        assert self.conversations is not None and self.sub is not None
        while True:
            try:
                agent = self._creates.get_nowait()
            except queue.Empty:
                break
            self.sub.subscribe(f"error.{agent}.")  # a refusal (busy) reaches the page at once
            self.publish(CreateAgent(agent=agent, request_id=f"web-{agent}"))
        if now < self._next_reap_ns:
            return
        self._next_reap_ns = now + REAP_EVERY_NS
        with self._lock:
            left, self._left = self._left, set()
        for agent in self.conversations.to_remove(now, left):
            self.publish(RemoveAgent(agent=agent, request_id=f"web-{agent}-end"))
        for agent in self.conversations.forget_unanswered(now, int(2 * CREATE_TIMEOUT_S * 1e9)):
            self._unsubscribe(f"error.{agent}.")

    def submit(self, msg: Message) -> None:
        if self._submitted.qsize() >= MAX_SUBMITTED:
            self.dropped += 1
            return
        self._submitted.put(msg)

    # --- start and stop -------------------------------------------------------------------------

    def setup(self) -> None:
        logging.getLogger("aioice").setLevel(logging.WARNING)  # every ICE check at INFO drowns the service's lines
        for name in self._missing_interfaces:
            self.log.warning("[web.ice] interfaces: %s is not on this host; its addresses are not offered", name)
        self.viewers = Viewers(self, self.options.max_viewers, self.options.vad, self.options.connect_timeout_s,
                               self.options.silent_timeout_s, self.options.ice)
        if self.options.draw != "server":
            self.face_frames.prepare()
        if self.gl_at_start:
            try:
                self._prepare_drawing((self.options.width, self.options.height))  # before ready: _prepare_drawing
            except HeadlessContextError as exc:
                raise CannotStart(str(exc)) from None
        self._events = EventLoopThread().start()
        if self.options.sfu is not None:
            drawable = [a for a in self.agent_ids if self.options.draw != "server" and self.face_frames.drawable(a)]
            faces = tuple(a for a in drawable if self.face_frames.face(a).layout.size <= MAX_DATA_BYTES)
            if self.options.draw == "browser" and len(faces) != len(self.agent_ids):
                big = ", ".join(a for a in drawable if a not in faces)
                raise CannotStart(f"Janus relays data messages of at most {MAX_DATA_BYTES} bytes; the face frames of "
                                  f"{big} are larger (an avatar with many morph targets): use draw = \"auto\" (they "
                                  "go as video) or a smaller avatar")
            publisher = SfuPublisher(self, self.options.sfu, tuple(self.agent_ids), self.options.width,
                                     self.options.height, self.options.fps, faces=faces,
                                     video=self.options.draw != "browser")
            try:
                self._events.call(publisher.start(), timeout_s=30.0)
            except (SfuError, TimeoutError) as exc:
                raise CannotStart(str(exc) or f"Janus at {self.options.sfu} did not make the mountpoints in 30 s") \
                    from None
            self.sfu = publisher
        app = make_app(self, self.viewers, self.options, tuple(self.agent_ids), self.face_frames, self.conversations,
                       self.create_conversation if self.conversations is not None else None)
        try:
            self._runner = self._events.call(self._listen(app), timeout_s=20.0)
        except OSError as exc:
            raise CannotStart(f"cannot listen on {self.options.host}:{self.options.listen_port}: "
                              f"{exc.strerror or exc}") from None
        self.port = int(self._runner.addresses[0][1])
        self.url = self.options.url(self.port)
        self.log.info("serving %s (agents %s)", self.url, ", ".join(self.agent_ids))

    async def _listen(self, app: web.Application) -> web.AppRunner:
        runner = web.AppRunner(app, access_log=None)
        await runner.setup()
        try:
            await web.TCPSite(runner, self.options.host, self.options.listen_port).start()
        except BaseException:
            await runner.cleanup()
            raise
        return runner

    def teardown(self) -> None:
        if self._events is not None:
            if self.sfu is not None:
                try:
                    self._events.call(self.sfu.stop(), timeout_s=10.0)
                except Exception:  # a Janus that will not answer must not keep the process
                    self.log.exception("unpublishing from Janus failed")
            if self.viewers is not None and self._runner is not None:
                try:
                    self._events.call(self._stop_serving(), timeout_s=10.0)
                except Exception:  # a peer that will not close must not keep the process
                    self.log.exception("closing the viewers failed")
            self._events.stop()
        self._release_drawing()

    async def _stop_serving(self) -> None:
        assert self.viewers is not None and self._runner is not None
        await self.viewers.close_all()
        await self._runner.cleanup()

    # --- the loop -------------------------------------------------------------------------------

    def on_voice(self, msg: VoiceBlock) -> None:
        feed = self.voices.get(msg.agent)
        if feed is None:
            if msg.agent in self._gone:
                return  # the last blocks of a conversation that ended
            raise Rejected(f"this web service does not serve agent '{msg.agent}'")
        try:
            feed.add(msg.dac_time_ns, np.frombuffer(msg.pcm, dtype="<i2"), msg.sample_rate)
        except ValueError as exc:
            raise Rejected(str(exc)) from None

    def run_once(self) -> None:
        assert self.sub is not None
        now = self.clock.now_ns()
        self.beat_if_due(now)
        self._publish_submitted()
        if self.conversations is not None:
            self._tend_conversations(now)
        if self._warm_up.is_set():
            self._warm_up.clear()
            if self._yuv is None:  # drawing made ready already (at whatever size pages asked) stays as it is
                self._try_prepare((self.options.width, self.options.height))
        plan = self._current_plan()
        if plan != self._plan:
            self._replan(plan)
        schedule = self._schedule
        if schedule is not None and now >= self._next_draw_ns(schedule):
            self.scenes.drain()
            self.scenes.commanded = False  # this frame shows it
            shown_ns = now + self._lead_ns()
            early = shown_ns < schedule.due_ns
            self._draw(shown_ns if early else schedule.due_ns, early)
            schedule.advance()
        else:
            due = self._next_draw_ns(schedule) if schedule is not None else now + int(0.1e9)
            wait_s = max(0.0, min(_WAIT_S if schedule is not None else 0.1, (due - now) / 1e9))
            if self.sub.socket.poll(math.ceil(wait_s * 1000)):
                self.scenes.drain()  # voice blocks must reach the tracks before their time
        self._check_parent()

    def _lead_ns(self) -> int:
        """How long before its time a frame is drawn: it is shown (sent) once drawn and encoded."""
        return self._typical_draw_ns() + self.encoded.encode_ns

    def _next_draw_ns(self, schedule: FrameSchedule) -> int:
        """When to draw the next slot (its time less the lead), or sooner when a commanded change waits
        to be shown."""
        shown_ns = schedule.early_due_ns(self._last_frame_ns, EARLY_GAP) if self.scenes.commanded else schedule.due_ns
        return shown_ns - self._lead_ns()

    def _publish_submitted(self) -> None:
        while True:
            try:
                msg = self._submitted.get_nowait()
            except queue.Empty:
                return
            self.publish(msg)

    def _plan_inputs_changed(self) -> None:
        with self._lock:
            self._plan_inputs += 1

    def _current_plan(self) -> DrawPlan | None:
        with self._lock:
            inputs = self._plan_inputs
            if self._asked[0] == inputs:
                return self._asked[1]
            requests = list(self._watching.values())
        plan = self._plan_of(requests)
        self._asked = (inputs, plan)
        return plan

    def _plan_of(self, requests: list[ViewRequest]) -> DrawPlan | None:
        if not requests:
            return None
        # one pass over the pages' requests, not over every agent for every page
        wanted_video: set[str] = set()
        wanted_by_pages: set[str] = set()
        for r in requests:
            wanted_by_pages.update(r.drawn_here)
            if self._no_gl is None:
                wanted_video.update(a for a in r.agents if a not in r.drawn_here)
        video = tuple(a for a in self.agent_ids if a in wanted_video)
        by_pages = tuple(a for a in self.agent_ids if a in wanted_by_pages)
        return DrawPlan(video, max(r.width for r in requests), max(r.height for r in requests),
                        max(r.fps for r in requests), by_pages)

    def _replan(self, plan: DrawPlan | None) -> None:
        old = self._plan
        self._plan = plan
        if plan is None:
            self._schedule = None
            self._stages = {}
            for agent in self.agent_ids:
                self.frames.forget(agent)
            self.log.info("no one watching: drawing stopped")
            return
        if plan.agents and not self._try_prepare((plan.width, plan.height)):
            plan = self._plan = dataclasses.replace(plan, agents=())  # the pages' video is missing; said once
        if old is None or old.fps != plan.fps:
            # frames at k / fps of the master clock, whoever watches: at a whole-number rate every whole
            # second is a frame's time (the calibration markers, web/calibration.py, rely on it)
            self._schedule = FrameSchedule(self.clock, plan.fps, t0_ns=0)
        drawers = self._drawers
        self._stages = {v.agent: Stage(drawers(self.faces[v.agent]), [v], fps=plan.fps)
                        for v in self.scenes.views if v.agent in plan.agents and drawers is not None}
        if plan.agents:
            self.log.info("drawing %s at %dx%d, %g fps", ", ".join(plan.agents), plan.width, plan.height, plan.fps)
        if plan.drawn_by_pages:
            self.log.info("face frames of %s at %g fps for the pages that draw them", ", ".join(plan.drawn_by_pages),
                          plan.fps)

    def _prepare_drawing(self, size: tuple[int, int]) -> None:
        """A GL context, renderer and yuv target of `size`, kept while the size stays (also while no one
        watches): making them (the context, the shaders' compilation, the first frame's compiled code)
        takes a second or more on a loaded machine, which the loop must not spend when a viewer comes."""
        if self._yuv is not None and self._yuv.size == size:
            return
        self._release_drawing()
        self._canvas = OffscreenCanvas(size)
        self._drawers = Drawers(self._canvas.ctx, size)
        self._yuv = YuvTarget(self._canvas.ctx, size)
        for view in self.scenes.views:  # each face's drawer made, and its first frame drawn, before anyone watches
            warm_up = Stage(self._drawers(self.faces[view.agent]), [view], fps=self.options.fps)
            warm_up.draw(warm_up.compose(self.clock.now_ns()), self._yuv.fbo)
        self._yuv.read()

    def _try_prepare(self, size: tuple[int, int]) -> bool:
        """Drawing made ready at `size`; False (said once) when this machine cannot draw headless."""
        if self._no_gl is not None:
            return False
        try:
            with self.keeping_alive():  # a second or more on a loaded machine, in one piece
                self._prepare_drawing(size)
        except HeadlessContextError as exc:
            self._no_gl = str(exc)
            self._plan_inputs_changed()
            self.log.error("no video for pages without WebGL: %s", exc)
            return False
        return True

    def _release_drawing(self) -> None:
        self._stages = {}
        self._drawers = None
        if self._yuv is not None:
            self._yuv.release()
            self._yuv = None
        if self._canvas is not None:
            self._canvas.close()
            self._canvas = None
        for agent in self.agent_ids:
            self.frames.forget(agent)

    def _draw(self, frame_ns: int, early: bool = False) -> None:
        """Each watched agent's face for the frame shown at `frame_ns`: a slot's time, drawn that long
        before it as drawing and encoding take, or drawn now (early) to show a commanded change at once.

        A frame's time is when it will leave, drawn and encoded: the browser takes the time a picture is
        sent as the time it shows (the sender's reports), as it does for the voice, sent at its output
        time. It is composed for the middle of its time on screen (half a period later): a change shows
        at the nearest frame, not the next one."""
        assert self._plan is not None and self._schedule is not None
        if self._plan.drawn_by_pages:
            self._send_face_frames(frame_ns, early)
        if not self._stages:
            self._last_frame_ns = frame_ns
            return
        assert self._yuv is not None
        width, height = self._plan.width, self._plan.height
        began = self.clock.now_ns()
        composed_ns = frame_ns + self._schedule.period_ns // 2
        for agent, stage in self._stages.items():
            stage.draw(stage.compose(composed_ns), self._yuv.fbo)
            self.frames.put(agent, Picture(frame_ns, self._yuv.read(), width, height, early))
        self._draw_times.append(self.clock.now_ns() - began)
        self._last_frame_ns = frame_ns

    def _send_face_frames(self, frame_ns: int, early: bool) -> None:
        """The faces pages draw, at `frame_ns` (their frames are composed for their own time: a page shows the
        voice's part of one when that time's sound plays, the rest as it comes)."""
        assert self._plan is not None
        views = [self.scenes.by_agent[a] for a in self._plan.drawn_by_pages]
        frames = self.face_frames.make(views, frame_ns, self._sounding)
        if frames and self._events is not None and self.viewers is not None:
            self._events.loop.call_soon_threadsafe(self.viewers.send_face_frames, frames, frame_ns, early)
            if self.sfu is not None and self.sfu.faces:
                self._events.loop.call_soon_threadsafe(self.sfu.send_face_frames, frames, frame_ns, early)

    def _sounding(self, agent: str, t_ns: int) -> bool:
        feed = self.voices.get(agent)
        return feed is not None and feed.sounding(t_ns)

    def _typical_draw_ns(self) -> int:
        return statistics.median_high(self._draw_times) if self._draw_times else 0
