"""Benchmark: offline render of the demo dialogue (about 60 s) at 30 fps to MP4 with audio.

Baseline: the dialogue's own length (real time). Target: the render takes at most 0.5x real time on
this machine's software OpenGL. Also prints the models' share (no GL, no encoding) and peak memory.
Each figure is the median of --runs runs in fresh processes.
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DIALOGUE = ROOT / "eca" / "configs" / "demo" / "dialogue.xml"

MODELS_ONLY = """
import time
from eca.agent.script import build_timeline
from eca.services.tools.offline import RenderSettings, animate
from eca.services.tools.playback import VoiceCache
voices = VoiceCache()
timeline = build_timeline([{path!r}], agent="ada", text_duration=voices.duration_of_text)
t0 = time.perf_counter()
animate(timeline, "ada", RenderSettings(fps={fps}), voices)
print(time.perf_counter() - t0, timeline.length_s)
"""


def run_render(fps: float, size: str) -> tuple[float, float]:
    with tempfile.TemporaryDirectory() as tmp:
        before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "eca.services.tools.cli", "render", str(DIALOGUE),
                        "-o", f"{tmp}/demo.mp4", "--fps", str(fps), "--size", size],
                       check=True, cwd=ROOT, capture_output=True)
        took = time.perf_counter() - t0
        peak_mib = max(before, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss) / 1024
    return took, peak_mib


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=2)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--size", default="640x480")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    run_render(args.fps, args.size)  # warm the voice cache: synthesis is not rendering
    models = []
    length_s = 0.0
    for _ in range(args.runs):
        out = subprocess.run([sys.executable, "-c", MODELS_ONLY.format(path=str(DIALOGUE), fps=args.fps)],
                             check=True, cwd=ROOT, capture_output=True, text=True).stdout.split()
        models.append(float(out[0]))
        length_s = float(out[1])
    renders = [run_render(args.fps, args.size) for _ in range(args.runs)]
    render_s = statistics.median(r[0] for r in renders)
    result = {
        "dialogue_s": round(length_s, 2),
        "fps": args.fps,
        "size": args.size,
        "render_s_median": round(render_s, 2),
        "render_vs_real_time": round(render_s / length_s, 3),
        "target_vs_real_time": 0.5,
        "models_only_s_median": round(statistics.median(models), 2),
        "peak_rss_mib": round(max(r[1] for r in renders), 1),
        "runs": args.runs,
    }
    print(f"dialogue {length_s:.1f} s at {args.fps:g} fps, {args.size}: render {render_s:.1f} s "
          f"= {result['render_vs_real_time']:.2f}x real time (target <= 0.5x); models alone "
          f"{result['models_only_s_median']:.1f} s; peak memory {result['peak_rss_mib']:.0f} MiB")
    if args.json:
        print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
