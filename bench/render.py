"""Benchmark: one face frame at 640x480 (compose + draw + read-back) against a bare clear + read-back, and the
3D head's frame against the 2D face's.

A frame is what the renderer service does per display frame, headless: compose the flexor frame from
the face model (emotion, head motion, gaze, blink, mouth layers, idle noise) at the frame's time, pose
and draw the face into the offscreen framebuffer, read the pixels back. The baseline clears the same
framebuffer and reads it back, so it holds everything except the face. The 3D head's frame is the same
composed face drawn by the head drawer (renderer/head/: retarget, drive the avatar, morph and skin on the
GPU, draw) and read back. All run interleaved in short blocks (bare, 2D, head, head, 2D, bare) so drift of
a shared machine hits them alike; figures are medians per frame. The head's memory is the process's
resident memory before the head drawer is made and after it has drawn (software GL keeps the GPU's
objects in the process), beside what the avatar's GPU objects take by their sizes.

    python bench/render.py [--frames 600] [--size 640x480] [--head default|sample|none|PATH] [--json]

Targets on software OpenGL (llvmpipe, 2 cores): >= 200 frames/s for the 2D face's whole frame and at
most 3 ms over the bare baseline; the head's whole frame >= 60 frames/s and at most 3 times the 2D
face's. `--head default` is eca/assets/default_head.glb (the sample head when it is not baked yet),
`sample` the procedural head of renderer/head/sample.py, a path any .glb/.gltf/.vrm.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from eca.agent.face.composed import ComposedFace  # noqa: E402
from eca.agent.face.model import FaceModel  # noqa: E402
from eca.agent.face.settings import load_flexor_units  # noqa: E402
from eca.services.processes.renderer import Renderer, create_headless_context, read_rgb  # noqa: E402

TARGET_FPS = 200.0
TARGET_OVERHEAD_MS = 3.0
TARGET_HEAD_FPS = 60.0
TARGET_HEAD_RATIO = 3.0  # the head's whole frame against the 2D face's
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


def resident_mb() -> float:
    """The process's resident memory (Linux /proc; 0 where there is none)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0


def head_avatar(choice: str) -> tuple[object, str]:
    """The avatar (or its file) `--head` names, and what to call it."""
    from eca.services.processes.renderer.head import DEFAULT_HEAD, sample_avatar

    if choice == "default" and DEFAULT_HEAD.exists():
        return DEFAULT_HEAD, "default head"
    if choice in ("default", "sample"):
        return sample_avatar(), "sample head" + (" (the default head is not baked)" if choice == "default" else "")
    return Path(choice), Path(choice).name


def measure(frames: int, size: tuple[int, int], head: str = "default") -> dict[str, Any]:
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

    # The 3D head: the same faces (a face model of its own, seeded alike), composed, drawn and read back.
    drawer = None
    head_parts: dict[str, list[float]] = {"compose": [], "rig": [], "draw": [], "readback": []}
    head_info: dict[str, object] = {}
    if head != "none":
        from eca.services.processes.renderer.head import HeadDrawer

        avatar, head_name = head_avatar(head)
        units = load_flexor_units()
        head_model = FaceModel(seed=1)
        before_mb = resident_mb()
        drawer = HeadDrawer(ctx, size, avatar)  # type: ignore[arg-type]
        head_fbo = drawer.fbo

        def head_frame(i: int) -> None:
            drive(head_model, i)
            face = ComposedFace.from_frame(head_model.frame_at(i * FRAME_NS), units)
            drawer.draw(face)
            read_rgb(head_fbo)

        def head_split(i: int) -> None:
            t0 = time.perf_counter()
            drive(head_model, i)
            face = ComposedFace.from_frame(head_model.frame_at(i * FRAME_NS), units)
            t1 = time.perf_counter()
            pose = drawer.driver.drive(drawer.retargeter.retarget(face))
            t2 = time.perf_counter()
            drawer.draw_pose(pose)
            ctx.finish()
            t3 = time.perf_counter()
            read_rgb(head_fbo)
            t4 = time.perf_counter()
            for key, a, b in (("compose", t0, t1), ("rig", t1, t2), ("draw", t2, t3), ("readback", t3, t4)):
                head_parts[key].append(b - a)

        for i in range(30):
            head_frame(i)
        avatar_obj = drawer.avatar
        head_info = {
            "head": head_name,
            "head_vertices": sum(len(p.positions) for p in avatar_obj.primitives),
            "head_targets": len(avatar_obj.shapes),
            "head_primitives": len(avatar_obj.primitives),
            "head_samples": drawer.samples,
            "head_memory_mb": round(resident_mb() - before_mb, 1),
            "head_gpu_mb": round(drawer.gpu.nbytes / 2**20, 1),
        }

    times: dict[str, list[float]] = {"bare": [], "whole": [], "head": []}
    order = [("bare", bare), ("whole", whole)] + ([("head", head_frame)] if drawer is not None else [])
    order += order[::-1]
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
        if drawer is not None:
            head_split(i)
        i += 1
    resident_total = resident_mb()
    if drawer is not None:
        drawer.release()
    ctx.release()
    ms = {name: 1e3 * statistics.median(v) for name, v in times.items() if v}
    result: dict[str, Any] = {
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
    result["resident_mb"] = round(resident_total, 1)
    if drawer is not None:
        result.update(head_info)
        result.update({
            "head_frame_ms": round(ms["head"], 3),
            "head_fps": round(1e3 / ms["head"], 1),
            "head_ratio_vs_2d": round(ms["head"] / ms["whole"], 3),
            **{f"head_{k}_ms": round(1e3 * statistics.median(v), 3) for k, v in head_parts.items()},
            "target_head_fps": TARGET_HEAD_FPS,
            "target_head_ratio": TARGET_HEAD_RATIO,
        })
        result["head_meets_targets"] = (result["head_fps"] >= TARGET_HEAD_FPS
                                        and result["head_ratio_vs_2d"] <= TARGET_HEAD_RATIO)
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=600, help="timed frames of each kind (default 600)")
    parser.add_argument("--size", type=parse_size, default=(640, 480), help="framebuffer WxH (default 640x480)")
    parser.add_argument("--head", default="default",
                        help="the 3D head to measure: default, sample, none, or a .glb/.gltf/.vrm path")
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    args = parser.parse_args(argv)
    if args.frames < 1:
        parser.error("--frames must be at least 1")
    r = measure(args.frames, args.size, args.head)
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
    if "head_frame_ms" in r:
        print(
            f"3D head ({r['head']}: {r['head_vertices']} vertices, {r['head_targets']} shapes, "
            f"{r['head_samples']}x multisampling) frame {r['size']}: median {r['head_frame_ms']:.2f} ms = "
            f"{r['head_fps']:.0f} frames/s (target >= {TARGET_HEAD_FPS:.0f}), {r['head_ratio_vs_2d']:.2f}x the 2D "
            f"face's (target <= {TARGET_HEAD_RATIO:.0f}x)"
        )
        print(
            f"  parts: compose {r['head_compose_ms']:.2f} ms, retarget + drive {r['head_rig_ms']:.2f} ms, "
            f"deform + draw {r['head_draw_ms']:.2f} ms, read-back {r['head_readback_ms']:.2f} ms"
        )
        print(
            f"  memory: the head adds {r['head_memory_mb']:.1f} MB resident ({r['head_gpu_mb']:.1f} MB of it GPU "
            f"objects by their sizes); the process holds {r['resident_mb']:.0f} MB with it loaded"
        )
        print("head targets met" if r["head_meets_targets"] else "head targets NOT met")
    if args.json:
        print(json.dumps(r))
    return 0


if __name__ == "__main__":
    sys.exit(main())
