"""The renderer service: the face of one or more agents, live from the bus, in a window or headless.

Each frame slot (schedule.py) it handles every message that has arrived about its agents (bus_scene.py:
states, events, streams), composes each agent's face for the frame's display time (agent/face/scene.py:
eyes on the exact saccade trajectory, mouth at the sample at the DAC), draws the agents side by side
(stage.py), hands the frame to its outputs (outputs.py) and publishes the composed flexors as a
FaceFrame on `stream.<agent>.face_frame`: recorders and tests see exactly what was drawn. The
last-value cache hands a renderer that starts late, or restarts, the current states on subscription,
so its first frame shows them.

Modes: a glfw window where a display exists (keys publish commands, see window.py), otherwise EGL
headless at a fixed frame rate, optionally writing an H.264 MP4 and/or PNG frames, with a progress bar
when the length is known.

Options come from the config's [renderer] table, overridden on the command line (options.py).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import moderngl

from eca.agent.face.composed import ComposedFace
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import FaceFrame
from eca.services.processes.renderer.common import RenderToggles
from eca.services.processes.renderer.faces import Drawers, agent_faces
from eca.services.processes.renderer.options import RendererOptions, options_from
from eca.services.processes.renderer.outputs import (
    Canvas,
    DrawnFrame,
    FinishOutput,
    OffscreenCanvas,
    Output,
    WindowOutput,
    file_outputs,
    output_name,
)
from eca.services.processes.renderer.stage import Stage
from eca.services.processes.runtime import Service
from eca.services.processes.scene.bus_scene import AgentView, BusScenes
from eca.services.processes.scene.schedule import FrameSchedule

if TYPE_CHECKING:
    from eca.services.processes.renderer.window import AgentStatus, Window


class RendererService(Service):
    name = "renderer"

    def __init__(self, config: BusConfig, options: RendererOptions | None = None, **kwargs: Any) -> None:
        super().__init__(config, **kwargs)
        self.options = (options or RendererOptions()).check()
        self.scenes = BusScenes(self, self.options.agent_ids(config), seed=self.options.seed,
                                idle_noise=self.options.idle_noise)
        self.views = self.scenes.views
        self.faces = agent_faces(config.raw, [v.agent for v in self.views], self.options.face)
        self.toggles = RenderToggles(trajectory=False)
        self.view = self.options.view
        self.selected = 0  # the agent keys act on
        self.frame_count = 0  # frames drawn
        self.mode = ""
        self.window: Window | None = None  # in window mode
        self.canvas: Canvas | None = None
        self.stage: Stage | None = None
        self.outputs: list[Output] = []
        self.schedule: FrameSchedule | None = None
        self._progress: Any = None

    @classmethod
    def from_args(cls, config: BusConfig, argv: list[str], **kwargs: Any) -> RendererService:
        try:
            options = options_from(config, argv)
        except ValueError as exc:
            print(f"[renderer] ERROR {exc}", file=sys.stderr)
            raise SystemExit(2) from None
        return cls(config, options, **kwargs)

    def subscriptions(self) -> list[str]:
        return self.scenes.subscriptions()

    def drain(self) -> int:
        """Handle every message waiting on the socket (see BusScenes.drain); returns how many were read."""
        return self.scenes.drain()

    # --- set-up --------------------------------------------------------------------------------

    def setup(self) -> None:
        self.mode = self._open_output()
        self.schedule = FrameSchedule(self.clock, self.options.fps, lead_s=self.options.lead_s,
                                      total=self.options.total_slots)
        if self.schedule.total is not None and self.options.progress:
            from tqdm import tqdm

            self._progress = tqdm(total=self.schedule.total, unit="frame", desc="rendering", file=sys.stderr,
                                  mininterval=0.5)
            self.schedule.on_advance = self._progress.update

    def _open_output(self) -> str:
        from eca.services.processes.renderer.display import display_available

        opts = self.options
        agents = ", ".join(v.agent for v in self.views)
        if opts.mode == "window" or (opts.mode == "auto" and display_available() and not (opts.video or opts.png_dir)):
            from eca.services.processes.renderer.window import WindowError  # glfw loads only where a window is tried

            try:
                self._open_window()
                self.log.info("window mode (display %s): %dx%d at %g fps, agents %s", _display_name(), *opts.size,
                              opts.fps, agents)
                return "window"
            except WindowError as exc:
                if opts.mode == "window":
                    raise
                self.log.info("no window (%s): rendering headless instead", exc)
        canvas = OffscreenCanvas(opts.size)
        self._use_canvas(canvas)
        self.outputs = file_outputs(opts) or [FinishOutput(canvas.ctx)]
        writing = [
            s for s in (opts.video and f"video {opts.video}", opts.png_dir and f"PNG frames in {opts.png_dir}") if s
        ] or ["face frames on the bus only"]
        self.log.info("headless mode (EGL, %s): %dx%d at %g fps, agents %s; writing %s",
                      "forced" if opts.mode == "headless" else "no display", *opts.size, opts.fps, agents,
                      " and ".join(writing))
        return "headless"

    def _open_window(self) -> None:
        from eca.services.processes.renderer.window import Window

        self.window = Window(self.options.size, "eca", vsync=self.options.vsync, on_key=self.on_key)
        self._use_canvas(self.window)
        self.outputs = [WindowOutput(self.window, self.help_line)]

    def _use_canvas(self, canvas: Canvas) -> None:
        self.canvas = canvas
        drawers = Drawers(canvas.ctx, self.options.size).for_faces(self.faces)
        self.stage = Stage(drawers, self.views, fps=self.options.fps, facing_turn=self.options.facing_turn,
                           trail_s=self.options.trail_s)

    # --- the frame loop ------------------------------------------------------------------------

    def run_once(self) -> None:
        assert self.sub is not None and self.schedule is not None
        now = self.clock.now_ns()
        self.beat_if_due(now)
        if self.window is not None:
            self.window.poll()
            if self.window.should_close:
                self.request_stop()
                return
        due = self.schedule.due_ns
        if now >= due:
            self.drain()
            self.render_frame(self.schedule.slot, self.schedule.display_ns)
            self.dropped += self.schedule.advance()
            if self.schedule.finished:
                self.request_stop()
        else:
            # Messages wait in the socket until the frame: one batch per frame costs least, and a frame
            # sees everything that arrived before it either way.
            self._stop.wait(max(0.0, min(due, self._next_beat_ns) - now) / 1e9)
        self._check_parent()

    def render_frame(self, index: int, display_ns: int) -> None:
        assert self.stage is not None and self.canvas is not None
        faces = self.stage.compose(display_ns)
        target = self.canvas.screen
        self.draw(faces, target)
        drawn = DrawnFrame(target, index, display_ns)
        for output in self.outputs:
            output.present(drawn)
        self.frame_count += 1
        if self.options.publish_frames:
            for v, face in zip(self.views, faces, strict=True):
                self.publish(FaceFrame(agent=v.agent, frame_ns=display_ns, flexors=face.frame.as_dict()))

    def draw(self, faces: Sequence[ComposedFace], target: moderngl.Framebuffer) -> None:
        """Draw the agents side by side into target as the keys have set the view and toggles."""
        assert self.stage is not None
        self.stage.draw(faces, target, view=self.view, toggles=self.toggles)

    # --- keys (window mode) -----------------------------------------------------------------------

    def status(self, view: AgentView | None = None) -> AgentStatus:
        from eca.services.processes.renderer.window import AgentStatus

        v = view or self.views[self.selected]
        s = v.scene
        return AgentStatus(
            agent=v.agent, emotion=s.emotion[0], intensity=s.emotion[1], role=s.role, eye_mode=s.eye_mode, head=s.head
        )

    def on_key(self, key: str) -> None:
        from eca.services.processes.renderer.window import LocalAction, action_for_key

        action = action_for_key(key, self.status())
        if action is None:
            return
        if isinstance(action, LocalAction):
            self.apply_local(action.name)
            return
        stamped = self.publish(action)
        self.log.info("key %s: sent %s", key, stamped.TYPE)

    def apply_local(self, name: str) -> None:
        if name == "view":
            self.view = "upper" if self.view == "full" else "full"
        elif name == "next_agent":
            self.selected = (self.selected + 1) % len(self.views)
        elif name == "close":
            if self.window is not None:
                self.window.request_close()
            self.request_stop()
        else:  # a renderer switch, the gaze trail ("trajectory") among them
            setattr(self.toggles, name, not getattr(self.toggles, name))

    def help_line(self) -> str:
        from eca.services.processes.renderer.window import HELP_LINE

        st = self.status()
        agent = f"[{st.agent}] " if len(self.views) > 1 else ""
        return f"{agent}{st.emotion} {st.intensity:.1f} | {st.role} | eyes {st.eye_mode} | {self.view} | {HELP_LINE}"

    # --- shutdown ------------------------------------------------------------------------------

    def teardown(self) -> None:
        if self._progress is not None:
            self._progress.close()
            self._progress = None
        for output in self.outputs:
            try:
                output.close()
            except Exception:  # a broken video file must not hide the reason the loop stopped
                self.log.exception("closing %s failed", output_name(output))
        self.outputs.clear()
        if self.frame_count:
            self.log.info("drew %d frames (%d slots skipped)", self.frame_count, self.dropped)
        if self.canvas is not None:
            self.canvas.close()
        self.canvas = None
        self.window = None


def _display_name() -> str:
    return os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") or "?"
