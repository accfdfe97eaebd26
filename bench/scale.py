"""eca beyond one machine, side by side in one run (each against its baseline measured in the same run):

1. bus: one-way latency over CURVE/TCP between network namespaces against local IPC (target: median <= 1.5x);
2. viewers: eca's CPU and memory as viewers of one face grow through Janus against the same viewers peering
   with eca, and command -> frame shown p95 both ways (target: flat through Janus, within 10 % of one
   viewer's cost at 50);
3. hosts: conversations across two eca hosts behind HAProxy against one host.

Each part runs alone too (bench/_scale_bus.py, bench/_scale_janus.py, bench/_scale_hosts.py). Network
namespaces need root; a part that cannot run here says why and the others still run. All "hosts" share this
machine's cores and clock: the figures compare paths, not machines.

    python bench/scale.py [--only bus,viewers,hosts] [--json]
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
import traceback
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

PARTS = {
    "bus": ("bench._scale_bus", "bus_latency"),
    "viewers": ("bench._scale_janus", "viewers_through_janus"),
    "hosts": ("bench._scale_hosts", "conversations_behind_haproxy"),
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default=",".join(PARTS), help="comma-separated parts: " + ", ".join(PARTS))
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    args = parser.parse_args()
    wanted = [p.strip() for p in args.only.split(",") if p.strip()]
    unknown = [p for p in wanted if p not in PARTS]
    if unknown:
        print(f"bench/scale.py: unknown parts {unknown}; known: {', '.join(PARTS)}", file=sys.stderr)
        return 2
    print(f"scale bench; {os.cpu_count()} cores, load average {[round(x, 2) for x in os.getloadavg()]}")
    results: dict[str, Any] = {}
    for name in wanted:
        module_name, function = PARTS[name]
        print(f"--- {name}", flush=True)
        try:
            results[name] = getattr(importlib.import_module(module_name), function)()
        except Exception as exc:  # one part that cannot run here must not hide the others
            traceback.print_exc()
            results[name] = {"error": f"{type(exc).__name__}: {exc}"}
        print(json.dumps(results[name], indent=1, default=str), flush=True)
    if args.json:
        print(json.dumps(results, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
