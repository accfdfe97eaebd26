"""Benchmark: GazeEngine ticks per second for 1 to 1,000,000 agents against a plain per-agent Python model.

The baseline is the same model (Eyes Alive saccades, the statistical blink model, the bell velocity
profile) written the obvious way: one Python object per agent, `random.Random` per agent, `math.erf`
per in-flight eye; each tick it produces what the engine's tick does (every eye's position and lid,
the saccade and blink onsets sorted by time). It is timed on the same crowd up to 100,000 agents and
scaled per agent above that: its per-agent cost grows with the crowd (100,000 agents' objects miss the
caches that 2,000 fit in: about 1.7 times the cost per agent), so a small crowd scaled up would flatter
it, while at 100,000 it already pays the misses a larger crowd pays. Both run on virtual time at 60 Hz after
a warm-up that reaches the steady state, timed in alternating blocks so that load from other processes
hits both alike (see time_both). Figures are medians.

    python bench/gaze_engine.py [--sizes 1 1000 100000 1000000] [--ticks 60] [--json]
"""

from __future__ import annotations

import argparse
import bisect
import json
import math
import random
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from agent.gaze.engine import GazeEngine  # noqa: E402
from agent.gaze.params import GazeParams  # noqa: E402
from bench.report import machine  # noqa: E402

NS = 1_000_000_000
FRAME_NS = NS // 60
# Alternating blocks: each evicts the other's data from the caches, so a block's first ticks run cold.
# Engine blocks are long enough that those few stay out of the median; both kinds of block take well
# under a second at 100,000 agents, short against the drift of the load from other processes.
ENGINE_BLOCK_TICKS = 20
PYTHON_BLOCK_TICKS = 3
TARGETS_MS = {100_000: 2.0, 1_000_000: 16.7}


HOLD_TABLE_INTERVALS = 32_768


class PythonAgent:
    """One agent of the same model, in plain Python: the per-agent baseline (with `fixational`, the small
    saccades and drift of mode saccade+noise+blink as well).

    It does what the engine does for each agent and tick: advance its timers in time order (saccade
    decisions with the role's and emotion's statistics around its gaze target, spontaneous and
    gaze-evoked blinks), report every onset, and give its eye position and lid. Hold times are read from
    the same quantile tables as the engine's, the cheapest exact inverse CDF in Python too.
    """

    def __init__(self, params: GazeParams, index: int, seed: int, role: str, tables: dict[str, list[float]],
                 fixational: bool = False) -> None:
        self.p = params
        self.index = index
        self.rng = random.Random(seed)
        self.role_name = role
        self.role = params.roles[role]
        # Mode saccade+noise+blink: small saccades (scans over the partner's face, microsaccades) and drift
        # between the Eyes Alive saccades; the offset from the fixation's base point, the point held (0 the
        # gaze target, then the face features), and when the next small saccade starts.
        self.fixational = fixational
        self.offset = (0.0, 0.0)
        self.held = 0
        self.landed = 0
        self.next_small = 1 << 62
        self.small_mutual = False
        self.scan_cumulative = list(np.cumsum(params.fixation.feature_weights(role, index & 1)))[:-1]
        self.cumulative_direction = list(np.cumsum(params.direction_probability))
        self.bins = [math.radians(b) for b in params.direction_bins_deg]
        self.tables = tables
        self.interval_scale, self.magnitude_scale, self.mutual_shift = 1.0, 1.0, 0.0  # "natural"
        self.target = (0.0, 0.0)
        self.p_min = params.p_ref * math.exp(-self.role.max_magnitude_deg / params.a_scale_deg)
        self.blink_mean_s = 60.0 / self.role.blink_rate_per_min
        self.k = math.sqrt(math.pi) / 2.0
        self.erf_edge = math.erf(3.0 * self.k)
        self.onset = self.end = 0
        self.from_ = self.to = (0.0, 0.0)
        self.next_saccade = 0
        self.next_blink = self._blink_interval()
        self.blink_onset = -(10**18)

    def _hold(self, kind: str) -> float:
        table = self.tables[kind]
        x = self.rng.random() * HOLD_TABLE_INTERVALS
        cell = int(x)
        return (table[cell] + (table[cell + 1] - table[cell]) * (x - cell)) * self.interval_scale

    def _blink_interval(self) -> int:
        refractory = self.p.blink.refractory_s
        return round((refractory - (self.blink_mean_s - refractory) * math.log1p(-self.rng.random())) * NS)

    def _position(self, t: int) -> tuple[float, float]:
        if t >= self.end:
            return self.to
        tau = (t - self.onset) / (self.end - self.onset)
        progress = (math.erf(self.k * (6.0 * tau - 3.0)) + self.erf_edge) / (2.0 * self.erf_edge)
        return (
            self.from_[0] + (self.to[0] - self.from_[0]) * progress,
            self.from_[1] + (self.to[1] - self.from_[1]) * progress,
        )

    def _decide(self, t: int, onsets: list[tuple], blinks: list[tuple[int, int]]) -> None:
        p = self.p
        start = self._position(t)
        if self.fixational and t >= self.end:  # the small saccades left the eye off the fixation's base
            start = tuple(max(-30.0, min(30.0, s + o)) for s, o in zip(start, self.offset, strict=True))
        mutual = self.rng.random() < min(max(self.role.mutual_probability + self.mutual_shift, 0.0), 1.0)
        magnitude = -p.a_scale_deg * math.log((p.p_max - self.rng.random() * (p.p_max - self.p_min)) / p.p_ref)
        magnitude *= self.magnitude_scale
        direction = self.bins[bisect.bisect_right(self.cumulative_direction, self.rng.random())]
        if mutual:
            target = self.target
        else:
            target = (
                max(-30.0, min(30.0, self.target[0] + magnitude * math.cos(direction))),
                max(-30.0, min(30.0, self.target[1] + magnitude * math.sin(direction))),
            )
        hold = self._hold("mutual" if mutual else "away")
        d_yaw, d_pitch = target[0] - start[0], target[1] - start[1]
        amplitude = math.hypot(d_yaw, d_pitch)
        duration = round((p.d0_s + p.d_s_per_deg * amplitude) * NS)
        self.onset, self.end = t, t + duration
        self.from_, self.to = start, target
        self.next_saccade = self.end + round(hold * NS)
        if self.fixational:  # a new fixation at the landing point
            self.offset, self.held, self.landed, self.small_mutual = (0.0, 0.0), 0, self.end, mutual
            self.next_small = self.end + self._small_interval()
        onsets.append((
            t, self.index, start, target, amplitude if mutual else magnitude, amplitude,
            math.degrees(math.atan2(d_pitch, d_yaw)) % 360.0, duration * 1e-9, "mutual" if mutual else "away", hold,
        ))  # fmt: skip
        blink = p.blink
        chance = min(max((amplitude - blink.evoked_min_deg) / (blink.evoked_full_deg - blink.evoked_min_deg), 0), 1)
        if (
            self.rng.random() < chance * blink.evoked_max_probability
            and self.next_blink - t <= blink.pull_window_s * NS
        ):
            self.blink_onset = t
            self.next_blink += self._blink_interval()
            blinks.append((t, self.index))

    def _small_interval(self) -> int:
        fix = self.p.fixation
        mean = 1.0 / fix.event_rate_hz(self.role_name, self.small_mutual)
        return round((fix.refractory_s + self.rng.expovariate(1.0 / (mean - fix.refractory_s))) * NS)

    def _small_saccade(self, t: int, onsets: list[tuple]) -> None:
        """A scan (mutual gaze only) or a microsaccade, after the drift since the last landing."""
        fix, p = self.p.fixation, self.p
        sigma = math.sqrt(2.0 * fix.drift_diffusion_deg2_per_s * (t - self.landed) * 1e-9)
        off = (self.offset[0] + self.rng.gauss(0.0, sigma), self.offset[1] + self.rng.gauss(0.0, sigma))
        rate = fix.event_rate_hz(self.role_name, self.small_mutual)
        if self.rng.random() < (rate - fix.microsaccade_rate_hz) / rate:
            self.held = 1 + bisect.bisect_right(self.scan_cumulative, self.rng.random())
            to_off = tuple(fix.features_deg[self.held - 1])
            kind = "scan"
        else:
            while (amplitude := fix.microsaccade_median_deg * math.exp(
                    fix.microsaccade_log_sd * self.rng.gauss(0.0, 1.0))) > fix.microsaccade_max_deg:
                pass
            point = (0.0, 0.0) if self.held == 0 else tuple(fix.features_deg[self.held - 1])
            spread = math.radians(fix.correction_spread_deg)
            heading = math.atan2(point[1] - off[1], point[0] - off[0]) + self.rng.uniform(-spread, spread)
            to_off = (off[0] + amplitude * math.cos(heading), off[1] + amplitude * math.sin(heading))
            kind = "micro"
        limit = p.eye_yaw_limit_deg
        start = tuple(max(-limit, min(limit, b + o)) for b, o in zip(self.to, off, strict=True))
        end = tuple(max(-limit, min(limit, b + o)) for b, o in zip(self.to, to_off, strict=True))
        amplitude = math.hypot(end[0] - start[0], end[1] - start[1])
        duration = round((p.d0_s + p.d_s_per_deg * amplitude) * NS)
        self.offset, self.landed = to_off, t + duration
        self.next_small = t + self._small_interval()
        onsets.append((t, self.index, start, end, amplitude, amplitude,
                       math.degrees(math.atan2(end[1] - start[1], end[0] - start[0])) % 360.0, duration * 1e-9,
                       kind, (self.next_small - t - duration) * 1e-9))

    def tick(self, t: int, onsets: list[tuple], blinks: list[tuple[int, int]]) -> tuple[float, float, float]:
        while min(self.next_saccade, self.next_blink, self.next_small) <= t:
            if self.next_small < min(self.next_saccade, self.next_blink):
                self._small_saccade(self.next_small, onsets)
            elif self.next_saccade <= self.next_blink:
                self._decide(self.next_saccade, onsets, blinks)
            else:
                self.blink_onset = self.next_blink
                blinks.append((self.next_blink, self.index))
                self.next_blink += self._blink_interval()
        yaw, pitch = self._position(t)
        if t >= self.end and self.fixational:
            yaw, pitch = yaw + self.offset[0], pitch + self.offset[1]
        elapsed = (t - self.blink_onset) * 1e-9
        curve_s, curve_c = self.p.blink.lid_curve_s, self.p.blink.lid_curve_closure
        lid = 0.0
        if 0.0 <= elapsed < curve_s[-1]:
            i = bisect.bisect_right(curve_s, elapsed)
            lid = curve_c[i - 1] + (curve_c[i] - curve_c[i - 1]) * (elapsed - curve_s[i - 1]) / (
                curve_s[i] - curve_s[i - 1]
            )
        return yaw, pitch, lid


def python_tick(agents: list[PythonAgent], t: int) -> tuple[list[tuple[float, float, float]], list, list]:
    """What GazeEngine.tick returns, agent by agent: every eye's state and the onsets, sorted by time."""
    onsets: list[tuple] = []
    blinks: list[tuple[int, int]] = []
    states = [agent.tick(t, onsets, blinks) for agent in agents]
    onsets.sort(key=lambda onset: onset[:2])
    blinks.sort()
    return states, onsets, blinks


def hold_tables(params: GazeParams, role: str) -> dict[str, list[float]]:
    """The engine's quantile tables of the role's hold distributions, as Python lists."""
    u = np.linspace(0.0, 1.0, HOLD_TABLE_INTERVALS + 1)
    role_params = params.roles[role]
    return {
        "mutual": role_params.mutual_interval.sample_s(u).tolist(),
        "away": role_params.away_interval.sample_s(u).tolist(),
    }


def time_both(params: GazeParams, n: int, python_n: int, ticks: int, mode: str) -> tuple[float, float]:
    """Median seconds per 60 Hz tick of the engine (n agents) and of plain Python (python_n agents).

    The two are timed in alternating blocks, so load from other processes hits both alike: `ticks` Python
    ticks in blocks of PYTHON_BLOCK_TICKS, each block followed by ENGINE_BLOCK_TICKS engine ticks.
    """
    engine = GazeEngine(n, seed=1, params=params, role="talking", mode=mode)
    tables = hold_tables(params, "talking")
    fixational = mode == "saccade+noise+blink"
    agents = [PythonAgent(params, i, i, "talking", tables, fixational) for i in range(python_n)]
    for second in range(1, 11):  # warm-up to the steady state; onsets are exact whatever the step
        engine.tick(second * NS)
        python_tick(agents, second * NS)
    start_ns = 10 * NS
    engine_samples: list[float] = []
    python_samples: list[float] = []
    python_k = engine_k = 0
    while len(python_samples) < ticks:
        for _ in range(min(PYTHON_BLOCK_TICKS, ticks - len(python_samples))):
            python_k += 1
            began = time.perf_counter()
            python_tick(agents, start_ns + python_k * FRAME_NS)
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
