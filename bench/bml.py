"""BML against eca's own messages: what a block costs on its way to the face, and what parsing costs.

1. Arrival -> first visible: a private instance (broker, dialogue, gaze, rig at 120 Hz, bml; each its own
   process). Trials alternate between the same change sent two ways: eca's own `set_emotion` (the
   baseline) and a BML block holding `<eca:emotion>`; the emotion toggles natural <-> surprised with no
   transition, so the first rig frame whose outer-brow weight has crossed half way shows it. The latency is
   that frame's publish stamp minus the command's, both on this host's monotonic clock. Target: the BML
   p99 within 5 ms of the baseline's (the rig's frame period, 8.3 ms, quantizes both alike).
2. Parse + schedule of a 50-behaviour block (heads, face lexemes, gazes and waits tied to each other),
   in process, against the standard library's XML parser reading the same text (the baseline: what the
   bytes cost before any BML work).

    python bench/bml.py [--trials 60] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from eca.agent.bml import parse_block, schedule  # noqa: E402
from eca.agent.rig.names import ARKIT_INDEX  # noqa: E402
from eca.protocol.client import AgentClient  # noqa: E402
from eca.protocol.messages import Bml, Message, RigPose, SetEmotion  # noqa: E402
from tests.support.bus import eca_command, private_bus_config, running  # noqa: E402

BML = "http://www.bml-initiative.org/bml/bml-1.0"
BROW = ARKIT_INDEX["BrowOuterUpLeft"]
RIG_HZ = 120


def fifty_behaviours() -> str:
    parts = []
    for i in range(50):
        kind = i % 4
        if kind == 0:
            parts.append(f'<head id="h{i}" lexeme="NOD" start="{i * 0.1:.1f}"/>')
        elif kind == 1:
            parts.append(f'<faceLexeme id="f{i}" lexeme="RAISE_BROWS" amount="0.5" start="h{i - 1}:stroke"/>')
        elif kind == 2:
            parts.append(f'<gaze id="g{i}" target="user" start="f{i - 1}:attackPeak" end="f{i - 1}:relax+0.2"/>')
        else:
            parts.append(f'<wait id="w{i}" start="g{i - 1}:ready" end="g{i - 1}:end"/>')
    return f'<bml xmlns="{BML}" id="big">{"".join(parts)}</bml>'


def parse_figures(rounds: int = 200) -> dict[str, float]:
    text = fifty_behaviours()
    block = parse_block(text, "bench")
    assert len(block.behaviours) == 50, len(block.behaviours)
    base, ours = [], []
    for _ in range(rounds):
        t0 = time.perf_counter()
        ET.fromstring(text)
        t1 = time.perf_counter()
        schedule(parse_block(text, "bench"), 0.0, {})
        t2 = time.perf_counter()
        base.append(t1 - t0)
        ours.append(t2 - t1)
    return {"etree_parse_ms": float(np.median(base) * 1e3), "bml_parse_schedule_ms": float(np.median(ours) * 1e3),
            "bml_parse_schedule_p99_ms": float(np.percentile(ours, 99) * 1e3),
            "ratio": float(np.median(ours) / np.median(base))}


def brow_up(frame: RigPose, surprised: bool) -> bool:
    return (frame.arkit[BROW] > 0.35) == surprised


def arrival_figures(trials: int) -> dict[str, float | int]:
    with private_bus_config(services=["dialogue", "gaze"]) as config:
        argv = eca_command("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet",
                           "--bml", "--rig", "--rig-rate", str(RIG_HZ))
        with running(argv) as (_proc, reader):
            reader.wait_for("[up] ready in", 90.0)
            with AgentClient(config, agent="ada") as client:
                client.sub.subscribe("stream.ada.rig")
                client.wait_for(lambda m: isinstance(m, RigPose), 10.0)
                own: list[float] = []
                bml: list[float] = []
                surprised = False
                for k in range(2 * trials + 2):
                    surprised = not surprised
                    name = "surprised" if surprised else "natural"
                    rid = client.new_request_id()
                    if k % 2 == 0:
                        msg: Message = SetEmotion(agent="ada", name=name, transition_s=0.0, request_id=rid)
                    else:
                        msg = Bml(agent="ada", request_id=rid, xml=(
                            f'<bml xmlns="{BML}" xmlns:eca="urn:eca:bml:1.0" id="e{k}">'
                            f'<eca:emotion id="x" name="{name}" transition="0"/></bml>'))
                    client.take_held()  # what came before this trial
                    sent = client.send(msg)

                    def shown(m: Message, surprised: bool = surprised) -> bool:
                        return isinstance(m, RigPose) and brow_up(m, surprised)

                    frame = client.wait_for(shown, 5.0)
                    client.wait_applied(sent, 5.0)
                    if k >= 2:  # the first two warm the path
                        (own if k % 2 == 0 else bml).append((frame.t_ns - sent.t_ns) / 1e6)
                    time.sleep(0.05)  # pacing between trials (not synchronisation): a new frame after the change
    return {"trials": trials, "own_p50_ms": float(np.median(own)), "own_p99_ms": float(np.percentile(own, 99)),
            "bml_p50_ms": float(np.median(bml)), "bml_p99_ms": float(np.percentile(bml, 99)),
            "p99_extra_ms": float(np.percentile(bml, 99) - np.percentile(own, 99))}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=60, help="trials of each kind")
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    args = parser.parse_args()
    load = os.getloadavg()
    print(f"BML bench; {os.cpu_count()} cores, load average {[round(x, 2) for x in load]}")
    parsing = parse_figures()
    print(f"parse + schedule, 50 behaviours: {parsing['bml_parse_schedule_ms']:.2f} ms median "
          f"(p99 {parsing['bml_parse_schedule_p99_ms']:.2f}); "
          f"xml.etree parse alone {parsing['etree_parse_ms']:.3f} ms; "
          f"ratio {parsing['ratio']:.1f}x")
    arrival = arrival_figures(args.trials)
    met = arrival["p99_extra_ms"] <= 5.0
    print(f"arrival -> first visible ({RIG_HZ} Hz rig frames, {args.trials} trials each):")
    print(f"  set_emotion (baseline) p50 {arrival['own_p50_ms']:.1f} ms  p99 {arrival['own_p99_ms']:.1f} ms")
    print(f"  BML <eca:emotion>      p50 {arrival['bml_p50_ms']:.1f} ms  p99 {arrival['bml_p99_ms']:.1f} ms")
    print(f"  p99 extra {arrival['p99_extra_ms']:+.1f} ms (target <= +5 ms: {'met' if met else 'MISSED'})")
    if args.json:
        print(json.dumps({"parse": parsing, "arrival": arrival, "target_met": met, "load": load}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
