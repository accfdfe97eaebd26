"""Benchmark: one-way bus latency through the broker, eca's Publisher/Subscriber/codec against raw pyzmq + msgpack.

A real broker process is started (`python -m eca.services.processes.run broker`). For each rate (60 Hz, 1 kHz) a
publisher process and a subscriber process exchange eye-state messages through it, once with eca's
`Publisher`, `Subscriber` and validating codec, once with a bare pyzmq socket and `msgpack.packb` /
`unpackb` (the baseline), in ABBA order so slow drift of the machine cancels out. The publisher embeds
its monotonic send time (the envelope's `t_ns`, taken before encoding); the subscriber, on the same
host and so on the same clock, subtracts it from the time at which it holds the decoded message.
Figures are the median and the 99th percentile of all samples, and eca's value over the baseline's.

It then starts `eca up` a few times and reports its time to ready (the "ready in X s" line, and the
wall time from launching the command to that line) and the resident memory (VmRSS) of the supervisor,
the broker and each service.

    python bench/bus_latency.py [--seconds 10] [--up-runs 3] [--json]

Target (2-core machine): median ratio <= 1.2 and p99 <= 2 ms at 60 Hz.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import secrets
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from eca.services.tools.child_processes import subprocess_env  # noqa: E402 (after the path is set)

TOPIC = "stream.*.eye_states"
TARGET_MEDIAN_RATIO = 1.2
TARGET_P99_MS_60HZ = 2.0
READY_TIMEOUT_S = 30.0


# --- the two sides of one measurement, each run as its own process -------------------------------


def run_subscriber(mode: str, config_path: str, instance: str, count: int, idle_s: float) -> int:
    """Receive up to `count` messages; print READY once subscribed, then the latencies (ns) as JSON."""
    import msgpack
    import zmq

    from eca.protocol.bus import Subscriber
    from eca.protocol.endpoints import load_bus_config

    config = load_bus_config(config_path, instance)
    ctx = zmq.Context()
    latencies: list[int] = []
    seqs: set[int] = set()
    if mode == "eca":
        sub = Subscriber(ctx, config, [TOPIC])
        sub.wait_ready(10.0)
        print("READY", flush=True)
        while len(latencies) < count:
            got = sub.recv(idle_s)
            if got is None:
                break
            now = time.monotonic_ns()
            msg = got.message
            if msg is None or msg.TYPE != "eye_states":
                continue
            latencies.append(now - msg.t_ns)
            seqs.add(msg.seq)
        sub.close()
    else:
        sock = ctx.socket(zmq.SUB)
        sock.setsockopt(zmq.RCVHWM, config.hwm)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.SUBSCRIBE, TOPIC.encode())
        sock.connect(config.backend)
        probe = f"sys.{secrets.token_hex(8)}.hello".encode()  # the same barrier, by hand (docs/protocol.md)
        sock.setsockopt(zmq.SUBSCRIBE, probe)
        deadline = time.monotonic() + 10.0
        while True:
            if not sock.poll(max(0, int((deadline - time.monotonic()) * 1000))):
                raise SystemExit("no hello from the broker")
            if sock.recv_multipart()[0] == probe:
                break
        sock.setsockopt(zmq.UNSUBSCRIBE, probe)
        print("READY", flush=True)
        while len(latencies) < count and sock.poll(int(idle_s * 1000)):
            frames = sock.recv_multipart()
            msg = msgpack.unpackb(frames[1], raw=False)
            now = time.monotonic_ns()
            if msg.get("type") != "eye_states":
                continue
            latencies.append(now - msg["t_ns"])
            seqs.add(msg["seq"])
        sock.close()
    ctx.term()
    print(json.dumps({"latencies_ns": latencies, "distinct": len(seqs)}), flush=True)
    return 0


def run_publisher(mode: str, config_path: str, instance: str, count: int, rate_hz: float) -> int:
    """Send `count` eye-state messages at `rate_hz`, each stamped with its monotonic send time."""
    import msgpack
    import zmq

    from eca.protocol.bus import Publisher
    from eca.protocol.endpoints import load_bus_config
    from eca.protocol.messages import ALL_AGENTS, EyeStates

    config = load_bus_config(config_path, instance)
    ctx = zmq.Context()
    period_ns = int(1e9 / rate_hz)
    if mode == "eca":
        pub = Publisher(ctx, config, "bench")
        pub.wait_ready(10.0)

        def send(i: int) -> None:
            pub.publish(EyeStates(agent=ALL_AGENTS, agents=["ada"], yaw_deg=[3.5 + i % 7], pitch_deg=[-1.25], lid=[0.1],
                                  mode=["saccade+blink"]))

        sock = pub.socket
    else:
        sock = ctx.socket(zmq.XPUB)  # sends like a PUB; its one received frame is the readiness barrier
        sock.setsockopt(zmq.SNDHWM, config.hwm)
        sock.setsockopt(zmq.LINGER, 500)
        sock.connect(config.frontend)
        if not sock.poll(10_000):
            raise SystemExit("no subscription from the broker")
        sock.recv()
        topic = TOPIC.encode()
        packb = msgpack.packb

        def send(i: int) -> None:
            body = {"v": 1, "type": "eye_states", "agent": "*", "seq": i + 1, "t_ns": time.monotonic_ns(),
                    "source": "bench", "agents": ["ada"], "yaw_deg": [3.5 + i % 7], "pitch_deg": [-1.25],
                    "lid": [0.1], "mode": ["saccade+blink"]}
            sock.send_multipart([topic, packb(body)])

    next_ns = time.monotonic_ns()
    for i in range(count):
        wait_ns = next_ns - time.monotonic_ns()
        if wait_ns > 0:
            time.sleep(wait_ns / 1e9)  # pacing at the rate, not synchronisation
        send(i)
        next_ns = max(next_ns + period_ns, time.monotonic_ns())
    sock.close()
    ctx.term()
    return 0


# --- orchestration ---------------------------------------------------------------------------------


def _self(*args: str) -> list[str]:
    return [sys.executable, str(Path(__file__).resolve()), *args]


def measure(mode: str, rate_hz: float, count: int, config_path: Path, instance: str) -> dict[str, Any]:
    idle_s = max(2.0, 20.0 / rate_hz)
    sub = subprocess.Popen(_self("--role", "sub", "--mode", mode, "--config", str(config_path), "--instance",
                                 instance, "--count", str(count), "--idle", str(idle_s)),
                           stdout=subprocess.PIPE, env=subprocess_env(), cwd=REPO, text=True)
    try:
        assert sub.stdout is not None
        line = sub.stdout.readline()
        if line.strip() != "READY":
            raise RuntimeError(f"{mode} subscriber did not get ready: {line!r}")
        pub = subprocess.run(_self("--role", "pub", "--mode", mode, "--config", str(config_path), "--instance",
                                   instance, "--count", str(count), "--rate", str(rate_hz)),
                             env=subprocess_env(), cwd=REPO, timeout=count / rate_hz + 60)
        if pub.returncode:
            raise RuntimeError(f"{mode} publisher failed with code {pub.returncode}")
        out, _ = sub.communicate(timeout=count / rate_hz + 60)
    finally:
        if sub.poll() is None:
            sub.kill()
            sub.wait()
    result = json.loads(out.strip().splitlines()[-1])
    return {"latencies_ns": result["latencies_ns"], "lost": count - result["distinct"]}


def percentile(values: list[int], q: float) -> float:
    """The q-quantile by linear interpolation between order statistics."""
    s = sorted(values)
    pos = (len(s) - 1) * q
    lo = int(pos)
    hi = min(lo + 1, len(s) - 1)
    return s[lo] + (s[hi] - s[lo]) * (pos - lo)


def summarise(latencies_ns: list[int], lost: int) -> dict[str, Any]:
    return {"n": len(latencies_ns), "lost": lost, "median_us": round(statistics.median(latencies_ns) / 1e3, 1),
            "p99_us": round(percentile(latencies_ns, 0.99) / 1e3, 1),
            "max_us": round(max(latencies_ns) / 1e3, 1)}


@contextmanager
def broker_process(config_path: Path, instance: str) -> Iterator[subprocess.Popen[bytes]]:
    from tests.support.bus import running

    argv = [sys.executable, "-m", "eca.services.processes.run", "broker", "--config", str(config_path),
            "--instance", instance]
    with running(argv) as (proc, out):
        out.wait_for("ready (pid", READY_TIMEOUT_S)
        yield proc


def latency_benchmark(rates: list[float], seconds: float, config_path: Path) -> dict[str, Any]:
    instance = f"bench{secrets.token_hex(3)}"
    results: dict[str, Any] = {}
    with broker_process(config_path, instance):
        for rate in rates:
            count = max(50, int(rate * seconds / 4))  # four segments: raw, eca, eca, raw
            samples: dict[str, list[int]] = {"eca": [], "raw": []}
            lost = {"eca": 0, "raw": 0}
            for mode in ("raw", "eca", "eca", "raw"):
                got = measure(mode, rate, count, config_path, instance)
                samples[mode] += got["latencies_ns"]
                lost[mode] += got["lost"]
            eca, raw = summarise(samples["eca"], lost["eca"]), summarise(samples["raw"], lost["raw"])
            results[f"{rate:g}"] = {
                "rate_hz": rate, "eca": eca, "raw": raw,
                "median_ratio": round(eca["median_us"] / raw["median_us"], 3),
                "p99_ratio": round(eca["p99_us"] / raw["p99_us"], 3),
            }
            print(f"{rate:>6g} Hz  eca: median {eca['median_us']:7.1f} us  p99 {eca['p99_us']:7.1f} us  "
                  f"(n {eca['n']}, lost {eca['lost']})  |  raw: median {raw['median_us']:7.1f} us  "
                  f"p99 {raw['p99_us']:7.1f} us (n {raw['n']}, lost {raw['lost']})  |  ratio median "
                  f"{results[f'{rate:g}']['median_ratio']:.2f}, p99 {results[f'{rate:g}']['p99_ratio']:.2f}",
                  flush=True)
    return results


def rss_kib(pid: int) -> int | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except (FileNotFoundError, ProcessLookupError):
        return None
    return None


def up_benchmark(runs: int, config_path: Path) -> dict[str, Any]:
    """Time `eca up` to ready; read each process's resident memory once it is ready."""
    from tests.support.bus import eca_command, running

    ready_s: list[float] = []
    wall_s: list[float] = []
    memory: dict[str, list[int]] = {}
    services = ""
    for _ in range(runs):
        instance = f"benchup{secrets.token_hex(3)}"
        t0 = time.monotonic()
        with running(eca_command("up", "--config", str(config_path), "--instance", instance, "--quiet")) as (
                proc, out):
            line = out.lines[out.wait_for("ready in", READY_TIMEOUT_S)]
            wall_s.append(time.monotonic() - t0)
            found = re.search(r"ready in ([0-9.]+) s: ([^(]+) \(", line)
            if found is None:
                raise RuntimeError(f"cannot parse {line!r}")
            ready_s.append(float(found.group(1)))
            services = found.group(2).strip()
            pids = {"supervisor (eca up)": proc.pid}
            for text in list(out.lines):
                m = re.match(r"\[([\w-]+)\] INFO ready \(pid (\d+)\)", text)
                if m:
                    pids[m.group(1)] = int(m.group(2))
            for name, pid in pids.items():
                kib = rss_kib(pid)
                if kib is not None:
                    memory.setdefault(name, []).append(kib)
    rss = {name: int(statistics.median(v)) for name, v in memory.items()}
    result = {"runs": runs, "services": services, "ready_s_median": round(statistics.median(ready_s), 3),
              "ready_s": ready_s, "wall_to_ready_s_median": round(statistics.median(wall_s), 3),
              "rss_kib_median": rss, "rss_total_kib": sum(rss.values())}
    print(f"eca up ({services}): ready in {result['ready_s_median']:.2f} s (its own line, median of {runs}); "
          f"{result['wall_to_ready_s_median']:.2f} s from launching the command", flush=True)
    for name, kib in rss.items():
        print(f"  {name:<22} VmRSS {kib / 1024:7.1f} MiB", flush=True)
    print(f"  {'total':<22} VmRSS {result['rss_total_kib'] / 1024:7.1f} MiB", flush=True)
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="measured time per rate and mode pair")
    parser.add_argument("--rates", type=float, nargs="+", default=[60.0, 1000.0])
    parser.add_argument("--up-runs", type=int, default=3, help="eca up starts to time (0: skip)")
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    parser.add_argument("--role", choices=["sub", "pub"], help=argparse.SUPPRESS)
    parser.add_argument("--mode", choices=["eca", "raw"], help=argparse.SUPPRESS)
    parser.add_argument("--config", help=argparse.SUPPRESS)
    parser.add_argument("--instance", help=argparse.SUPPRESS)
    parser.add_argument("--count", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--rate", type=float, help=argparse.SUPPRESS)
    parser.add_argument("--idle", type=float, default=2.0, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.role == "sub":
        return run_subscriber(args.mode, args.config, args.instance, args.count, args.idle)
    if args.role == "pub":
        return run_publisher(args.mode, args.config, args.instance, args.count, args.rate)

    signal.signal(signal.SIGINT, signal.default_int_handler)
    from tests.support.bus import write_test_config

    directory = Path(tempfile.mkdtemp(prefix="eca-"))
    try:
        config_path = write_test_config(directory)
        print(f"bus latency, {os.cpu_count()} CPUs; eca = Publisher/Subscriber/codec, raw = pyzmq + msgpack; "
              f"both through one broker process", flush=True)
        latency = latency_benchmark(args.rates, args.seconds, config_path)
        up = up_benchmark(args.up_runs, config_path) if args.up_runs > 0 else None
    finally:
        shutil.rmtree(directory, ignore_errors=True)
    at60 = latency.get("60")
    met = None
    if at60 is not None:
        met = at60["median_ratio"] <= TARGET_MEDIAN_RATIO and at60["eca"]["p99_us"] <= TARGET_P99_MS_60HZ * 1000
        print(f"target at 60 Hz: median ratio <= {TARGET_MEDIAN_RATIO} and p99 <= {TARGET_P99_MS_60HZ} ms: "
              f"{'met' if met else 'NOT met'}", flush=True)
    if args.json:
        print(json.dumps({"bench": "bus_latency", "statistic": "median", "cpus": os.cpu_count(),
                          "latency": latency, "targets": {"median_ratio_60hz": TARGET_MEDIAN_RATIO,
                                                          "p99_ms_60hz": TARGET_P99_MS_60HZ, "met": met},
                          "up": up}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
