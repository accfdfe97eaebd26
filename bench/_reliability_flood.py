"""Bench part for bench/reliability.py: the flood's sender, a process of its own (`bench/reliability.py --role sender`):
pre-encoded valid commands and garbage on `cmd.ada.*`, paced on the monotonic clock."""

from __future__ import annotations

import json
import math
import random
import struct
import sys
import time
from dataclasses import dataclass, field
from typing import Any

from bench._reliability_common import AGENT, FINAL_COMMANDS, POOL_SIZE, wait_readable


def _envelope_prefix(body: dict[str, Any], source: str) -> bytes:
    """A msgpack map of `body` plus the envelope, open at the end for `seq` and `t_ns` (patched per send)."""
    import msgpack

    entries = {"v": 1, "agent": AGENT, "source": source, **body}
    count = len(entries) + 2
    head = bytes([0x80 | count]) if count < 16 else b"\xde" + struct.pack(">H", count)
    return head + b"".join(msgpack.packb(k) + msgpack.packb(v) for k, v in entries.items())


def _stamp(prefix: bytes, seq: int, t_ns: int) -> bytes:
    return prefix + b"\xa3seq\xcf" + seq.to_bytes(8, "big") + b"\xa4t_ns\xcf" + t_ns.to_bytes(8, "big")


EMOTIONS = ("natural", "happy", "surprised", "arrogant", "angry", "half-angry", "disappointed", "annoyed",
            "frightened")


def valid_command(rng: random.Random) -> dict[str, Any]:
    """One realistic command body with varying values; never one of FINAL_COMMANDS' values."""
    kind = rng.choices(("emotion", "head", "gaze_target", "role", "eyes"), weights=(25, 25, 25, 15, 10))[0]
    two = lambda lo, hi: round(rng.uniform(lo, hi), 2)  # two decimals: never a probe's intensity
    if kind == "emotion":
        name = rng.choice(EMOTIONS)
        intensity = two(0.0, 1.0)
        if name == "surprised" and intensity == 0.37:
            intensity = 0.38
        return {"type": "set_emotion", "name": name, "intensity": intensity, "transition_s": two(0.0, 1.0)}
    if kind == "head":
        turn = two(-1.0, 1.0)
        return {"type": "move_head", "turn": 0.2 if turn == 0.21 else turn, "nod": two(-1.0, 1.0),
                "tilt": two(-0.5, 0.5), "duration_s": two(0.0, 1.0)}
    if kind == "gaze_target":
        yaw = two(-30.0, 30.0)
        return {"type": "set_gaze_target", "yaw_deg": 7.49 if yaw == 7.5 else yaw, "pitch_deg": two(-20.0, 20.0),
                "target": rng.choice(("user", "bob", "screen"))}
    if kind == "role":
        return {"type": "set_role", "role": rng.choice(("talking", "listening")),
                "speaker": rng.choice(("user", AGENT, "bob"))}
    return {"type": "set_eyes", "mode": rng.choice(("static", "noise", "saccade+blink"))}


def garbage_message(rng: random.Random, kind: str) -> list[bytes]:
    """One malformed message (a list of frames) of the given kind, always on a `cmd.ada.` topic."""
    import msgpack

    good = valid_command(rng)
    topic = f"cmd.{AGENT}.{good['type']}".encode()
    full = {"v": 1, "agent": AGENT, "seq": rng.randrange(1, 10**6), "t_ns": time.monotonic_ns(),
            "source": "flood", **good}
    pack = lambda obj: msgpack.packb(obj, use_bin_type=True)
    if kind == "not_msgpack":
        choice = rng.randrange(5)
        if choice == 0:
            return [topic, rng.randbytes(rng.randrange(1, 200))]
        if choice == 1:
            return [topic, b"\xc1" + rng.randbytes(8)]  # 0xc1 is never used by msgpack
        if choice == 2:
            data = pack(full)
            return [topic, data[: rng.randrange(1, len(data))]]  # truncated
        if choice == 3:
            return [topic, pack(full) + pack(full)]  # two values
        return [topic, b""]
    if kind == "not_a_map":
        return [topic, pack(rng.choice([[1, 2, 3], 42, "set_emotion", None, 3.5, b"\x00\x01"]))]
    if kind == "wrong_type":
        body = dict(full)
        key = rng.choice([k for k in good if k != "type"] + ["agent", "seq", "v"])
        if isinstance(body[key], str):
            body[key] = rng.choice([5, [1.0], {"x": 1}, None, True, b"bin"])
        elif isinstance(body[key], float):
            body[key] = rng.choice(["high", [1.0], {"x": 1}, None, True, b"\x00"])
        else:  # the integers of the envelope
            body[key] = rng.choice(["1", 1.5, None, [1]])
        return [topic, pack(body)]
    if kind == "non_str_keys":
        return [topic, pack({1: 2, "v": 1, "type": good["type"]})]
    if kind == "missing_field":
        body = dict(full)
        required = {"set_emotion": "name", "set_role": "role", "set_eyes": "mode"}.get(good["type"], "type")
        body.pop(required, None)
        body.pop(rng.choice(["v", "agent", required]), None)
        return [topic, pack(body)]
    if kind == "unknown_type":
        body = dict(full, type=rng.choice(["dance", "set_mood", 7, "", "SET_EMOTION"]))
        if rng.random() < 0.3:
            body["v"] = rng.choice([2, 0, "1", None])
        return [topic, pack(body)]
    if kind == "extra_field":
        return [topic, pack(dict(full, color="red", **{"__class__": "x"}))]
    if kind == "not_finite":
        value = rng.choice([math.nan, math.inf, -math.inf])
        body = {"v": 1, "type": "set_emotion", "agent": AGENT, "name": "happy", "intensity": value}
        if rng.random() < 0.5:
            body = {"v": 1, "type": "move_head", "agent": AGENT, "turn": value, "nod": 0.0}
        return [topic if body["type"] == good["type"] else f"cmd.{AGENT}.{body['type']}".encode(), pack(body)]
    if kind == "out_of_range":
        body = rng.choice([
            {"v": 1, "type": "set_emotion", "agent": AGENT, "name": "gleeful"},  # refused by the service
            {"v": 1, "type": "set_emotion", "agent": AGENT, "name": "happy", "intensity": 5.0},
            {"v": 1, "type": "set_gaze_target", "agent": AGENT, "yaw_deg": 400.0},
            {"v": 1, "type": "set_role", "agent": AGENT, "role": "shouting"},
            {"v": 1, "type": "set_eyes", "agent": AGENT, "mode": "closed"},
            {"v": 1, "type": "set_emotion", "agent": AGENT, "name": "happy", "seq": -3},
        ])
        return [f"cmd.{AGENT}.{body['type']}".encode(), pack(body)]
    if kind == "long_string":
        n = rng.randrange(16_000, 256_000)
        key = rng.choice(["name", "speaker", "target", "source", "request_id"])
        body = {"v": 1, "type": "set_emotion", "agent": AGENT, "name": "happy"}
        if key in ("speaker",):
            body = {"v": 1, "type": "set_role", "agent": AGENT, "role": "talking"}
        if key in ("target",):
            body = {"v": 1, "type": "set_gaze_target", "agent": AGENT}
        body[key] = rng.choice("abcxyz") * n
        return [f"cmd.{AGENT}.{body['type']}".encode(), pack(body)]
    if kind == "deep":
        nested: Any = "bottom"
        for i in range(200):
            nested = [nested] if i % 2 else {"k": nested}
        body = rng.choice([nested, dict(full, name=nested), dict(full, intensity=nested)])
        return [topic, pack(body)]
    if kind == "frames":
        return rng.choice([[topic], [topic, pack(full), b"extra"], [topic, b"", pack(full)], [topic] * 5])
    if kind == "topic_mismatch":
        choice = rng.randrange(4)
        if choice == 0:
            other = "move_head" if good["type"] != "move_head" else "set_eyes"
            return [f"cmd.{AGENT}.{other}".encode(), pack(full)]
        if choice == 1:
            return [topic, pack(dict(full, agent="bob"))]
        if choice == 2:
            return [f"cmd.{AGENT}.{good['type']}.extra".encode(), pack(full)]
        return [f"cmd.{AGENT}.".encode(), pack(full)]
    if kind == "non_utf8_topic":
        return [rng.choice([b"cmd.ada.\xff\xfe", b"cmd.ada.set_\xc3(emotion", b"cmd.ada.\x80move_head"]),
                pack(full)]
    raise ValueError(kind)


GARBAGE_KINDS = ("not_msgpack", "not_a_map", "wrong_type", "non_str_keys", "missing_field", "unknown_type",
                 "extra_field", "not_finite", "out_of_range", "long_string", "deep", "frames", "topic_mismatch",
                 "non_utf8_topic")


@dataclass
class Pool:
    """What a sender cycles through: a valid command's envelope prefix (stamped per send) or garbage frames."""

    entries: list[tuple[bytes, bytes | None, list[bytes] | None]] = field(default_factory=list)
    garbage_by_kind: dict[str, int] = field(default_factory=dict)
    valid_by_type: dict[str, int] = field(default_factory=dict)


def build_pool(rng: random.Random, size: int, garbage_fraction: float, source: str) -> Pool:
    from eca.protocol.codec import decode

    pool = Pool()
    n_garbage = round(size * garbage_fraction)
    kinds = [GARBAGE_KINDS[i % len(GARBAGE_KINDS)] for i in range(n_garbage)]
    rng.shuffle(kinds)
    for kind in kinds:
        pool.entries.append((b"", None, garbage_message(rng, kind)))
        pool.garbage_by_kind[kind] = pool.garbage_by_kind.get(kind, 0) + 1
    # one payload just over the codec's 4 MiB cap, the broker still forwards it
    if n_garbage:
        huge = {"v": 1, "type": "set_emotion", "agent": AGENT, "name": "x" * (4 * 1024 * 1024 + 100)}
        import msgpack

        pool.entries[0] = (b"", None, [f"cmd.{AGENT}.set_emotion".encode(), msgpack.packb(huge)])
        pool.garbage_by_kind["over_cap"] = 1
        pool.garbage_by_kind[kinds[0]] -= 1
    for _ in range(size - n_garbage):
        body = valid_command(rng)
        prefix = _envelope_prefix(body, source)
        decode(_stamp(prefix, 1, 1))  # what we send as valid must be valid
        pool.entries.append((f"cmd.{AGENT}.{body['type']}".encode(), prefix, None))
        pool.valid_by_type[body["type"]] = pool.valid_by_type.get(body["type"], 0) + 1
    rng.shuffle(pool.entries)
    return pool


def run_sender(config_path: str, instance: str, rate: float, seconds: float, garbage: float, seed: int,
               index: int) -> int:
    """Wait for `go <start_ns>` on stdin, flood from then on at `rate`, then send the final commands."""
    import zmq

    from eca.protocol.codec import encode
    from eca.protocol.endpoints import load_bus_config
    from eca.protocol.messages import MESSAGE_TYPES

    config = load_bus_config(config_path, instance)
    source = f"flood{index}"
    pool = build_pool(random.Random(seed * 1009 + index), min(POOL_SIZE, max(100, int(rate))), garbage, source)
    ctx = zmq.Context()
    sock = ctx.socket(zmq.XPUB)
    sock.setsockopt(zmq.SNDHWM, config.hwm)
    sock.setsockopt(zmq.LINGER, 10_000)  # the final commands must leave before the process ends
    sock.setsockopt(zmq.XPUB_NODROP, 1)  # a full queue refuses (counted) instead of dropping silently
    sock.setsockopt(zmq.SNDTIMEO, 10_000)
    sock.connect(config.frontend)
    if not wait_readable(sock, 10.0):
        print(json.dumps({"error": "no broker subscription"}), flush=True)
        return 1
    sock.recv()
    print("READY", flush=True)
    line = sys.stdin.readline().split()
    if len(line) != 2 or line[0] != "go":
        return 1
    start_ns = int(line[1])
    total = round(rate * seconds)
    end_ns = start_ns + int(seconds * 1e9)
    entries = pool.entries
    n_pool = len(entries)
    sent = refused = 0
    garbage_sent = 0
    seq = 0
    max_behind = 0
    noblock = zmq.NOBLOCK
    while time.monotonic_ns() < start_ns:
        time.sleep(max(0.0, (start_ns - time.monotonic_ns()) / 1e9))  # pacing: the common start time
    first_ns = time.monotonic_ns()

    def send_upto(due: int) -> None:
        nonlocal sent, refused, garbage_sent, seq
        while sent + refused < due:
            topic, prefix, frames = entries[(sent + refused) % n_pool]
            if prefix is not None:
                seq += 1
                frames = [topic, _stamp(prefix, seq, time.monotonic_ns())]
            try:
                sock.send_multipart(frames, noblock)  # type: ignore[arg-type]
                sent += 1
                if prefix is None:
                    garbage_sent += 1
            except zmq.Again:
                refused += 1

    while True:
        now = time.monotonic_ns()
        if now >= end_ns:
            break
        due = min(total, (now - start_ns) * total // (end_ns - start_ns))
        max_behind = max(max_behind, due - sent - refused)
        send_upto(due)
        tick_left = 1_000_000 - (time.monotonic_ns() - start_ns) % 1_000_000
        time.sleep(tick_left / 1e9)  # pacing: the next millisecond tick of the schedule
    send_upto(total)
    last_ns = time.monotonic_ns()
    finals_refused = []
    for final in FINAL_COMMANDS.values():
        cls = MESSAGE_TYPES[final["type"]]
        seq += 1
        msg = cls(agent=AGENT, seq=seq, t_ns=time.monotonic_ns(), source=source,
                  **{k: v for k, v in final.items() if k != "type"})
        try:  # blocking (up to SNDTIMEO): the final commands must not be refused like flood messages
            sock.send_multipart([f"cmd.{AGENT}.{final['type']}".encode(), encode(msg)])
        except zmq.Again:
            finals_refused.append(final["type"])
    final_ns = time.monotonic_ns()
    print(json.dumps({
        "index": index, "offered": sent + refused, "sent": sent, "refused": refused, "garbage_sent": garbage_sent,
        "first_ns": first_ns, "last_ns": last_ns, "final_sent_ns": final_ns, "finals_refused": finals_refused,
        "max_behind_ms": max_behind / rate * 1000.0, "garbage_by_kind": pool.garbage_by_kind,
        "valid_by_type": pool.valid_by_type, "pool": n_pool,
    }), flush=True)
    # Keep the connection until told (or stdin closes): a peer that goes away may take its unread
    # messages, the final commands among them, with it.
    sys.stdin.readline()
    sock.close()
    ctx.term()
    return 0
