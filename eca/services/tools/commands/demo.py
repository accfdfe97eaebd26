"""`eca demo`: the main job. With a display, the demo dialogue plays live in a window; without one,
it is rendered to a video with its pupil-trajectory plot, and the paths are printed."""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
from pathlib import Path

from eca.agent.gaze.params import default_eye_mode
from eca.agent.script import ScriptError
from eca.services.processes.audio.tts import SpeechSynthesisError
from eca.services.tools.commands.experiment import DEMO_DIALOGUE
from eca.services.tools.commands.render import (
    RENDER_ERRORS,
    load_inputs,
    print_render_failure,
    render_video,
    settings_from,
)
from eca.services.tools.script_input import print_failure


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="the demo dialogue: live in a window, or rendered to video without a display")
    p.add_argument("--headless", action="store_true", help="render to video even if a display exists")
    p.add_argument("-o", "--output", type=Path, default=Path("out/demo"), help="folder for the headless results")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--face", default="flexor", metavar="FACE",
                   help="the agent's face: flexor (the paper's 2D face, default), head (eca's 3D head) or a "
                        ".glb/.gltf/.vrm file")
    p.set_defaults(func=run)


def display_available() -> bool:
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return False
    try:
        import glfw

        ok = bool(glfw.init())
        glfw.terminate()
        return ok
    except Exception:
        return False


def run(args: argparse.Namespace) -> int:
    if not args.headless and display_available():
        return run_live(args)
    print("eca demo: no display found: rendering the demo to a video instead", flush=True)
    return run_headless(args)


def run_headless(args: argparse.Namespace) -> int:
    from eca.services.tools.experiment import plot_trajectory

    # agent=None: the demo dialogue animates its own agent
    render_args = argparse.Namespace(scripts=[str(DEMO_DIALOGUE)], agent=None, eyes=default_eye_mode(), view="full",
                                     seed=args.seed, fps=30.0, size="640x480", no_voice=False, face=args.face)
    try:
        settings = settings_from(render_args)
        loaded, voices = load_inputs(render_args, "demo")
    except (ScriptError, SpeechSynthesisError, ValueError) as exc:
        print_failure("demo", exc, "nothing rendered")
        return 1
    out: Path = args.output
    video, csv, plot = out / "demo.mp4", out / "demo_flexors.csv", out / "demo_trajectory.png"
    try:
        result = render_video(loaded.timeline, voices, loaded.agent, settings, video, csv, label="demo")
        plot_trajectory(result.eye_yaw_deg, result.lid, settings.fps, "demo: pupil trajectory", plot)
    except RENDER_ERRORS as exc:
        print_render_failure("demo", exc)
        return 1
    print(f"video:      {video}\ntrajectory: {plot}\nflexors:    {csv}")
    return 0


def run_live(args: argparse.Namespace) -> int:
    """`eca up` with the window, then the demo played into it over the bus."""
    from eca.services.tools.child_processes import LineReader, eca_command, subprocess_env

    def stop(*_: object) -> None:
        raise KeyboardInterrupt  # so the runtime below is stopped in order, not orphaned

    signal.signal(signal.SIGTERM, stop)
    instance = f"demo{os.getpid()}"
    argv = eca_command("up", "--instance", instance, "--quiet", "--face", args.face)
    up = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=subprocess_env(),
                          start_new_session=True)
    reader = LineReader(up.stdout)
    try:
        reader.wait_for("[up] ready in", 60.0)
        return subprocess.call(eca_command("play", str(DEMO_DIALOGUE), "--instance", instance))
    except KeyboardInterrupt:
        return 130
    except TimeoutError as exc:
        print(f"eca demo: the runtime did not start:\n{exc}", file=sys.stderr)
        return 1
    finally:
        up.send_signal(signal.SIGINT)
        up.wait(timeout=10)
