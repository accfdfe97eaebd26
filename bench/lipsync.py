"""Lip-sync cost per 10 ms block, and the audio-to-mouth offset at the player.

Figures, each a ratio against a baseline measured or fixed in the same run:
- cost: median CPU time of one 10 ms block / the 10 ms of real time the block represents
  (= the fraction of one core lip-sync takes while speech plays; target <= 1%);
- offset: mouth-open onset vs audio onset at the DAC, as the renderer would see them (mouth keys
  placed on the DAC timeline through the player's clock anchors, fake sink on a virtual clock),
  against one video frame (1/60 s); target |offset| <= 10 ms. The bus adds its own latency on top
  (about 0.5 ms, SPEC section 2), measured end to end elsewhere.

Usage: python bench/lipsync.py [--json] [--repeats N]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from agent.clock import VirtualClock  # noqa: E402
from agent.lipsync import LipSyncEstimator, MouthTrack  # noqa: E402
from services.audio import ClockAnchor, FakeSink, MouthKeys, Player, SpeechFinished  # noqa: E402

BLOCK_S = 0.010
FRAME_S = 1.0 / 60.0


def speech_sample() -> tuple[np.ndarray, int, str]:
    try:
        from services.audio.espeak import EspeakUnavailable, synthesize

        speech = synthesize("She sells sea shells by the sea shore, and my father bought a map of the moon.")
        return speech.samples, speech.sample_rate, "espeak-ng sentence"
    except (ImportError, EspeakUnavailable):
        sr = 22_050
        return synthetic_vowel(750, 1200, 3.0, sr), sr, "synthetic vowel (espeak-ng missing)"


def synthetic_vowel(f1: float, f2: float, seconds: float, sr: int) -> np.ndarray:
    """Pulse train at 120 Hz shaped by two formant resonators (numpy only, no scipy)."""
    n = round(seconds * sr)
    y = np.zeros(n)
    y[:: round(sr / 120)] = 1.0
    for fc, bw in ((f1, 80.0), (f2, 100.0)):
        r = np.exp(-np.pi * bw / sr)
        a1, a2 = -2 * r * np.cos(2 * np.pi * fc / sr), r * r
        out = np.zeros(n)
        for i in range(n):  # direct-form resonator
            out[i] = y[i] - a1 * (out[i - 1] if i else 0.0) - a2 * (out[i - 2] if i > 1 else 0.0)
        y = out
    return (0.4 * y / np.max(np.abs(y))).astype(np.float32)


def block_costs(samples: np.ndarray, sr: int) -> list[float]:
    est = LipSyncEstimator(sr)
    costs = []
    for k in range(int(len(samples) / (sr * BLOCK_S))):
        block = samples[(k * sr) // 100 : ((k + 1) * sr) // 100]
        t0 = time.perf_counter_ns()
        est.push(block)
        costs.append((time.perf_counter_ns() - t0) / 1e9)
    return costs


def onset_offset_ms(onset_s: float, sr_in: int, vowel: np.ndarray) -> float:
    clock = VirtualClock()
    sink = FakeSink(clock, 48_000, 480, latency_s=0.02)
    events: list[object] = []
    player = Player(sink, events.append, clock=clock).start()
    x = np.concatenate([np.zeros(round(onset_s * sr_in), np.float32), vowel, np.zeros(sr_in // 5, np.float32)])
    player.say_pcm("u", x, sr_in)
    while not any(isinstance(e, SpeechFinished) for e in events):
        sink.advance(1)
    keys = tuple(k for e in events if isinstance(e, MouthKeys) for k in e.keys)
    track = MouthTrack(48_000, keys)
    anchor = next(e for e in events if isinstance(e, ClockAnchor))
    out = sink.output
    t_audio = sink.block_time_ns(0) + sink.latency_ns + np.flatnonzero(np.abs(out) > 0.02)[0] * 1e9 / 48_000
    steady = max(k.weights["say_ah"] for k in keys)
    # The renderer's view: the mouth for the sample at the DAC at time t, on a 0.1 ms grid.
    for t in np.arange(t_audio - 50e6, t_audio + 50e6, 1e5):
        sample = anchor.sample_index + (t - anchor.dac_time_ns) * 48_000 / 1e9
        if track.weights_at(sample)["say_ah"] >= 0.5 * steady:
            return (t - t_audio) / 1e6
    return float("nan")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    samples, sr, source = speech_sample()
    figures: dict[str, object] = {"source": source, "blocks_per_run": int(len(samples) / (sr * BLOCK_S))}
    for rate in (sr, 48_000):
        x = samples if rate == sr else np.interp(np.arange(round(len(samples) * rate / sr)) * sr / rate,
                                                 np.arange(len(samples)), samples).astype(np.float32)
        medians, p95s = [], []
        for _ in range(args.repeats):
            costs = block_costs(x, rate)
            medians.append(statistics.median(costs))
            p95s.append(float(np.percentile(costs, 95)))
        median = statistics.median(medians)
        figures[f"cost_median_us_{rate}"] = round(median * 1e6, 1)
        figures[f"cost_p95_us_{rate}"] = round(statistics.median(p95s) * 1e6, 1)
        figures[f"core_fraction_{rate}"] = round(median / BLOCK_S, 5)  # baseline: 10 ms of real time

    vowel = synthetic_vowel(750, 1200, 0.3, 22_050)
    offsets = [onset_offset_ms(0.1 + 0.00137 * i, 22_050, vowel) for i in range(12)]
    figures["offset_median_ms"] = round(statistics.median(offsets), 2)
    figures["offset_max_abs_ms"] = round(max(abs(o) for o in offsets), 2)
    figures["offset_max_abs_per_frame"] = round(max(abs(o) for o in offsets) / (FRAME_S * 1e3), 3)

    print(f"lip-sync on {source}, {figures['blocks_per_run']} blocks of 10 ms, {args.repeats} runs (medians)")
    for rate in (sr, 48_000):
        print(f"  {rate:>6} Hz: {figures[f'cost_median_us_{rate}']:7.1f} us/block (p95 "
              f"{figures[f'cost_p95_us_{rate}']:.1f}) = {100 * figures[f'core_fraction_{rate}']:.2f}% of one core "
              f"(baseline 10 ms real time; target <= 1%)")
    print(f"  mouth-open onset - audio onset at the DAC: median {figures['offset_median_ms']:+.2f} ms, "
          f"max |offset| {figures['offset_max_abs_ms']:.2f} ms = {figures['offset_max_abs_per_frame']:.2f} "
          f"video frames (target <= 10 ms)")
    if args.json:
        print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main())
