"""Bench part for bench/reliability.py: the settings and the final commands that its processes (the orchestrator, the
flood's senders, the monitor) share."""

from __future__ import annotations

import struct
import sys
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent

AGENT = "ada"
READY_TIMEOUT_S = 90.0  # eca up to "ready": the renderer's JIT cache may be cold
WARM_UP_S = 3.0
AFTER_FLOOD_S = 5.0  # the third RSS reading, this long after the flood's end
PROBE_PERIOD_S = 0.05
PROBE_ANSWER_TIMEOUT_S = 2.0
PROBE_EMOTION = "happy"
SETTLE_TIMEOUT_S = 30.0
INTERRUPT_AFTER_S = 30.0
SAY_RATE_HZ = 22_050
POOL_SIZE = 10_000  # distinct messages a sender cycles through (pre-encoded, so sending is cheap)

# Targets
TARGET_FPS_OF_60 = 58.0
TARGET_PROBE_MS = 100.0
TARGET_SETTLE_MS = 100.0
TARGET_RSS_GROWTH = 0.10
TARGET_START_S = 1.0
PLAYED_TOLERANCE_S = 0.5

# The final command per state; the flood never sends these values, so seeing one means it arrived.
FINAL_COMMANDS: dict[str, dict[str, Any]] = {
    "emotion": {"type": "set_emotion", "name": "surprised", "intensity": 0.37, "transition_s": 0.2},
    "head": {"type": "move_head", "turn": 0.21, "nod": 0.0, "tilt": 0.0, "duration_s": 0.3},
    "role": {"type": "set_role", "role": "silence", "speaker": ""},
    "gaze_target": {"type": "set_gaze_target", "yaw_deg": 7.5, "pitch_deg": 0.0, "target": "user"},
    "eyes": {"type": "set_eyes", "mode": "saccade"},
}
STATE_KINDS = tuple(FINAL_COMMANDS)


# Load for the says: a pure Python loop per core, which ends itself if the bench dies without stopping it.
BUSY_LOOP = ("import os\nparent = os.getppid()\nwhile os.getppid() == parent:\n"
             "    for _ in range(1_000_000):\n        pass\n")


def is_final(kind: str, state: dict[str, Any]) -> bool:
    """Whether a decoded state message carries the final value of its kind."""
    if kind == "emotion":
        return state.get("name") == "surprised" and state.get("intensity") == 0.37
    if kind == "head":
        return state.get("turn") == 0.21
    if kind == "role":
        return state.get("role") == "silence"
    if kind == "gaze_target":
        return state.get("yaw_deg") == 7.5
    return state.get("mode") == "saccade"


def _packed_float(x: float) -> bytes:
    return b"\xcb" + struct.pack(">d", x)


# A state payload can only be final if it holds these bytes: most flood states are skipped undecoded.
FINAL_MARKERS: dict[str, bytes] = {
    "emotion": _packed_float(0.37), "head": _packed_float(0.21), "role": b"\xa7silence",
    "gaze_target": _packed_float(7.5), "eyes": b"\xa7saccade",
}


def say_stderr(line: str) -> None:
    print(f"[reliability] {line}", file=sys.stderr, flush=True)


def reliability_command(*args: str) -> list[str]:
    """bench/reliability.py with `args`: how the orchestrator starts its senders and monitor."""
    return [sys.executable, str(REPO / "bench" / "reliability.py"), *args]


def wait_readable(sock: Any, timeout_s: float) -> bool:
    return bool(sock.poll(max(0, int(timeout_s * 1000))))
