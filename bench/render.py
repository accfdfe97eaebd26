"""Benchmark: one face frame at 640x480 (compose + draw + read-back) against a bare clear + read-back.

A frame is what the renderer service does per display frame, headless: compose the flexor frame from
the face model (emotion, head motion, gaze, blink, mouth layers, idle noise) at the frame's time, pose
and draw the face into the offscreen framebuffer, read the pixels back. The baseline clears the same
framebuffer and reads it back, so it holds everything except the face. Both run interleaved in short
blocks (ABBA) so drift of a shared machine hits both alike; figures are medians per frame.

    python bench/render.py [--frames 600] [--size 640x480] [--json]

Target on software OpenGL (llvmpipe, 2 cores): >= 200 frames/s for the whole frame and at most 3 ms
over the bare baseline.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from eca.agent.face.model import FaceModel  # noqa: E402
from eca.services.processes.renderer import Renderer, create_headless_context, read_rgb  # noqa: E402

TARGET_FPS = 200.0
TARGET_OVERHEAD_MS = 3.0
FRAME_NS = 16_666_667
BLOCK = 20  # frames per interleaved block


def parse_size(text: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--size must look like 640x480, got {text!r}") from None
    if width < 16 or height < 16:
        raise argparse.ArgumentTypeError(f"--size must be at least 16x16, got {text!r}")
    return width, height


def drive(model: FaceModel, i: int) -> None:
    """Keep every layer busy: a new emotion, gaze target, blink and mouth shape every few frames."""
    t_ns = i * FRAME_NS
    if i % 90 == 0:
        name = model.emotions.names[(i // 90) % len(model.emotions.names)]
        model.set_emotion(name, 1.0, t_ns=t_ns)
    if i % 120 == 0:
        model.move_head(0.3 * np.sin(i * 0.05), 0.2 * np.cos(i * 0.03), 0.1, 1.0, t_ns)
    blink = 1.0 if i % 150 < 6 else None
    model.set_eyes(20.0 * np.sin(i * 0.11), 10.0 * np.cos(i * 0.07), blink)
    model.set_mouth({"say_ah": 0.5 + 0.5 * np.sin(i * 0.3), "say_oo": 0.3 * (i % 40 < 20)})


def measure(frames: int, size: tuple[int, int]) -> dict[str, float]:
    ctx = create_headless_context()
    renderer = Renderer(ctx, size)
    fbo = renderer.fbo
    model = FaceModel(seed=1)
    bg = renderer.config.colors["background"]

    def bare(i: int) -> None:
        fbo.use()
        fbo.clear(bg[0], bg[1], bg[2], 1.0, depth=1.0)
        read_rgb(fbo)

    def whole(i: int) -> None:
        drive(model, i)
        frame = model.frame_at(i * FRAME_NS)
        renderer.render(frame.values)
        read_rgb(fbo)

    parts: dict[str, list[float]] = {"compose": [], "draw": [], "readback": []}

    def split(i: int) -> None:
        t0 = time.perf_counter()
        drive(model, i)
        frame = model.frame_at(i * FRAME_NS)
        t1 = time.perf_counter()
        renderer.render(frame.values)
        ctx.finish()
        t2 = time.perf_counter()
        read_rgb(fbo)
        t3 = time.perf_counter()
        parts["compose"].append(t1 - t0)
        parts["draw"].append(t2 - t1)
        parts["readback"].append(t3 - t2)

    for i in range(30):  # warm up: shader variants compile on first use
        whole(i)
        bare(i)
    times: dict[str, list[float]] = {"bare": [], "whole": []}
    order = (("bare", bare), ("whole", whole), ("whole", whole), ("bare", bare))
    i = 0
    while len(times["whole"]) < frames:
        for name, fn in order:
            for _ in range(BLOCK):
                t = time.perf_counter()
                fn(i)
                times[name].append(time.perf_counter() - t)
                i += 1
    for _ in range(min(frames, 200)):
        split(i)
        i += 1
    ctx.release()
    ms = {name: 1e3 * statistics.median(v) for name, v in times.items()}
    result = {
        "size": f"{size[0]}x{size[1]}",
        "frames": len(times["whole"]),
        "frame_ms": round(ms["whole"], 3),
        "baseline_ms": round(ms["bare"], 3),
        "overhead_ms": round(ms["whole"] - ms["bare"], 3),
        "ratio_vs_baseline": round(ms["whole"] / ms["bare"], 3),
        "fps": round(1e3 / ms["whole"], 1),
        "compose_ms": round(1e3 * statistics.median(parts["compose"]), 3),
        "draw_ms": round(1e3 * statistics.median(parts["draw"]), 3),
        "readback_ms": round(1e3 * statistics.median(parts["readback"]), 3),
        "target_fps": TARGET_FPS,
        "target_overhead_ms": TARGET_OVERHEAD_MS,
    }
    result["meets_targets"] = result["fps"] >= TARGET_FPS and result["overhead_ms"] <= TARGET_OVERHEAD_MS
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=600, help="timed frames of each kind (default 600)")
    parser.add_argument("--size", type=parse_size, default=(640, 480), help="framebuffer WxH (default 640x480)")
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    args = parser.parse_args(argv)
    if args.frames < 1:
        parser.error("--frames must be at least 1")
    r = measure(args.frames, args.size)
    print(
        f"face frame {r['size']}: median {r['frame_ms']:.2f} ms = {r['fps']:.0f} frames/s (target >= {TARGET_FPS:.0f})"
    )
    print(
        f"bare clear + read-back: median {r['baseline_ms']:.2f} ms; face costs {r['overhead_ms']:+.2f} ms over it "
        f"(target <= {TARGET_OVERHEAD_MS:.0f} ms), ratio {r['ratio_vs_baseline']:.2f}x"
    )
    print(
        f"  parts: compose {r['compose_ms']:.2f} ms, pose + draw {r['draw_ms']:.2f} ms, "
        f"read-back {r['readback_ms']:.2f} ms"
    )
    print("targets met" if r["meets_targets"] else "targets NOT met")
    if args.json:
        print(json.dumps(r))
    return 0


if __name__ == "__main__":
    sys.exit(main())
