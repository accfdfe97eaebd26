"""`eca experiment [DIALOGUE]`: the paper's eye conditions rendered side by side with trajectory plots."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from eca import shipped_configs
from eca.agent.script import ScriptError
from eca.services.processes.audio.tts import SpeechSynthesisError
from eca.services.tools.commands.render import (
    RENDER_ERRORS,
    load_inputs,
    print_render_failure,
    render_video,
    settings_from,
)
from eca.services.tools.script_input import AGENT_HELP, print_failure

DEMO_DIALOGUE = shipped_configs() / "demo" / "dialogue.xml"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("experiment", help="render the paper's eye conditions side by side")
    p.add_argument("scripts", nargs="*", default=[str(DEMO_DIALOGUE)], help="dialogue (default: the demo)")
    p.add_argument("-o", "--output", type=Path, default=Path("out/experiment"), help="output folder")
    p.add_argument("--agent", default=None, help=AGENT_HELP)
    p.add_argument("--view", choices=["full", "upper"], default="upper", help="the paper used the upper face")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--size", default="480x360")
    p.add_argument("--seconds", type=float, default=None, help="render only the first N seconds")
    p.add_argument("--no-voice", action="store_true")
    p.add_argument("--no-csv", action="store_true", help="do not write the flexor CSV of each condition")
    p.set_defaults(func=run, eyes="saccade+blink")


def run(args: argparse.Namespace) -> int:
    from eca.services.tools.experiment import (
        CONDITIONS,
        Panel,
        plot_trajectory,
        poster_frame,
        write_index,
        write_poster,
    )

    try:
        if args.seconds is not None and not args.seconds > 0:
            raise ValueError(f"--seconds {args.seconds} must be greater than 0")
        base = settings_from(args)
        loaded, voices = load_inputs(args, "experiment")
    except (ScriptError, SpeechSynthesisError, ValueError) as exc:
        print_failure("experiment", exc, "nothing rendered")
        return 1
    timeline = loaded.timeline
    if args.seconds is not None:
        timeline = replace(timeline, cues=tuple(c for c in timeline.cues if c.t_s < args.seconds),
                           length_s=min(timeline.length_s, args.seconds))
    out = args.output
    panels = []
    try:
        out.mkdir(parents=True, exist_ok=True)
        for cond in CONDITIONS:
            settings = replace(base, eyes=cond.key)
            panel = Panel.of(cond)
            csv_path = None if args.no_csv else out / Path(panel.video).with_suffix(".csv")
            result = render_video(timeline, voices, loaded.agent, settings, out / panel.video, csv_path,
                                  label=cond.key)
            poster_t = float(result.t_s[poster_frame(result.t_s, result.lid)])
            write_poster(out / panel.video, poster_t, out / panel.poster)
            plot_trajectory(result.eye_yaw_deg, result.lid, settings.fps, cond.key, out / panel.plot)
            panels.append(panel)
            print(f"{cond.label}: {out / panel.video}", flush=True)
        notes = (f"The same dialogue ({', '.join(Path(s).name for s in args.scripts)}, "
                 f"{timeline.length_s:.0f} s) under each of the {len(panels)} eye conditions, {args.view} view, "
                 f"seed {args.seed}. Before it plays, each video shows its first frame from 1 s on with the eyes "
                 "open. Below each video: the horizontal pupil position over time (the paper's Figure 4), lid "
                 "closures in red.")
        write_index(out, "Eye conditions of Rodrigues et al., side by side", panels, notes, base.size)
    except RENDER_ERRORS as exc:
        print_render_failure("experiment", exc)
        return 1
    print(f"index: {out / 'index.html'} and {out / 'index.md'}")
    return 0
