"""`eca gaze-trace`: run the gaze model for one agent and write its saccades and blinks as CSV."""

from __future__ import annotations

import argparse
import csv
import math
import sys
from typing import TextIO

from eca.agent.config import ConfigError
from eca.agent.gaze.engine import GazeEngine
from eca.agent.gaze.params import KINDS, MODES, ROLES, GazeParams

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
BLINK = "blink"
# Every kind a row can have: the engine's kinds of saccade (KINDS: Eyes Alive's mutual and away decisions,
# head-led saccades, and the scans and microsaccades of mode saccade+noise+blink), then the blink model's blinks.
EVENT_KINDS: tuple[str, ...] = (*KINDS, BLINK)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "gaze-trace",
        help="write one agent's saccades and blinks (Eyes Alive model and its extensions) as CSV",
        description="Run the gaze model for one agent on virtual time and write one row per event, in time "
        "order. Saccades (kind mutual, away, head, and in mode saccade+noise+blink scan and micro): onset, "
        "kind, the drawn magnitude, the amplitude and direction moved, duration, the hold time that follows, "
        "from and to positions. Blinks of the statistical blink model (kind blink, modes saccade+blink and "
        "saccade+noise+blink): onset, kind and the lid curve's duration, the other columns empty.",
    )
    parser.add_argument("--eyes", choices=MODES, default="saccade",
                        help="eye mode (default: saccade, the paper's condition c)")
    parser.add_argument("--role", choices=ROLES, default="talking", help="conversational role (default: talking)")
    parser.add_argument("--emotion", default="natural", help="emotion from configs/gaze_emotions.toml")
    parser.add_argument("--intensity", type=float, default=1.0, help="emotion intensity in [0, 1]")
    parser.add_argument("--seconds", type=float, default=60.0, help="virtual seconds to run (default: 60)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    parser.add_argument("--kinds", default=",".join(EVENT_KINDS),
                        help=f"comma-separated kinds of event to write (default: all: {','.join(EVENT_KINDS)})")
    parser.add_argument("-o", "--output", help="CSV file to write (default: standard output)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if not (math.isfinite(args.seconds) and 0.0 < args.seconds <= 86_400.0):
        print(f"eca gaze-trace: --seconds must be in (0, 86400], got {args.seconds}", file=sys.stderr)
        return 2
    try:
        kinds = parse_kinds(args.kinds)
        params = GazeParams.load()
        engine = GazeEngine(1, seed=args.seed, params=params, role=args.role, mode=args.eyes)
        engine.set_emotion(0, args.emotion, args.intensity, 0)
    except (ConfigError, ValueError) as exc:
        print(f"eca gaze-trace: {exc}", file=sys.stderr)
        return 2
    end_ns = round(args.seconds * NS_PER_S)
    if args.output is None:
        write_trace(engine, end_ns, sys.stdout, kinds=kinds)
        return 0
    try:
        with open(args.output, "w", newline="") as fh:
            counts = write_trace(engine, end_ns, fh, kinds=kinds)
    except OSError as exc:
        print(f"eca gaze-trace: cannot write {args.output}: {exc.strerror}", file=sys.stderr)
        return 1
    saccades = sum(n for kind, n in counts.items() if kind != BLINK)
    by_kind = ", ".join(f"{kind} {n}" for kind, n in counts.items() if n)
    print(f"wrote {saccades} saccades and {counts[BLINK]} blinks to {args.output}"
          + (f" ({by_kind})" if by_kind else ""), file=sys.stderr)
    return 0


def parse_kinds(text: str) -> frozenset[str]:
    """The kinds named in a --kinds value ("away,blink"), each one of EVENT_KINDS."""
    kinds = [k.strip() for k in text.split(",") if k.strip()]
    unknown = [k for k in kinds if k not in EVENT_KINDS]
    if unknown or not kinds:
        raise ValueError(f"--kinds: unknown kind {unknown[0]!r}; valid: {', '.join(EVENT_KINDS)}" if unknown
                         else f"--kinds names no kind; valid: {', '.join(EVENT_KINDS)}")
    return frozenset(kinds)


def write_trace(
    engine: GazeEngine, end_ns: int, out: TextIO, step_ns: int = NS_PER_S, kinds: frozenset[str] | None = None
) -> dict[str, int]:
    """Tick the engine to `end_ns` (onsets are exact whatever the step) and write agent 0's events of the given
    `kinds` (default: all) in time order, a blink after a saccade of the same instant (the blink it evoked).
    Returns the number of rows written per kind."""
    wanted = frozenset(EVENT_KINDS) if kinds is None else kinds
    blink_s = f"{engine.params.blink.duration_s:.9f}"
    writer = csv.writer(out)
    writer.writerow(COLUMNS)
    counts = dict.fromkeys(EVENT_KINDS, 0)
    t = 0
    while t < end_ns:
        t = min(t + step_ns, end_ns)
        tick = engine.tick(t)
        s, b = tick.saccades, tick.blinks
        # (onset, 0 for a saccade or 1 for a blink, index): both lists are sorted by onset already.
        events = [(int(s.onset_ns[k]), 0, k) for k in range(len(s)) if s.agent[k] == 0]
        events += [(int(b.onset_ns[k]), 1, k) for k in range(len(b)) if b.agent[k] == 0]
        for onset_ns, is_blink, k in sorted(events):
            kind = BLINK if is_blink else KINDS[s.kind[k]]
            if kind not in wanted:
                continue
            counts[kind] += 1
            if is_blink:
                writer.writerow((_fixed(onset_ns / NS_PER_S, 9), BLINK, "", "", "", blink_s, "", "", "", "", ""))
                continue
            writer.writerow(
                (
                    _fixed(onset_ns / NS_PER_S, 9),
                    kind,
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
    return counts


def _fixed(value: float, digits: int) -> str:
    # Adding 0.0 after rounding turns -0.0 into 0.0, so the CSV never shows "-0.0000".
    return f"{round(float(value), digits) + 0.0:.{digits}f}"
