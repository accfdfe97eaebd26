"""`eca render SCRIPT... -o out.mp4`: the deterministic offline render, with audio, a flexor CSV and, beside it,
each agent's rig frames as a Live Link Face CSV (services/tools/rig_csv.py; `--no-rig-csv` leaves them out).

A dialogue of several agents is rendered with its agents side by side (services/tools/offline_conversation.py)."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from eca.agent.gaze.params import default_eye_mode
from eca.agent.script import ScriptError, ScriptSet
from eca.agent.vocabulary import EYE_MODES
from eca.services.processes.audio.tts import SpeechSynthesisError
from eca.services.tools.playback import VoiceCache
from eca.services.tools.script_input import AGENT_HELP, load_run, open_voices, print_failure

if TYPE_CHECKING:  # the offline pipeline pulls in GL and FFmpeg: imported only when rendering
    from eca.services.tools.offline import RenderSettings

EYE_CHOICES = [*EYE_MODES, "script"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("render", help="render scripts offline to MP4 (with audio), a flexor CSV and rig frames")
    add_render_arguments(p)
    p.add_argument("-o", "--output", type=Path, required=True, help="the MP4 to write")
    p.add_argument("--csv", type=Path, default=None, help="flexor frames CSV (default: beside the MP4)")
    p.add_argument("--no-rig-csv", action="store_true",
                   help="do not write the rig frames (ARKit weights, head and eye angles: a Live Link Face CSV per "
                        "agent, <csv stem>_rig_<agent>.csv beside the flexor CSV)")
    p.set_defaults(func=run)


def add_render_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scripts", nargs="+", help="dialogue XML and/or parameter files")
    p.add_argument("--agent", default=None, help=AGENT_HELP)
    p.add_argument("--eyes", choices=EYE_CHOICES, default=default_eye_mode(),
                   help="eye condition (default: %(default)s, the paper's recommendation); 'script' follows the "
                        "scripts' own eye-mode cues")
    p.add_argument("--view", choices=["full", "upper"], default="full")
    p.add_argument("--face", default="flexor", metavar="FACE",
                   help="the agents' face: flexor (the paper's 2D face, default), head (eca's 3D head) or a "
                        ".glb/.gltf/.vrm file")
    p.add_argument("--seed", type=int, default=0, help="seed of the eyes and blinks")
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--size", default=None,
                   help="WxH, even numbers (default 640x480; for a dialogue of several agents 400x300 per agent, "
                        "side by side)")
    p.add_argument("--no-voice", action="store_true", help="do not speak lines that have only text")


def parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size {text!r} must look like 640x480") from None
    if not (16 <= w <= 4096 and 16 <= h <= 4096) or w % 2 or h % 2:
        raise ValueError(f"--size {text!r}: width and height must be even and within 16..4096")
    return w, h


def settings_from(args: argparse.Namespace) -> RenderSettings:
    from eca.services.tools.offline import RenderSettings

    if not 1 <= args.fps <= 120:
        raise ValueError(f"--fps {args.fps} must lie in [1, 120]")
    size = parse_size(args.size) if args.size is not None else RenderSettings().size
    face = getattr(args, "face", "flexor")
    if face != "flexor":
        from eca.services.processes.renderer.faces import check_face  # GL libraries load only here

        face = check_face(face, "--face")
    return RenderSettings(fps=args.fps, size=size, view=args.view,
                          eyes=None if args.eyes == "script" else args.eyes, seed=args.seed, face=face)


def load_inputs(args: argparse.Namespace, command: str = "render",
                several_agents: bool = False) -> tuple[ScriptSet, VoiceCache | None]:
    """The scripts as one run (its agent: --agent or the dialogue's own; a dialogue of several agents where
    the command can animate them) and the voices they speak with."""
    voices = open_voices(command, args.no_voice)
    return load_run(args.scripts, args.agent, voices, several_agents), voices


def render_video(timeline: Any, voices: VoiceCache | None, agent: str, settings: RenderSettings,
                 output: Path, csv_path: Path | None, label: str = "render", rig: bool = False) -> Any:
    """Render the timeline to `output` (MP4 with audio) and the CSV, and with `rig` the agent's rig frames beside
    the CSV (rig_csv.rig_csv_path); returns the RenderedTimeline."""
    from eca.services.tools.offline import RenderedTimeline, animate, write_flexor_csv, write_rig_csv
    from eca.services.tools.rig_csv import rig_csv_path
    from eca.services.tools.video_render import FrameSink, render_panels

    def animate_one(draw: FrameSink) -> Any:
        return animate(timeline, agent, settings, voices, on_frame=lambda k, face: draw(k, (face,)))

    def write_csvs(path: Path, result: RenderedTimeline) -> None:
        write_flexor_csv(path, result)
        if rig:
            write_rig_csv(rig_csv_path(path, agent), result, settings.fps)

    return render_panels(animate_one, lambda result: result.audio, 1, settings.size, settings.fps, timeline.length_s,
                         settings.view, output, csv_path, write_csvs, label, face=settings.face)


# What a render can still meet after the scripts loaded: an output it cannot write (OSError), a sound
# file that changed since and cannot be read (the offline pipeline's AudioFileError, a ValueError).
RENDER_ERRORS = (OSError, ValueError)


def print_render_failure(command: str, exc: Exception) -> None:
    if isinstance(exc, FileExistsError | NotADirectoryError) and exc.filename:
        # mkdir's words ("File exists") for a file standing where an output folder must go
        print(f"eca {command}: {exc.filename}: is a file, not a folder to write into", file=sys.stderr)
    elif isinstance(exc, OSError) and exc.filename and exc.strerror:
        print(f"eca {command}: {exc.filename}: {exc.strerror}", file=sys.stderr)
    else:
        print(f"eca {command}: {exc}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    try:
        settings = settings_from(args)
        if args.output.suffix.lower() != ".mp4":
            raise ValueError(f"{args.output}: the output must be an .mp4 file")
        loaded, voices = load_inputs(args, several_agents=True)
        if len(loaded.agents) > 1:
            from eca.services.tools.offline_conversation import default_size
            from eca.services.tools.video_render import panel_widths

            if args.size is None:
                settings = replace(settings, size=default_size(len(loaded.agents)))
            panel_widths(settings.size[0], len(loaded.agents))  # wide enough for every face
    except (ScriptError, SpeechSynthesisError, ValueError) as exc:
        print_failure("render", exc, "nothing rendered")
        return 1
    csv_path = args.csv or args.output.with_suffix(".csv")
    rig = not args.no_rig_csv
    try:
        if len(loaded.agents) > 1:
            from eca.services.tools.offline_conversation import render_conversation_video

            render_conversation_video(loaded.timeline, voices, loaded.agents, settings, args.output, csv_path,
                                      rig=rig)
        else:
            render_video(loaded.timeline, voices, loaded.agent, settings, args.output, csv_path, rig=rig)
    except RENDER_ERRORS as exc:
        print_render_failure("render", exc)
        return 1
    who = f"agents {', '.join(loaded.agents)}" if len(loaded.agents) > 1 else f"agent {loaded.agent}"
    print(f"wrote {args.output} ({loaded.timeline.length_s:.1f} s, {who}) and {csv_path}")
    if rig:
        from eca.services.tools.rig_csv import rig_csv_paths

        print(f"rig frames (Live Link Face CSV): {', '.join(map(str, rig_csv_paths(csv_path, loaded.agents)))}")
    return 0
