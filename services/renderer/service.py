"""The renderer service: the face of one or more agents, live from the bus, in a window or headless.

It subscribes to each agent's states (role, emotion, head, eyes), events (saccades, speech lifecycle)
and streams (eye state, clock anchors, mouth keys). Every frame it drains its socket, so the frame sees
every message that has arrived (never ZMQ_CONFLATE, which would mix topics), composes each agent's
face for the frame's display time (agent/face/scene.py: eyes on the exact saccade trajectory, mouth at
the sample at the DAC), draws it and publishes the composed flexors as a FaceFrame on
`stream.<agent>.face_frame`: recorders and tests see exactly what was drawn. The last-value cache hands
a renderer that starts late, or restarts, the current states on subscription, so its first frame shows
them.

Modes: a glfw window where a display exists (keys publish commands, see window.py), otherwise EGL
headless at a fixed frame rate, optionally writing an H.264 MP4 and/or PNG frames, with a progress bar
when the length is known. Frame k is composed for t0 + k / fps (plus a configurable display lead); a
slot the renderer could not reach in time is skipped rather than delaying every later frame.

Several agents in one renderer are drawn side by side, turned toward each other (a staging turn added
when drawing only; the published frames are each agent's own face).

Options come from the config's [renderer] table, overridden on the command line (`from_args`).
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from agent.face.flexors import FLEXOR_INDEX
from agent.face.frame import FlexorFrame
from agent.face.scene import LiveScene
from protocol.endpoints import BusConfig
from protocol.messages import (
    ClockAnchor,
    EmotionState,
    EyesState,
    EyeState,
    FaceFrame,
    GazeTargetState,
    HeadState,
    Message,
    MouthKeys,
    RoleState,
    Saccade,
    SpeechFailed,
    SpeechFinished,
    SpeechInterrupted,
    SpeechStarted,
)
from services.renderer.video import FrameSink, PngWriter, VideoWriter
from services.runtime import Rejected, Service, latest_per_state_topic

MODES = ("auto", "window", "headless")
KEEP_EYE_SAMPLES = 4
MAX_READ_PER_FRAME = 5000  # a frame never reads an unbounded backlog: the rest waits for the next frame
_TURN = FLEXOR_INDEX["turn"]
_LOOK = [FLEXOR_INDEX["look_x"], FLEXOR_INDEX["look_y"]]


@dataclass
class RendererOptions:
    agents: tuple[str, ...] = ()  # empty: every agent of the instance ([agents] ids)
    fps: float = 60.0
    size: tuple[int, int] = (640, 480)
    view: str = "full"
    mode: str = "auto"  # auto: a window where a display exists, else headless
    idle_noise: bool = True
    seed: int = 0
    video: str | None = None  # headless: write an H.264 MP4 here
    png_dir: str | None = None  # headless: write PNG frames here
    png_every: int = 1
    seconds: float | None = None  # stop after this long (the length of a video)
    frames: int | None = None  # stop after this many frame slots
    progress: bool = True  # a progress bar when the length is known
    lead_s: float = 0.0  # display time = slot time + lead (a window's presentation delay)
    facing_turn: float = 0.3  # staging turn of side-by-side agents toward each other (flexor units)
    trail_s: float = 1.0  # length of the saccade trajectory overlay
    vsync: bool = True
    publish_frames: bool = True

    def check(self) -> RendererOptions:
        if not (1.0 <= self.fps <= 240.0):
            raise ValueError(f"fps must lie in [1, 240], got {self.fps}")
        if self.view not in ("full", "upper"):
            raise ValueError(f"view must be full or upper, got {self.view!r}")
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        w, h = self.size
        if not (16 <= w <= 8192 and 16 <= h <= 8192):
            raise ValueError(f"size must lie between 16x16 and 8192x8192, got {w}x{h}")
        if self.seconds is not None and self.seconds <= 0:
            raise ValueError(f"seconds must be positive, got {self.seconds}")
        if self.frames is not None and self.frames <= 0:
            raise ValueError(f"frames must be positive, got {self.frames}")
        if self.mode == "window" and (self.video or self.png_dir):
            raise ValueError("video and PNG output are headless features: add --headless")
        return self

    @property
    def total_slots(self) -> int | None:
        slots = [
            n
            for n in (self.frames, None if self.seconds is None else math.ceil(self.seconds * self.fps))
            if n is not None
        ]
        return min(slots) if slots else None

    @classmethod
    def from_table(cls, table: dict[str, Any]) -> RendererOptions:
        """Options from a config's [renderer] table (unknown keys are an error naming them)."""
        names = {f.name for f in cls.__dataclass_fields__.values()} | {"width", "height", "headless"}
        unknown = set(table) - names
        if unknown:
            raise ValueError(f"[renderer]: unknown keys {sorted(unknown)}")
        values = {k: v for k, v in table.items() if k not in ("width", "height", "headless")}
        if "agents" in values:
            values["agents"] = tuple(values["agents"])
        opts = cls(**values)
        if "width" in table or "height" in table:
            opts.size = (int(table.get("width", opts.size[0])), int(table.get("height", opts.size[1])))
        if table.get("headless"):
            opts.mode = "headless"
        return opts


def options_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="renderer", add_help=False)
    p.add_argument("--agent", action="append", default=None, help="draw this agent (repeat for side by side)")
    p.add_argument("--fps", type=float, default=None, help="frame rate (default 60)")
    p.add_argument("--size", default=None, metavar="WxH", help="window or image size (default 640x480)")
    p.add_argument("--view", choices=("full", "upper"), default=None, help="full face or upper face only")
    p.add_argument("--headless", action="store_true", help="render offscreen (EGL) even where a display exists")
    p.add_argument("--window", action="store_true", help="require a window (fail without a display)")
    p.add_argument("--no-idle", action="store_true", help="no idle noise (exact, repeatable frames)")
    p.add_argument("--seed", type=int, default=None, help="idle-noise seed")
    p.add_argument("--video", default=None, metavar="PATH", help="headless: write an H.264 MP4")
    p.add_argument("--png", default=None, metavar="DIR", help="headless: write PNG frames")
    p.add_argument("--png-every", type=int, default=None, metavar="N", help="only every Nth frame as PNG")
    p.add_argument("--seconds", type=float, default=None, help="stop after this long")
    p.add_argument("--frames", type=int, default=None, help="stop after this many frames")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--lead-ms", type=float, default=None, help="display time ahead of the frame slot")
    return p


def parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = text.lower().split("x")
        return int(w), int(h)
    except ValueError:
        raise ValueError(f"size must look like 640x480, got {text!r}") from None


def options_from(config: BusConfig, argv: list[str]) -> RendererOptions:
    """The config's [renderer] table overridden by command-line arguments; ValueError names the problem."""
    args, unknown = options_parser().parse_known_args(argv)
    if unknown:
        raise ValueError(f"unknown renderer arguments: {shlex.join(unknown)}")
    return options_from_namespace(config, args)


def options_from_namespace(config: BusConfig, args: argparse.Namespace) -> RendererOptions:
    opts = RendererOptions.from_table(dict(config.raw.get("renderer", {})))
    if args.headless and args.window:
        raise ValueError("--headless and --window exclude each other")
    changes: dict[str, Any] = {}
    if args.agent:
        changes["agents"] = tuple(args.agent)
    for name in ("fps", "view", "seed", "video", "seconds", "frames", "png_every"):
        if getattr(args, name) is not None:
            changes[name] = getattr(args, name)
    if args.size is not None:
        changes["size"] = parse_size(args.size)
    if args.png is not None:
        changes["png_dir"] = args.png
    if args.headless:
        changes["mode"] = "headless"
    if args.window:
        changes["mode"] = "window"
    if args.no_idle:
        changes["idle_noise"] = False
    if args.no_progress:
        changes["progress"] = False
    if args.lead_ms is not None:
        changes["lead_s"] = args.lead_ms / 1000.0
    return replace(opts, **changes).check()


@dataclass
class AgentView:
    agent: str
    scene: LiveScene
    trail: deque[tuple[float, float]] = field(default_factory=deque)
    frame: FlexorFrame | None = None


class RendererService(Service):
    name = "renderer"

    def __init__(self, config: BusConfig, options: RendererOptions | None = None, **kwargs: Any) -> None:
        super().__init__(config, **kwargs)
        self.options = (options or RendererOptions()).check()
        ids = list(self.options.agents or config.raw.get("agents", {}).get("ids", ["ada"]))
        self.views = [
            AgentView(a, LiveScene(seed=self.options.seed + i, idle_noise=self.options.idle_noise))
            for i, a in enumerate(ids)
        ]
        self.by_agent = {v.agent: v for v in self.views}
        self.toggles: Any = None  # RenderToggles, made with the GL objects
        self.view = self.options.view
        self.show_trajectory = False
        self.selected = 0  # the agent keys act on
        self.period_ns = round(1e9 / self.options.fps)
        self.frame_count = 0  # frames drawn
        self.dropped = 0  # frame slots skipped because drawing fell behind
        self.slot = 0
        self.mode = ""
        self.window: Any = None
        self.gl: Any = None
        self.renderer: Any = None
        self.target: Any = None
        self.sinks: list[FrameSink] = []
        self._t0_ns = 0
        self._progress: Any = None
        for cls, fn in (
            (RoleState, self.on_role),
            (EmotionState, self.on_emotion),
            (HeadState, self.on_head),
            (EyesState, self.on_eyes),
            (GazeTargetState, lambda m: None),
            (Saccade, self.on_saccade),
            (EyeState, self.on_eye_state),
            (ClockAnchor, self.on_anchor),
            (MouthKeys, self.on_mouth),
            (SpeechStarted, self.on_speech_started),
            (SpeechFinished, self.on_speech_ended),
            (SpeechInterrupted, self.on_speech_ended),
            (SpeechFailed, self.on_speech_failed),
        ):
            self.handle(cls, fn)

    @classmethod
    def from_args(cls, config: BusConfig, argv: list[str], **kwargs: Any) -> RendererService:
        try:
            options = options_from(config, argv)
        except ValueError as exc:
            print(f"[renderer] ERROR {exc}", file=sys.stderr)
            raise SystemExit(2) from None
        return cls(config, options, **kwargs)

    def subscriptions(self) -> list[str]:
        subs = []
        for v in self.views:
            a = v.agent
            subs += [
                f"state.{a}.",
                f"event.{a}.",
                f"stream.{a}.eye_state",
                f"stream.{a}.clock_anchor",
                f"stream.{a}.mouth",
            ]
        return subs

    # --- bus in --------------------------------------------------------------------------------

    def _scene(self, msg: Message) -> LiveScene:
        view = self.by_agent.get(msg.agent)
        if view is None:
            raise Rejected(f"this renderer does not draw agent '{msg.agent}'")
        return view.scene

    def _guard(self, fn: Any, *args: Any) -> None:
        try:
            fn(*args)
        except ValueError as exc:
            raise Rejected(str(exc)) from None

    def on_role(self, m: RoleState) -> None:
        self._guard(self._scene(m).set_role, m.role, m.t_ns, m.speaker)

    def on_emotion(self, m: EmotionState) -> None:
        self._guard(self._scene(m).set_emotion, m.name, m.intensity, m.transition_s, m.t_ns)

    def on_head(self, m: HeadState) -> None:
        self._guard(self._scene(m).move_head, m.turn, m.nod, m.tilt, m.duration_s, m.t_ns)

    def on_eyes(self, m: EyesState) -> None:
        self._guard(self._scene(m).set_eye_mode, m.mode)

    def on_saccade(self, m: Saccade) -> None:
        self._guard(
            self._scene(m).add_saccade,
            m.onset_ns,
            (m.from_yaw_deg, m.from_pitch_deg),
            (m.to_yaw_deg, m.to_pitch_deg),
            m.duration_s,
        )

    def on_eye_state(self, m: EyeState) -> None:
        self._guard(self._scene(m).add_eye_sample, m.t_ns, m.yaw_deg, m.pitch_deg, m.lid, m.mode)

    def on_anchor(self, m: ClockAnchor) -> None:
        self._guard(self._scene(m).add_clock_anchor, m.request_id, m.sample_index, m.sample_rate, m.dac_time_ns)

    def on_mouth(self, m: MouthKeys) -> None:
        self._guard(
            self._scene(m).add_mouth_keys, m.request_id, m.sample_rate, m.sample_index, m.weights, m.reset, m.t_ns
        )

    def on_speech_started(self, m: SpeechStarted) -> None:
        self._guard(self._scene(m).speech_started, m.request_id, m.dac_time_ns)

    def on_speech_ended(self, m: SpeechFinished | SpeechInterrupted) -> None:
        self._guard(self._scene(m).speech_ended, m.request_id, m.played_s, m.t_ns)

    def on_speech_failed(self, m: SpeechFailed) -> None:
        self._guard(self._scene(m).speech_failed, m.request_id, m.t_ns)

    # --- GL set-up -----------------------------------------------------------------------------

    def setup(self) -> None:
        from services.renderer import RenderToggles

        self.toggles = RenderToggles(trajectory=False)
        self.mode = self._open_output()
        self._t0_ns = self.clock.now_ns()
        total = self.options.total_slots
        if total is not None and self.options.progress:
            from tqdm import tqdm

            self._progress = tqdm(total=total, unit="frame", desc="rendering", file=sys.stderr, mininterval=0.5)

    def _open_output(self) -> str:
        from services.renderer import Renderer
        from services.renderer.window import WindowError, display_available

        opts = self.options
        if opts.mode == "window" or (opts.mode == "auto" and display_available() and not (opts.video or opts.png_dir)):
            try:
                self._open_window()
                self.renderer = Renderer(self.gl, size=opts.size)
                self.log.info(
                    "window mode (display %s): %dx%d at %g fps, agents %s",
                    _display_name(),
                    *opts.size,
                    opts.fps,
                    ", ".join(v.agent for v in self.views),
                )
                return "window"
            except WindowError as exc:
                if opts.mode == "window":
                    raise
                self.log.info("no window (%s): rendering headless instead", exc)
        from services.renderer import create_headless_context, create_offscreen_target

        self.gl = create_headless_context()
        self.renderer = Renderer(self.gl, size=opts.size)
        self.target = create_offscreen_target(self.gl, opts.size)
        if opts.video:
            self.sinks.append(VideoWriter(opts.video, opts.fps, opts.size))
        if opts.png_dir:
            self.sinks.append(PngWriter(opts.png_dir, opts.png_every))
        outputs = [
            s for s in (opts.video and f"video {opts.video}", opts.png_dir and f"PNG frames in {opts.png_dir}") if s
        ] or ["face frames on the bus only"]
        self.log.info(
            "headless mode (EGL, %s): %dx%d at %g fps, agents %s; writing %s",
            "forced" if opts.mode == "headless" else "no display",
            *opts.size,
            opts.fps,
            ", ".join(v.agent for v in self.views),
            " and ".join(outputs),
        )
        return "headless"

    def _open_window(self) -> None:
        from services.renderer.window import Window

        self.window = Window(self.options.size, "eca", vsync=self.options.vsync, on_key=self.on_key)
        self.gl = self.window.ctx

    # --- the frame loop ------------------------------------------------------------------------

    def slot_ns(self, k: int) -> int:
        return self._t0_ns + (k * 1_000_000_000 * 1000) // round(self.options.fps * 1000)

    def run_once(self) -> None:
        assert self.sub is not None
        now = self.clock.now_ns()
        self.beat_if_due(now)
        if self.window is not None:
            self.window.poll()
            if self.window.should_close:
                self.request_stop()
                return
        due = self.slot_ns(self.slot)
        if now >= due:
            self.drain()
            self.render_frame(self.slot, due + round(self.options.lead_s * 1e9))
            self._advance_slot()
        else:
            # Messages wait in the socket until the frame: one batch per frame costs least, and a frame
            # sees everything that arrived before it either way.
            self._stop.wait(max(0.0, min(due, self._next_beat_ns) - now) / 1e9)
        if self.parent_pid is not None and _parent_gone(self.parent_pid):
            self.log.warning("supervisor %d is gone: stopping", self.parent_pid)
            self.request_stop()

    def drain(self) -> int:
        """Handle every message waiting on the socket; returns how many were read.

        Eye-state samples are only ever interpolated near the newest ones, so of each agent's samples in
        one batch only the newest KEEP_EYE_SAMPLES are decoded, and of each state topic only the newest
        message: a flood costs a socket read each, not a decode. Everything else (events, mouth keys,
        clock anchors) is handled in order; a state the last-value cache re-sent unchanged (byte for
        byte) is ignored. At most MAX_READ_PER_FRAME messages are read per frame, so the frame rate
        holds whatever arrives (the rest waits for the next frame).
        """
        assert self.sub is not None
        raw = self.sub.read_frames(MAX_READ_PER_FRAME)
        read = len(raw)
        raw = latest_per_state_topic(raw)
        self.coalesced += read - len(raw)
        seen: dict[bytes, int] = {}
        keep = [True] * len(raw)
        for i in range(len(raw) - 1, -1, -1):
            topic = raw[i][0]
            if topic.endswith(b".eye_state"):
                seen[topic] = seen.get(topic, 0) + 1
                keep[i] = seen[topic] <= KEEP_EYE_SAMPLES
        for frames, wanted in zip(raw, keep, strict=True):
            if not wanted:
                self.coalesced += 1
                continue
            got = self.sub.accept(frames)
            if got is not None:
                self.dispatch(got)
        return read

    def _advance_slot(self) -> None:
        nxt = self.slot + 1
        now = self.clock.now_ns()
        latest = (now - self._t0_ns) * round(self.options.fps * 1000) // (1_000_000_000 * 1000)
        if latest > nxt:  # drawing fell behind by more than a frame: skip to the current slot
            self.dropped += latest - nxt
            nxt = latest
        total = self.options.total_slots
        if total is not None:
            nxt = min(nxt, total)
        if self._progress is not None:
            self._progress.update(nxt - self.slot)
        self.slot = nxt
        if total is not None and self.slot >= total:
            self.request_stop()

    def compose(self, frame_ns: int) -> list[FlexorFrame]:
        """Every agent's face at display time frame_ns."""
        frames = []
        for v in self.views:
            frame = v.scene.frame_at(frame_ns)
            v.scene.prune(frame_ns)
            v.frame = frame
            v.trail.append((float(frame.values[_LOOK[0]]), float(frame.values[_LOOK[1]])))
            while len(v.trail) > max(2, round(self.options.trail_s * self.options.fps)):
                v.trail.popleft()
            frames.append(frame)
        return frames

    def render_frame(self, index: int, frame_ns: int) -> None:
        frames = self.compose(frame_ns)
        target = self.window.screen if self.window is not None else self.target
        self.draw(frames, target)
        if self.window is not None:
            self.window.draw_text_line(target, self.help_line())
            self.window.swap()
        elif self.sinks:
            from services.renderer import read_rgb

            rgb = read_rgb(target)
            for sink in self.sinks:
                sink.write(rgb, index)
        else:
            self.gl.finish()
        self.frame_count += 1
        if self.options.publish_frames:
            for v, frame in zip(self.views, frames, strict=True):
                self.publish(FaceFrame(agent=v.agent, frame_ns=frame_ns, flexors=frame.as_dict()))

    def draw(self, frames: list[FlexorFrame], target: Any) -> None:
        """Draw the agents side by side into target (each in its own viewport, turned toward the other)."""
        x0, y0, width, height = target.viewport
        n = len(frames)
        self.toggles.trajectory = self.show_trajectory
        for i, (v, frame) in enumerate(zip(self.views, frames, strict=True)):
            values = np.array(frame.values)
            if n > 1:
                # The agent on the left turns to its left (the screen's right) to face the other.
                side = -1.0 if i < n / 2 else 1.0
                values[_TURN] = float(np.clip(values[_TURN] + side * self.options.facing_turn, -1.0, 1.0))
            region = (x0 + i * width // n, y0, (i + 1) * width // n - i * width // n, height)
            target.viewport = region
            target.scissor = region
            trail = np.array(v.trail) if self.show_trajectory and len(v.trail) >= 2 else None
            self.renderer.render(values, target=target, view=self.view, toggles=self.toggles, overlay_points=trail)
        target.viewport = (x0, y0, width, height)
        target.scissor = None

    # --- keys (window mode) -----------------------------------------------------------------------

    def status(self, view: AgentView | None = None) -> Any:
        from services.renderer.window import AgentStatus

        v = view or self.views[self.selected]
        s = v.scene
        return AgentStatus(
            agent=v.agent, emotion=s.emotion[0], intensity=s.emotion[1], role=s.role, eye_mode=s.eye_mode, head=s.head
        )

    def on_key(self, key: str) -> None:
        from services.renderer.window import LocalAction, action_for_key

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
        elif name == "trajectory":
            self.show_trajectory = not self.show_trajectory
        else:
            setattr(self.toggles, name, not getattr(self.toggles, name))

    def help_line(self) -> str:
        from services.renderer.window import HELP_LINE

        st = self.status()
        agent = f"[{st.agent}] " if len(self.views) > 1 else ""
        return f"{agent}{st.emotion} {st.intensity:.1f} | {st.role} | eyes {st.eye_mode} | {self.view} | {HELP_LINE}"

    # --- shutdown ------------------------------------------------------------------------------

    def teardown(self) -> None:
        if self._progress is not None:
            self._progress.close()
            self._progress = None
        for sink in self.sinks:
            try:
                sink.close()
            except Exception:  # a broken video file must not hide the reason the loop stopped
                self.log.exception("closing %s failed", type(sink).__name__)
        self.sinks.clear()
        if self.frame_count:
            self.log.info("drew %d frames (%d slots skipped)", self.frame_count, self.dropped)
        if self.window is not None:
            self.window.close()
            self.window = None
        elif self.gl is not None:
            self.gl.release()
        self.gl = None


def _display_name() -> str:
    import os

    return os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") or "?"


def _parent_gone(pid: int) -> bool:
    import os

    return os.getppid() != pid
