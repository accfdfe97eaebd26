"""`eca gaze-check FILE...`: in a conversation of several agents, how much each listener looks at the speaker.

FILEs are the flexor CSVs that `eca render` writes for a dialogue of several agents (each checked on its own),
or the dialogue itself (with its parameter files), which is then animated as `eca render` would, without
drawing. Who looks at whom is measured from the eye and head angles drawn (agent/gaze_check.py).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from eca.agent.config import ConfigError
from eca.agent.face.flexors import FLEXOR_INDEX
from eca.agent.face.settings import load_flexor_units
from eca.agent.gaze.params import default_eye_mode
from eca.agent.gaze.situated import USER, SituatedParams
from eca.agent.gaze_check import DEFAULT_TOLERANCE_DEG, GazeCheck, LookCounts, check_gaze
from eca.agent.script import ScriptError
from eca.agent.vocabulary import EYE_MODES
from eca.services.processes.audio.tts import SpeechSynthesisError
from eca.services.tools.script_input import print_failure

# The columns a conversation CSV needs (docs/scripts.md, "The flexor CSV").
NEEDED = ("t_s", "agent", "speaker", "addressees", "eye_yaw_deg", "eye_pitch_deg", "turn", "nod")


class CsvProblem(ValueError):
    """A CSV that cannot be checked; the message names the file (and line)."""


@dataclass(frozen=True)
class GazeRecord:
    """What a check needs of a rendered conversation (from its CSV, or animated from its script): the agents
    in seat order, per frame whose turn it is, and each agent's gaze (eyes plus head) in degrees, shaped
    (agents, frames)."""

    source: str
    agents: tuple[str, ...]
    t_s: np.ndarray
    speaker: tuple[str | None, ...]
    addressees: tuple[tuple[str, ...], ...]
    gaze_yaw_deg: np.ndarray
    gaze_pitch_deg: np.ndarray


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "gaze-check",
        help="how much each listener of a conversation of several agents looks at the speaker",
        description="For each agent, the share of the frames in which it listens that it looks at the speaker, "
        "and of those in which it speaks that it looks at an addressee: the person whose seat is nearest where its "
        "eyes and head point, within a tolerance. FILEs are flexor CSVs from `eca render` of a dialogue of several "
        "agents, or the dialogue (and its parameter files) to animate without drawing.",
    )
    parser.add_argument("files", nargs="+", metavar="FILE", help="render CSVs, or the dialogue of several agents")
    parser.add_argument("--tolerance-deg", type=float, default=DEFAULT_TOLERANCE_DEG,
                        help="how near a seat the gaze must point to look at that person (default: %(default)g)")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    parser.add_argument("--eyes", choices=[*EYE_MODES, "script"], default=default_eye_mode(),
                        help="animating a dialogue: the eye condition (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0, help="animating a dialogue: the seed (default: 0)")
    parser.add_argument("--fps", type=float, default=30.0, help="animating a dialogue: frames per second")
    parser.add_argument("--no-voice", action="store_true", help="animating a dialogue: no espeak-ng timing")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if not (math.isfinite(args.tolerance_deg) and 0 < args.tolerance_deg <= 90):
        print(f"eca gaze-check: --tolerance-deg must lie in (0, 90], got {args.tolerance_deg}", file=sys.stderr)
        return 2
    csvs = [f for f in args.files if Path(f).suffix.lower() == ".csv"]
    if csvs and len(csvs) != len(args.files):
        print("eca gaze-check: give render CSVs or the script, not both", file=sys.stderr)
        return 2
    try:
        params = SituatedParams.load()
        units = load_flexor_units()
    except ConfigError as exc:
        print(f"eca gaze-check: {exc}", file=sys.stderr)
        return 1
    head_deg = (units.turn_deg, units.nod_deg)
    if csvs:
        conversations = []
        for path in csvs:
            try:
                conversations.append(read_conversation_csv(Path(path), head_deg))
            except CsvProblem as exc:
                print(f"eca gaze-check: {exc}", file=sys.stderr)
                return 1
    else:
        try:
            conversations = [animate_script(args, head_deg)]
        except (ScriptError, SpeechSynthesisError, ValueError) as exc:
            print_failure("gaze-check", exc, "nothing checked")
            return 1
    reports = []
    for talk in conversations:
        check = check_gaze(talk.agents, talk.speaker, talk.addressees, talk.gaze_yaw_deg, talk.gaze_pitch_deg,
                           args.tolerance_deg, params)
        reports.append((talk, check))
    if args.json:
        print(json.dumps([as_json(talk, check, args.tolerance_deg, params) for talk, check in reports], indent=2))
    else:
        print("\n\n".join(as_table(talk, check, args.tolerance_deg, params) for talk, check in reports))
    return 0


# ---------------------------------------------------------------------------------------------- inputs


def animate_script(args: argparse.Namespace, head_deg: tuple[float, float]) -> GazeRecord:
    """The dialogue animated as `eca render` animates it (same seed, eyes, timing), without drawing."""
    from eca.services.tools.commands.render import load_inputs
    from eca.services.tools.offline import RenderSettings
    from eca.services.tools.offline_conversation import animate_conversation

    if not 1 <= args.fps <= 120:
        raise ValueError(f"--fps {args.fps} must lie in [1, 120]")
    loaded, voices = load_inputs(argparse.Namespace(scripts=args.files, agent=None, no_voice=args.no_voice),
                                 "gaze-check", several_agents=True)
    if len(loaded.agents) < 2:
        raise ValueError(f"{', '.join(args.files)}: gaze-check needs a dialogue of several agents "
                         "(<dialogue agents=\"...\">)")
    settings = RenderSettings(fps=args.fps, eyes=None if args.eyes == "script" else args.eyes, seed=args.seed)
    rendered = animate_conversation(loaded.timeline, loaded.agents, settings, voices)
    turn, nod = FLEXOR_INDEX["turn"], FLEXOR_INDEX["nod"]
    yaw = np.array([f.eye_yaw_deg + f.flexors[:, turn] * head_deg[0] for f in rendered.faces])
    pitch = np.array([f.eye_pitch_deg + f.flexors[:, nod] * head_deg[1] for f in rendered.faces])
    source = f"{', '.join(args.files)} (seed {args.seed}, eyes {args.eyes})"
    return GazeRecord(source, rendered.agents, rendered.t_s, tuple(s or None for s in rendered.speaker),
                      rendered.addressees, yaw, pitch)


def read_conversation_csv(path: Path, head_deg: tuple[float, float]) -> GazeRecord:
    """A render's CSV of a dialogue of several agents; CsvProblem naming the file and line otherwise."""
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except FileNotFoundError:
        raise CsvProblem(f"{path}: no such file") from None
    except IsADirectoryError:
        raise CsvProblem(f"{path}: is a folder, not a CSV") from None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise CsvProblem(f"{path}: cannot be read as CSV: {exc}") from None
    if not rows:
        raise CsvProblem(f"{path}: empty file")
    header = rows[0]
    if "agent" not in header and {"t_s", "role", "eye_yaw_deg"} <= set(header):
        raise CsvProblem(f"{path}: the CSV of a single agent (no 'agent' column); gaze-check needs the CSV of a "
                         "dialogue of several agents (<dialogue agents=\"...\">)")
    missing = [c for c in NEEDED if c not in header]
    if missing:
        raise CsvProblem(f"{path}:1: not a flexor CSV of `eca render`: no column {', '.join(map(repr, missing))}")
    col = {name: header.index(name) for name in NEEDED}
    frames: list[list[tuple[int, list[str]]]] = []
    for line, row in enumerate(rows[1:], start=2):
        if len(row) != len(header):
            raise CsvProblem(f"{path}:{line}: {len(row)} fields, the header has {len(header)}")
        if frames and row[col["t_s"]] == frames[-1][0][1][col["t_s"]]:
            frames[-1].append((line, row))
        else:
            frames.append([(line, row)])
    if not frames:
        raise CsvProblem(f"{path}: no frames")
    agents = tuple(row[col["agent"]] for _, row in frames[0])
    people = (*agents, USER)
    if len(set(agents)) != len(agents) or USER in agents:
        raise CsvProblem(f"{path}:2: the first frame lists agents {', '.join(agents)}; they must differ and not "
                         f"be {USER!r}")
    yaw = np.empty((len(agents), len(frames)))
    pitch = np.empty_like(yaw)
    times, speakers, addressees = np.empty(len(frames)), [], []
    for k, frame in enumerate(frames):
        names = tuple(row[col["agent"]] for _, row in frame)
        if names != agents:
            raise CsvProblem(f"{path}:{frame[0][0]}: the frame lists agents {', '.join(names)}; every frame lists "
                             f"{', '.join(agents)} in that order")
        line, first = frame[0]
        speaker, to = first[col["speaker"]], tuple(first[col["addressees"]].split())
        for name in (speaker, *to) if speaker else to:
            if name not in people:
                raise CsvProblem(f"{path}:{line}: {name!r} is neither one of the agents ({', '.join(agents)}) nor "
                                 f"{USER!r}")
        for line, row in frame:
            if (row[col["speaker"]], tuple(row[col["addressees"]].split())) != (speaker, to):
                raise CsvProblem(f"{path}:{line}: the speaker or addressees differ from the frame's first row")
        speakers.append(speaker or None)
        addressees.append(to)
        times[k] = _number(path, line, first, col, "t_s")
        for a, (line, row) in enumerate(frame):
            values = {c: _number(path, line, row, col, c) for c in ("eye_yaw_deg", "eye_pitch_deg", "turn", "nod")}
            yaw[a, k] = values["eye_yaw_deg"] + values["turn"] * head_deg[0]
            pitch[a, k] = values["eye_pitch_deg"] + values["nod"] * head_deg[1]
    return GazeRecord(str(path), agents, times, tuple(speakers), tuple(addressees), yaw, pitch)


def _number(path: Path, line: int, row: list[str], col: dict[str, int], name: str) -> float:
    text = row[col[name]]
    try:
        value = float(text)
    except ValueError:
        raise CsvProblem(f"{path}:{line}: {name} {text!r} is not a number") from None
    if not math.isfinite(value):
        raise CsvProblem(f"{path}:{line}: {name} {text!r} is not a finite number")
    return value


# ---------------------------------------------------------------------------------------------- outputs


def _share(value: float) -> str:
    return "-" if math.isnan(value) else f"{value:.3f}"


def _rows(title: str, target: str, names: tuple[str, ...], counts: tuple[LookCounts, ...],
          total: LookCounts) -> list[str]:
    head = (title, "frames", f"at {target}", "at others", "at nobody", f"{target} of looks")
    lines = [head]
    for name, c in (*zip(names, counts, strict=True), ("all", total)):
        others = c.at_other / c.frames if c.frames else math.nan
        nobody = c.elsewhere / c.frames if c.frames else math.nan
        lines.append((name, str(c.frames), _share(c.share), _share(others), _share(nobody), _share(c.of_looks)))
    widths = [max(len(line[i]) for line in lines) for i in range(len(head))]
    return ["  ".join(cell.ljust(w) if i == 0 else cell.rjust(w) for i, (cell, w) in enumerate(zip(line, widths,
                                                                                                  strict=True)))
            for line in lines]


def as_table(talk: GazeRecord, check: GazeCheck, tolerance_deg: float, params: SituatedParams) -> str:
    fps = 1.0 / float(np.median(np.diff(talk.t_s))) if talk.t_s.size > 1 else math.nan
    lines = [f"{talk.source}: {talk.t_s.size} frames ({fps:.4g} fps); a person is looked at when the eyes and head "
             f"point within {tolerance_deg:g} deg of their seat",
             *_rows("listener", "speaker", check.agents, check.listening, check.all_listening), "",
             *_rows("speaker", "addressee", check.agents, check.speaking, check.all_speaking), "",
             f"configured (configs/conversation.toml [gaze], Vertegaal et al. 2001): listener at speaker "
             f"{params.listener_at_speaker:g}, speaker at addressee {params.speaker_at_addressee:g}; compare "
             "'of looks', the share among the frames that look at some person"]
    return "\n".join(lines)


def _counts(c: LookCounts) -> dict[str, Any]:
    def number(value: float) -> float | None:
        return None if math.isnan(value) else round(value, 6)

    return {"frames": c.frames, "at_target": c.at_target, "at_other": c.at_other, "at_nobody": c.elsewhere,
            "share": number(c.share), "of_looks": number(c.of_looks)}


def as_json(talk: GazeRecord, check: GazeCheck, tolerance_deg: float, params: SituatedParams) -> dict[str, Any]:
    return {
        "source": talk.source,
        "frames": int(talk.t_s.size),
        "tolerance_deg": tolerance_deg,
        "configured": {"listener_at_speaker": params.listener_at_speaker,
                       "speaker_at_addressee": params.speaker_at_addressee},
        "listeners": {**{a: _counts(c) for a, c in zip(check.agents, check.listening, strict=True)},
                      "all": _counts(check.all_listening)},
        "speakers": {**{a: _counts(c) for a, c in zip(check.agents, check.speaking, strict=True)},
                     "all": _counts(check.all_speaking)},
    }
