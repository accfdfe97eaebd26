"""Bench part for bench/pipecat.py: the settings and helpers its phases share."""

from __future__ import annotations

import os
import sys

from bench.procs import descendants, proc_table

AGENT = "ada"
WIDTH, HEIGHT, FPS = 640, 480, 30.0
TTS_RATE = 24_000  # the pipeline's output rate (pipecat's default)
FRAME_MS = 20
REPLIES = ("Yes, of course.", "I see.", "Sure.", "Right, let me think.")
BURST_S = 0.25
BURST_GAP_S = (0.45, 0.75)  # silence between bursts, drawn per burst
BURST_LEVEL = 0.5
EDGE_WINDOW_MS = 150.0  # pictures this close to a burst's start or end judge its offset
MAX_SHIFT_MS = 120.0
MOUTH_BOX = (0.35, 0.6, 0.65, 0.9)  # x0, y0, x1, y1 of the picture, around the mouth
CPU_BASELINE_BURSTS = 10


def progress(line: str) -> None:
    print(f"[pipecat-bench] {line}", file=sys.stderr, flush=True)


def process_cpu_s() -> float:
    """This process's CPU time so far, every thread included."""
    t = os.times()
    return t.user + t.system


def tree_cpu_s(root_pid: int) -> float:
    """CPU time (utime + stime) of a process and all its descendants, from /proc."""
    table = proc_table()
    return sum(table[pid].own_ticks for pid in descendants(root_pid, table)) / os.sysconf("SC_CLK_TCK")
