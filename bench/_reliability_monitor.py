"""Bench part for bench/reliability.py: the monitor, a process of its own (`bench/reliability.py --role monitor`), so
the bench's reading does not share the orchestrator's CPU time: frame rate, probes, final states, heartbeats."""

from __future__ import annotations

import json
import os
import random
import sys
import time

from bench._reliability_common import (
    AGENT,
    FINAL_MARKERS,
    PROBE_ANSWER_TIMEOUT_S,
    PROBE_EMOTION,
    PROBE_PERIOD_S,
    STATE_KINDS,
    is_final,
    wait_readable,
)


def run_monitor(config_path: str, instance: str, seed: int) -> int:
    """Subscribe before the flood; commands on stdin: `probe <start_ns> <end_ns>`, `stop` (dump JSON)."""
    import msgpack
    import zmq

    from eca.protocol.codec import encode
    from eca.protocol.endpoints import load_bus_config
    from eca.protocol.messages import SetEmotion

    config = load_bus_config(config_path, instance)
    rng = random.Random(seed * 7919 + 1)
    ctx = zmq.Context()
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.RCVHWM, config.hwm)
    sub.setsockopt(zmq.LINGER, 0)
    face_topic = f"stream.{AGENT}.face_frame".encode()
    state_prefix = f"state.{AGENT}.".encode()
    ack_topic = f"event.{AGENT}.ack".encode()  # where a dialogue service that acknowledges commands does so
    for prefix in (face_topic, state_prefix, ack_topic, b"sys."):
        sub.setsockopt(zmq.SUBSCRIBE, prefix)
    sub.connect(config.backend)
    pub = ctx.socket(zmq.XPUB)
    pub.setsockopt(zmq.SNDHWM, config.hwm)
    pub.setsockopt(zmq.LINGER, 0)
    pub.connect(config.frontend)
    if not wait_readable(pub, 10.0):
        return 1
    pub.recv()

    unpack = msgpack.unpackb
    frames_t_ns: list[int] = []
    state_counts: dict[str, int] = {}
    final_since: dict[str, tuple[int, int] | None] = {k: None for k in STATE_KINDS}
    overwritten = {k: 0 for k in STATE_KINDS}
    settled_announced = False
    beats: dict[str, list[tuple[int, int, int, int]]] = {}  # service -> (arrival, pid, started, bad)
    probe_by_intensity: dict[float, int] = {}
    probe_by_request: dict[str, int] = {}
    # [sent_ns, first answer's arrival_ns, the answer's t_ns, state's arrival_ns, ack's arrival_ns]
    probes: list[list[int | None]] = []

    def answered(k: int | None, now: int, t_ns: int, slot: int) -> None:
        if k is None:
            return
        probe = probes[k]
        if probe[1] is None:
            probe[1], probe[2] = now, t_ns
        if probe[slot] is None:
            probe[slot] = now

    def take(frames: list[bytes], now: int) -> None:
        nonlocal settled_announced
        if len(frames) != 2:
            return
        topic, payload = frames
        if topic == face_topic:
            frames_t_ns.append(unpack(payload)["t_ns"])
            return
        if topic.startswith(state_prefix):
            kind = topic[len(state_prefix):].decode()
            state_counts[kind] = state_counts.get(kind, 0) + 1
            if kind not in final_since:
                return
            state = None
            if kind == "emotion" or FINAL_MARKERS[kind] in payload:
                state = unpack(payload)
            if kind == "emotion" and state is not None and state.get("name") == PROBE_EMOTION:
                answered(probe_by_intensity.pop(state.get("intensity"), None), now, state["t_ns"], 3)
            if state is not None and is_final(kind, state):
                if final_since[kind] is None:
                    final_since[kind] = (now, state["t_ns"])
            elif final_since[kind] is not None:
                overwritten[kind] += 1
                final_since[kind] = None
            if not settled_announced and all(v is not None for v in final_since.values()):
                settled_announced = True
                print("SETTLED " + json.dumps(final_since), flush=True)
            return
        if topic == ack_topic:
            ack = unpack(payload)
            answered(probe_by_request.pop(ack.get("request_id"), None), now, ack.get("t_ns", 0), 4)
            return
        if topic == b"sys.*.heartbeat":
            beat = unpack(payload)
            beats.setdefault(beat["service"], []).append(
                (now, beat["pid"], beat["started_ns"], beat.get("bad_messages", 0)))

    def read_all(limit: int = 2000) -> None:
        """What is waiting, up to `limit` (so a flood of states cannot starve the probes' schedule)."""
        for _ in range(limit):
            try:
                frames = sub.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            take(frames, time.monotonic_ns())

    probe = f"sys.{rng.getrandbits(64):016x}.hello".encode()  # the subscriber's readiness barrier
    sub.setsockopt(zmq.SUBSCRIBE, probe)
    deadline = time.monotonic() + 10.0
    while True:
        if not wait_readable(sub, deadline - time.monotonic()):
            return 1
        frames = sub.recv_multipart()
        if frames[0] == probe:
            break
        take(frames, time.monotonic_ns())
    sub.setsockopt(zmq.UNSUBSCRIBE, probe)
    print("READY", flush=True)

    poller = zmq.Poller()
    poller.register(sub, zmq.POLLIN)
    stdin_fd = sys.stdin.fileno()
    poller.register(stdin_fd, zmq.POLLIN)
    pending_input = b""
    probe_start = probe_end = next_probe = 0
    stop_at: int | None = None  # when stopping: the last probe's answer deadline
    seq = 0
    while True:
        now = time.monotonic_ns()
        if probe_end and next_probe <= now < probe_end and stop_at is None:
            k = len(probes)
            intensity = 0.5 + (k + 1) * 1e-6  # unique, and never a flood value (those have two decimals)
            seq += 1
            # Answered by the state showing its unique intensity or, from a dialogue service that publishes
            # one state per batch (a later command in the batch may hide this one's value), by its ack.
            msg = SetEmotion(agent=AGENT, seq=seq, t_ns=time.monotonic_ns(), source="probe", name=PROBE_EMOTION,
                             intensity=intensity, transition_s=0.0, request_id=f"probe-{k}")
            probe_by_intensity[intensity] = k
            probe_by_request[msg.request_id] = k
            probes.append([msg.t_ns, None, None, None, None])
            pub.send_multipart([f"cmd.{AGENT}.set_emotion".encode(), encode(msg)])
            next_probe = max(next_probe + int(PROBE_PERIOD_S * 1e9), now)
        if stop_at is not None and (now >= stop_at or all(p[1] is not None for p in probes)):
            break
        wake = [now + 100_000_000]
        if probe_end and next_probe < probe_end and stop_at is None:
            wake.append(max(next_probe, probe_start))
        if stop_at is not None:
            wake.append(stop_at)
        events = dict(poller.poll(max(0, (min(wake) - time.monotonic_ns()) // 1_000_000)))
        if sub in events:
            read_all()
        if stdin_fd in events:
            chunk = os.read(stdin_fd, 4096)
            pending_input += chunk if chunk else b"\nstop\n"
            while b"\n" in pending_input:
                line, pending_input = pending_input.split(b"\n", 1)
                words = line.decode().split()
                if words[:1] == ["probe"]:
                    probe_start, probe_end = int(words[1]), int(words[2])
                    next_probe = probe_start
                elif words[:1] == ["stop"] and stop_at is None:
                    last_sent = max((p[0] for p in probes), default=0) or 0
                    stop_at = max(time.monotonic_ns(), int(last_sent) + int(PROBE_ANSWER_TIMEOUT_S * 1e9))
            if not chunk:
                poller.unregister(stdin_fd)
    read_all(10**9)
    print(json.dumps({
        "frames_t_ns": frames_t_ns, "probes": probes, "state_counts": state_counts,
        "finals": {k: (None if v is None else {"arrival_ns": v[0], "t_ns": v[1]}) for k, v in final_since.items()},
        "overwritten_after_final": overwritten, "heartbeats": beats,
    }), flush=True)
    pub.close()
    sub.close()
    ctx.term()
    return 0
