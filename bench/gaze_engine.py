"""Benchmark: GazeEngine ticks per second for 1 to 1,000,000 agents against a plain per-agent Python model.

The baseline is the same model written the obvious way, one Python object per agent: the reference model
(agent/gaze/reference.py, ReferenceAgent), whose trajectories are the engine's bit for bit
(tests/test_gaze_reference.py), its draws and transcendentals numpy scalar calls; each tick it produces
what the engine's tick does (every eye's position and lid, the saccade and blink onsets sorted by time).
It is timed on the same crowd up to 100,000 agents and
scaled per agent above that: its per-agent cost grows with the crowd (100,000 agents' objects miss the
caches that 2,000 fit in: about 1.7 times the cost per agent), so a small crowd scaled up would flatter
it, while at 100,000 it already pays the misses a larger crowd pays. Both run on virtual time at 60 Hz after
a warm-up that reaches the steady state, timed in alternating blocks so that load from other processes
hits both alike (see time_both). Figures are medians.

    python bench/gaze_engine.py [--sizes 1 1000 100000 1000000] [--ticks 60] [--json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.report import machine  # noqa: E402
from eca.agent.gaze.engine import GazeEngine  # noqa: E402
from eca.agent.gaze.params import GazeParams  # noqa: E402
from eca.agent.gaze.reference import Onset, ReferenceAgent  # noqa: E402

NS = 1_000_000_000
FRAME_NS = NS // 60
# Alternating blocks: each evicts the other's data from the caches, so a block's first ticks run cold.
# Engine blocks are long enough that those few stay out of the median; both kinds of block take well
# under a second at 100,000 agents, short against the drift of the load from other processes.
ENGINE_BLOCK_TICKS = 20
PYTHON_BLOCK_TICKS = 3
TARGETS_MS = {100_000: 2.0, 1_000_000: 16.7}


def reference_tick(agents: list[ReferenceAgent], t: int) -> tuple[list[tuple[float, float, float]], list, list]:
    """What GazeEngine.tick returns, agent by agent: every eye's state and the onsets, sorted by time."""
    states: list[tuple[float, float, float]] = []
    onsets: list[tuple[int, int, Onset]] = []
    blinks: list[tuple[int, int]] = []
    for agent in agents:
        tick = agent.tick(t)
        states.append((tick.yaw_deg, tick.pitch_deg, tick.lid))
        if tick.saccades:
            onsets.extend((onset.onset_ns, agent.index, onset) for onset in tick.saccades)
        if tick.blinks:
            blinks.extend((onset_ns, agent.index) for onset_ns in tick.blinks)
    onsets.sort(key=lambda onset: onset[:2])
    blinks.sort()
    return states, onsets, blinks


def time_both(params: GazeParams, n: int, python_n: int, ticks: int, mode: str) -> tuple[float, float]:
    """Median seconds per 60 Hz tick of the engine (n agents) and of plain Python (python_n agents).

    The two are timed in alternating blocks, so load from other processes hits both alike: `ticks` Python
    ticks in blocks of PYTHON_BLOCK_TICKS, each block followed by ENGINE_BLOCK_TICKS engine ticks.
    """
    engine = GazeEngine(n, seed=1, params=params, role="talking", mode=mode)
    agents = [ReferenceAgent(i, 1, params, 0, "talking", mode) for i in range(python_n)]
    for second in range(1, 11):  # warm-up to the steady state; onsets are exact whatever the step
        engine.tick(second * NS)
        reference_tick(agents, second * NS)
    start_ns = 10 * NS
    engine_samples: list[float] = []
    python_samples: list[float] = []
    python_k = engine_k = 0
    while len(python_samples) < ticks:
        for _ in range(min(PYTHON_BLOCK_TICKS, ticks - len(python_samples))):
            python_k += 1
            began = time.perf_counter()
            reference_tick(agents, start_ns + python_k * FRAME_NS)
            python_samples.append(time.perf_counter() - began)
        for _ in range(ENGINE_BLOCK_TICKS):
            engine_k += 1
            began = time.perf_counter()
            engine.tick(start_ns + engine_k * FRAME_NS)
            engine_samples.append(time.perf_counter() - began)
    return statistics.median(engine_samples), statistics.median(python_samples)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 1_000, 100_000, 1_000_000])
    parser.add_argument("--ticks", type=int, default=60,
                        help="measured 60 Hz ticks of plain Python per size (the engine gets more)")
    parser.add_argument("--python-agents", type=int, default=100_000,
                        help="largest crowd timed in plain Python (larger ones are scaled per agent)")
    parser.add_argument("--mode", choices=["saccade+blink", "saccade+noise+blink"], default=None,
                        help="eye mode of every agent (default: the configured default, the paper's recommendation)")
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    args = parser.parse_args(argv)
    if min(args.sizes) < 1 or args.ticks < 1 or args.python_agents < 1:
        parser.error("--sizes, --ticks and --python-agents must be at least 1")
    params = GazeParams.load()
    mode = args.mode or params.default_mode
    host = machine()  # the load moves every figure: it is printed with them
    print(f"eye mode {mode}, role talking, 60 Hz ticks; {host['cores']} cores, {host['cpu']}, "
          f"load average {host['load_average']}")
    results = []
    print(f"{'agents':>10} {'engine ms/tick':>15} {'ticks/s':>10} {'python ms/tick':>15} {'ratio':>8}  target")
    for n in args.sizes:
        python_n = min(n, args.python_agents)
        engine_s, python_s = time_both(params, n, python_n, args.ticks, mode)
        python_s *= n / python_n
        target = TARGETS_MS.get(n)
        row = {
            "agents": n,
            "engine_ms_per_tick": engine_s * 1e3,
            "engine_ticks_per_s": 1.0 / engine_s,
            "python_ms_per_tick": python_s * 1e3,
            "python_agents_timed": python_n,
            "ratio": python_s / engine_s,
            "target_ms": target,
        }
        results.append(row)
        verdict = "" if target is None else f"<= {target} ms: {'met' if engine_s * 1e3 <= target else 'MISSED'}"
        print(
            f"{n:>10,} {engine_s * 1e3:>15.3f} {1.0 / engine_s:>10.0f} {python_s * 1e3:>15.3f}"
            f" {python_s / engine_s:>7.0f}x  {verdict}",
            flush=True,
        )
    if args.json:
        print(json.dumps({"bench": "gaze_engine", "statistic": "median", "tick_hz": 60, "mode": mode,
                          "machine": host, "results": results}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
