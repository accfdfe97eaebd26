"""Bench part for bench/scale.py: the bus's one-way latency over CURVE/TCP across hosts against local IPC.

One run, both links: a broker process and a client process that publishes a stamped message (`t_ns`, the
envelope's monotonic send time) and receives it back through the broker, one at a time (no queueing in the
figure), with eca's Publisher/Subscriber and codec. Local: broker and client on this host over ipc. Across:
the broker in a "model" network namespace, bound to its address with CURVE keys, the client in a "dm"
namespace with its own key (tests/support/netns.py; as root). All namespaces share one clock, so the
receive time minus the stamp is the one-way latency through the broker. The runs go local, across,
across, local (half the samples each), so slow drift of the shared machine cancels out. Without
namespaces (not root), the CURVE figures are over loopback TCP and `across_namespaces` is 0.

    python bench/_scale_bus.py [--samples 2000] [--json]

Target: the median across hosts at most 1.5 x the local IPC median.
"""

from __future__ import annotations

import argparse
import json
import secrets
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

TARGET_RATIO = 1.5
WARM_UP = 50


def measure(config_path: str, samples: int) -> int:
    """The client: `samples` messages through the broker, one at a time; prints the latencies (ns) as JSON."""
    import zmq

    from eca.protocol.bus import Publisher, Subscriber
    from eca.protocol.endpoints import load_bus_config
    from eca.protocol.messages import ALL_AGENTS, EyeStates

    config = load_bus_config(config_path)
    ctx = zmq.Context()
    pub = Publisher(ctx, config, "bench")
    sub = Subscriber(ctx, config, ["stream.*.eye_states"])
    pub.wait_ready(20.0)
    sub.wait_ready(20.0)
    latencies: list[int] = []
    for i in range(samples + WARM_UP):
        pub.publish(EyeStates(agent=ALL_AGENTS, agents=["ada"], yaw_deg=[3.5 + i % 7], pitch_deg=[-1.25], lid=[0.1],
                              mode=["saccade+blink"]))
        got = sub.recv(5.0)
        now = time.monotonic_ns()
        if got is None or got.message is None:
            raise SystemExit("a message did not come back within 5 s")
        if i >= WARM_UP:
            latencies.append(now - got.message.t_ns)
        time.sleep(0.001)  # a steady stream, not a busy loop
    pub.close()
    sub.close()
    ctx.term()
    print(json.dumps(latencies), flush=True)
    return 0


def _figures(name: str, latencies_ns: list[int]) -> dict[str, float]:
    ordered = sorted(latencies_ns)
    return {f"{name}_median_ms": statistics.median(ordered) / 1e6,
            f"{name}_p99_ms": ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))] / 1e6}


def _run_pair(broker_argv: list[str], client_argv: list[str], env: dict[str, str]) -> list[int]:
    broker = subprocess.Popen(broker_argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        done = subprocess.run(client_argv, env=env, capture_output=True, text=True, timeout=600)
        if done.returncode != 0:
            raise RuntimeError(f"the bench client failed: {done.stderr.strip()[-500:]}")
        return list(json.loads(done.stdout.strip().splitlines()[-1]))
    finally:
        broker.terminate()
        try:
            broker.wait(10)
        except subprocess.TimeoutExpired:
            broker.kill()
            broker.wait()


def bus_latency(samples: int = 2000) -> dict[str, float]:
    """Medians and p99 (ms) of the one-way latency over local IPC and over CURVE/TCP across namespaces."""
    from eca.services.tools.child_processes import subprocess_env
    from tests.support.bus import write_test_config
    from tests.support.netns import hosts, netns_available
    from tests.test_bus_curve import curve_setup

    env = subprocess_env()
    me = [sys.executable, str(Path(__file__).resolve()), "--client"]
    run = [sys.executable, "-m", "eca.services.processes.run", "broker", "--config"]
    root = Path(tempfile.mkdtemp(prefix="ecs-"))
    try:
        local = write_test_config(root, extra=f'[bus]\ntransport = "ipc"\ninstance = "b{secrets.token_hex(3)}"\n'
                                  f'runtime_dir = "{root / "run"}"\ntcp_host = "127.0.0.1"\ntcp_frontend_port = 1\n'
                                  "tcp_backend_port = 2\nallow_remote = false\nhwm = 20000\n"
                                  "max_message_bytes = 4194304\n")
        # ABBA (local, across, across, local), half the samples each: slow drift of a shared machine cancels out
        half = max(1, samples // 2)
        ipc = _run_pair([*run, str(local)], [*me, str(local), str(half)], env)
        why_not = netns_available()
        curve: list[int] = []
        with ExitStack() as stack:
            if why_not is None:
                net = stack.enter_context(hosts("dm", "model"))
                setup = curve_setup(root / "curve", host=net["model"].address)
                broker_argv = net["model"].argv([*run, str(setup.model)])
                client_argv = net["dm"].argv([*me, str(setup.client("dm")), str(half)])
            else:
                setup = curve_setup(root / "curve")
                broker_argv, client_argv = [*run, str(setup.model)], [*me, str(setup.client("dm")), str(half)]
            for _ in range(2):
                curve += _run_pair(broker_argv, client_argv, env)
        ipc += _run_pair([*run, str(local)], [*me, str(local), str(half)], env)
        out = {**_figures("ipc", ipc), **_figures("curve", curve)}
        out["across_namespaces"] = 1.0 if why_not is None else 0.0
        out["median_ratio"] = out["curve_median_ms"] / out["ipc_median_ms"]
        out["target_ratio"] = TARGET_RATIO
        out["samples"] = float(samples)
        return out
    finally:
        shutil.rmtree(root, ignore_errors=True)


def main() -> int:
    if len(sys.argv) >= 2 and sys.argv[1] == "--client":
        return measure(sys.argv[2], int(sys.argv[3]))
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=2000)
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
    args = parser.parse_args()
    figures = bus_latency(args.samples)
    if args.json:
        print(json.dumps(figures))
    else:
        for key, value in figures.items():
            print(f"{key:>20} {value:.4f}")
        verdict = "meets" if figures["median_ratio"] <= TARGET_RATIO else "misses"
        print(f"CURVE/TCP median is {figures['median_ratio']:.2f} x IPC's: {verdict} the {TARGET_RATIO} x target")
    return 0


if __name__ == "__main__":
    sys.exit(main())
