"""Reaction latency: from publishing a command to the first rendered frame that shows it.

Starts a private instance (broker, dialogue, gaze and a headless renderer, each its own process), then:

1. emotion: SetEmotion (alternating happy / angry, no transition) -> the first face frame whose
   expression flexors are the emotion's;
2. role: SetRole (alternating talking / listening, emotion natural) -> the first face frame whose eyes
   are on the saccade the role change starts: composed for a time after its onset, eyes moved off the
   fixation. That is the pipeline's latency (the target). The eye model's bell velocity profile (paper
   eq. 3) starts slowly, so the eyes reach 0.05 deg several ms after onset whatever the renderer does:
   the first frame that far along is reported too ("visible"). A role change whose saccade is too small
   to see (mutual gaze back to where the eyes already are) is not a trial; --trials counts measured ones;
3. load: the renderer's sustained frame rate with no extra traffic, then while another process floods
   its eye-state topic with 5,000 messages per second.

The latency of a trial is the face frame's publish stamp (taken after the frame is drawn) minus the
command's publish stamp, both on the monotonic clock of this host. Emotion trials are also split at
the stamps on the way (`parts`): bus (command -> the dialogue service's new state), wait (-> the slot
of the frame that shows it) and draw (slot -> the frame drawn and published): the worst case is a
period of waiting plus the draw, so the draw's tail decides whether p99 <= period + 3 ms holds.
The baseline is the frame period: ratios are latency / period. Target: p99 <= one period + 3 ms;
under load the renderer holds its rate.

    python bench/reaction.py [--fps 60] [--size 640x480] [--trials 40] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import subprocess
import sys
import time
from contextlib import ExitStack
from pathlib import Path

import numpy as np
import zmq

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from eca.agent.face.emotions import load_emotion_table  # noqa: E402
from eca.agent.face.flexors import FLEXOR_NAMES  # noqa: E402
from eca.protocol.bus import Publisher, Subscriber  # noqa: E402
from eca.protocol.client import AgentClient  # noqa: E402
from eca.protocol.endpoints import BusConfig, load_bus_config  # noqa: E402
from eca.protocol.messages import ALL_AGENTS, EmotionState, EyeStates, FaceFrame, Saccade  # noqa: E402
from tests.support.bus import private_bus_config, running  # noqa: E402

EXPRESSION = [n for n in FLEXOR_NAMES if n not in ("look_x", "look_y", "blink_l", "blink_r", "turn", "nod", "tilt")]


def service_argv(config: BusConfig, name: str, *extra: str) -> list[str]:
    return [sys.executable, "-m", "eca.services.processes.run", name, "--config", str(config.config_path),
            "--instance", config.instance, *extra]


def shows(frame: FaceFrame, target: dict[str, float]) -> bool:
    return all(abs(frame.flexors[k] - v) < 1e-6 for k, v in target.items())


def next_frame(
    sub: Subscriber, timeout_s: float, saccades: list[Saccade] | None = None, emotions: list[EmotionState] | None = None
) -> FaceFrame | None:
    deadline = time.monotonic() + timeout_s
    while (left := deadline - time.monotonic()) > 0:
        got = sub.recv(left)
        if got is None:
            return None
        if isinstance(got.message, FaceFrame):
            return got.message
        if isinstance(got.message, Saccade) and saccades is not None:
            saccades.append(got.message)
        if isinstance(got.message, EmotionState) and emotions is not None:
            emotions.append(got.message)
    return None


def settle(sub: Subscriber, seconds: float, saccades: list[Saccade] | None = None) -> FaceFrame | None:
    """Read frames for `seconds` (a random pause between trials, so commands land at every frame phase)."""
    last = None
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        f = next_frame(sub, deadline - time.monotonic(), saccades)
        last = f or last
    return last


def emotion_trials(
    client: AgentClient, sub: Subscriber, n: int, rng: random.Random
) -> tuple[list[float], dict[str, list[float]]]:
    """Latencies (ms), and each split at the stamps on the way: the dialogue service's new state
    (`bus`: command -> state published), the slot of the frame that shows it (`wait`: state -> frame
    slot, the broker hop included) and the frame's publication (`draw`: slot -> frame drawn and sent)."""
    table = load_emotion_table()
    targets = {}
    for name in ("happy", "angry"):
        pose = table.pose(name)
        targets[name] = {k: float(pose[FLEXOR_NAMES.index(k)]) for k in EXPRESSION
                         if not np.isnan(pose[FLEXOR_NAMES.index(k)])}
    out: list[float] = []
    parts: dict[str, list[float]] = {"bus": [], "wait": [], "draw": []}
    for i in range(n):
        name = ("happy", "angry")[i % 2]
        settle(sub, rng.uniform(0.05, 0.15))
        sent = client.set_emotion(name, 1.0, transition_s=0.0)
        emotions: list[EmotionState] = []
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            f = next_frame(sub, deadline - time.monotonic(), emotions=emotions)
            if f is not None and shows(f, targets[name]):
                out.append((f.t_ns - sent.t_ns) / 1e6)
                state = next((e for e in emotions if e.name == name and e.t_ns >= sent.t_ns), None)
                if state is not None:
                    parts["bus"].append((state.t_ns - sent.t_ns) / 1e6)
                    parts["wait"].append((f.frame_ns - state.t_ns) / 1e6)
                    parts["draw"].append((f.t_ns - f.frame_ns) / 1e6)
                break
    return out, parts


def role_trials(
    client: AgentClient, sub: Subscriber, n: int, rng: random.Random
) -> tuple[list[float], list[float], int]:
    """Latencies (ms) to the first frame on the new saccade and to the first with it 0.05 deg along."""
    client.set_emotion("natural", 1.0, transition_s=0.0)  # an emotion's gaze statistics can hold mutual gaze
    on_saccade: list[float] = []
    visible: list[float] = []
    skipped = 0
    for i in range(n * 5):
        if len(on_saccade) >= n:
            break
        saccades: list[Saccade] = []
        settle(sub, rng.uniform(0.25, 0.4), saccades)
        role = ("talking", "listening")[i % 2]
        saccades.clear()
        sent = client.set_role(role, speaker="ada" if role == "talking" else "user")
        deadline = time.monotonic() + 2.0
        first: float | None = None
        while time.monotonic() < deadline:
            f = next_frame(sub, deadline - time.monotonic(), saccades)
            started = [s for s in saccades if s.onset_ns >= sent.t_ns]
            if not started:
                continue
            s = started[0]
            if s.amplitude_deg < 1.0:
                skipped += 1  # a mutual saccade back to where the eyes already are: nothing to see
                break
            if f is None or f.frame_ns <= s.onset_ns:
                continue
            eyes = (f.flexors["look_x"] * 30.0, f.flexors["look_y"] * 30.0)
            moved = abs(eyes[0] - s.from_yaw_deg) + abs(eyes[1] - s.from_pitch_deg)
            if first is None and moved > 1e-9:
                first = (f.t_ns - sent.t_ns) / 1e6
            if moved > 0.05:
                if first is not None:
                    on_saccade.append(first)
                    visible.append((f.t_ns - sent.t_ns) / 1e6)
                break
    return on_saccade, visible, skipped


def frame_rate(sub: Subscriber, seconds: float) -> dict[str, float]:
    stamps: list[int] = []
    slots: list[int] = []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        f = next_frame(sub, deadline - time.monotonic())
        if f is not None:
            stamps.append(f.t_ns)
            slots.append(f.frame_ns)
    if len(stamps) < 2:
        return {"fps": 0.0, "interval_p99_ms": float("nan"), "lag_median_ms": float("nan")}
    intervals = np.diff(stamps) / 1e6
    return {"fps": (len(stamps) - 1) / ((stamps[-1] - stamps[0]) / 1e9),
            "interval_p99_ms": float(np.percentile(intervals, 99)),
            "lag_median_ms": float(np.median((np.array(stamps) - np.array(slots)) / 1e6))}


def flood(config_path: str, instance: str, rate: float, seconds: float) -> int:
    """Publish eye states for 'ada' at `rate` per second for `seconds` (run as its own process)."""
    config = load_bus_config(config_path, instance)
    ctx = zmq.Context()
    pub = Publisher(ctx, config, "flood")
    pub.wait_ready()
    sent = 0
    t0 = time.monotonic()
    while (elapsed := time.monotonic() - t0) < seconds:
        due = int(elapsed * rate)
        while sent < due:
            pub.publish(EyeStates(agent=ALL_AGENTS, agents=["ada"], yaw_deg=[1.0], pitch_deg=[0.0], lid=[0.0],
                                  mode=["saccade+blink"]))
            sent += 1
        time.sleep(0.002)  # pacing of the load generator, not synchronisation
    pub.close()
    ctx.term()
    print(json.dumps({"sent": sent, "seconds": time.monotonic() - t0}), flush=True)
    return 0


def stats(values: list[float], period_ms: float) -> dict[str, float]:
    if not values:
        return {"n": 0}
    a = np.array(values)
    return {"n": len(values), "median_ms": float(np.median(a)), "p99_ms": float(np.percentile(a, 99)),
            "max_ms": float(a.max()), "median_ratio": float(np.median(a) / period_ms),
            "p99_ratio": float(np.percentile(a, 99) / period_ms)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--fps", type=float, default=60.0)
    p.add_argument("--size", default="640x480")
    p.add_argument("--trials", type=int, default=40, help="trials per command kind")
    p.add_argument("--load-seconds", type=float, default=5.0)
    p.add_argument("--rate", type=float, default=5000.0, help="flood messages per second")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    p.add_argument("--flood", nargs=2, metavar=("CONFIG", "INSTANCE"), help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.flood:
        return flood(args.flood[0], args.flood[1], args.rate, args.load_seconds)
    period_ms = 1000.0 / args.fps
    rng = random.Random(args.seed)
    say = (lambda *a: print(*a, file=sys.stderr)) if args.json else print
    with private_bus_config() as config, ExitStack() as stack:
        for name in ("broker", "dialogue", "gaze"):
            _, out = stack.enter_context(running(service_argv(config, name)))
            out.wait_for("ready", 30)
        _, out = stack.enter_context(running(service_argv(
            config, "renderer", "--headless", "--no-idle", "--fps", str(args.fps), "--size", args.size)))
        out.wait_for("ready", 60)
        ctx = zmq.Context()
        sub = Subscriber(ctx, config, ["stream.ada.face_frame", "event.ada.saccade", "state.ada.emotion"])
        sub.wait_ready()
        client = AgentClient(config, agent="ada", ctx=ctx)
        try:
            if next_frame(sub, 30.0) is None:
                raise SystemExit("the renderer drew no frame")
            settle(sub, 1.0)
            say(f"renderer: headless {args.size} at {args.fps:g} fps; frame period {period_ms:.2f} ms (baseline)")
            emotion_ms, emotion_parts = emotion_trials(client, sub, args.trials, rng)
            emotion = stats(emotion_ms, period_ms)
            emotion["parts"] = {
                part: {"median_ms": float(np.median(v)), "p99_ms": float(np.percentile(v, 99))}
                for part, v in emotion_parts.items() if v
            }
            say(f"emotion -> frame: {json.dumps(emotion)}")
            role_ms, visible_ms, skipped = role_trials(client, sub, args.trials, rng)
            role = stats(role_ms, period_ms)
            role["skipped_small_saccades"] = skipped
            role["visible_0_05_deg"] = stats(visible_ms, period_ms)
            say(f"role -> frame:    {json.dumps(role)}")
            idle = frame_rate(sub, args.load_seconds)
            say(f"frame rate, no extra traffic: {json.dumps(idle)}")
            flooder = subprocess.Popen(
                [sys.executable, str(Path(__file__).resolve()), "--flood", str(config.config_path), config.instance,
                 "--rate", str(args.rate), "--load-seconds", str(args.load_seconds + 1.5)],
                stdout=subprocess.PIPE, env=dict(os.environ, PYTHONUNBUFFERED="1"))
            settle(sub, 1.0)
            loaded = frame_rate(sub, args.load_seconds)
            flood_out, _ = flooder.communicate(timeout=60)
            sent = json.loads(flood_out.decode().strip().splitlines()[-1])
            loaded["messages_per_s"] = sent["sent"] / sent["seconds"]
            say(f"frame rate under {loaded['messages_per_s']:.0f} msg/s: {json.dumps(loaded)}")
        finally:
            client.close()
            sub.close()
            ctx.term()
    target = period_ms + 3.0
    result = {
        "fps": args.fps, "size": args.size, "frame_period_ms": period_ms, "target_p99_ms": target,
        "emotion": emotion, "role": role,
        "target_met": bool(emotion.get("p99_ms", 1e9) <= target and role.get("p99_ms", 1e9) <= target),
        "fps_idle": idle["fps"], "fps_loaded": loaded["fps"], "load_messages_per_s": loaded["messages_per_s"],
        "fps_loaded_ratio": loaded["fps"] / args.fps, "fps_loaded_vs_idle": loaded["fps"] / max(idle["fps"], 1e-9),
        "frame_lag_median_ms": idle["lag_median_ms"],
    }
    say(f"p99 target {target:.2f} ms: {'met' if result['target_met'] else 'NOT met'}; "
        f"under load {loaded['fps']:.1f} fps = {result['fps_loaded_ratio']:.2f} x {args.fps:g}")
    if args.json:
        print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
