"""`eca gaze-trace`: run the gaze model for one agent and write its saccades as CSV."""

from __future__ import annotations

import argparse
import csv
import math
import sys
from typing import TextIO

from agent.config import ConfigError
from agent.gaze.engine import GazeEngine
from agent.gaze.params import KINDS, MODES, ROLES, GazeParams

COLUMNS = (
    "onset_s",
    "kind",
    "magnitude_deg",
    "amplitude_deg",
    "direction_deg",
    "duration_s",
    "hold_s",
    "from_yaw_deg",
    "from_pitch_deg",
    "to_yaw_deg",
    "to_pitch_deg",
)
NS_PER_S = 1_000_000_000


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "gaze-trace",
        help="write one agent's saccades (Eyes Alive model) as CSV",
        description="Run the gaze model for one agent on virtual time and write every saccade: onset time, "
        "kind (mutual, away, head), the drawn magnitude, the amplitude and direction moved, duration and the "
        "hold time that follows.",
    )
    parser.add_argument("--eyes", choices=MODES, default="saccade", help="eye mode (default: saccade)")
    parser.add_argument("--role", choices=ROLES, default="talking", help="conversational role (default: talking)")
    parser.add_argument("--emotion", default="natural", help="emotion from configs/gaze_emotions.toml")
    parser.add_argument("--intensity", type=float, default=1.0, help="emotion intensity in [0, 1]")
    parser.add_argument("--seconds", type=float, default=60.0, help="virtual seconds to run (default: 60)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    parser.add_argument("-o", "--output", help="CSV file to write (default: standard output)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if not (math.isfinite(args.seconds) and 0.0 < args.seconds <= 86_400.0):
        print(f"eca gaze-trace: --seconds must be in (0, 86400], got {args.seconds}", file=sys.stderr)
        return 2
    try:
        params = GazeParams.load()
        engine = GazeEngine(1, seed=args.seed, params=params, role=args.role, mode=args.eyes)
        engine.set_emotion(0, args.emotion, args.intensity, 0)
    except (ConfigError, ValueError) as exc:
        print(f"eca gaze-trace: {exc}", file=sys.stderr)
        return 2
    end_ns = round(args.seconds * NS_PER_S)
    if args.output is None:
        write_trace(engine, end_ns, sys.stdout)
        return 0
    try:
        with open(args.output, "w", newline="") as fh:
            count = write_trace(engine, end_ns, fh)
    except OSError as exc:
        print(f"eca gaze-trace: cannot write {args.output}: {exc.strerror}", file=sys.stderr)
        return 1
    print(f"wrote {count} saccades to {args.output}", file=sys.stderr)
    return 0


def write_trace(engine: GazeEngine, end_ns: int, out: TextIO, step_ns: int = NS_PER_S) -> int:
    """Tick the engine to `end_ns` (onsets are exact whatever the step) and write agent 0's saccades."""
    writer = csv.writer(out)
    writer.writerow(COLUMNS)
    count = 0
    t = 0
    while t < end_ns:
        t = min(t + step_ns, end_ns)
        s = engine.tick(t).saccades
        for k in range(len(s)):
            writer.writerow(
                (
                    _fixed(s.onset_ns[k] / NS_PER_S, 9),
                    KINDS[s.kind[k]],
                    _fixed(s.magnitude_deg[k], 4),
                    _fixed(s.amplitude_deg[k], 4),
                    _fixed(s.direction_deg[k], 2),
                    _fixed(s.duration_s[k], 9),
                    _fixed(s.hold_s[k], 9),
                    _fixed(s.from_yaw_deg[k], 4),
                    _fixed(s.from_pitch_deg[k], 4),
                    _fixed(s.to_yaw_deg[k], 4),
                    _fixed(s.to_pitch_deg[k], 4),
                )
            )
            count += 1
    return count


def _fixed(value: float, digits: int) -> str:
    # Adding 0.0 after rounding turns -0.0 into 0.0, so the CSV never shows "-0.0000".
    return f"{round(float(value), digits) + 0.0:.{digits}f}"
