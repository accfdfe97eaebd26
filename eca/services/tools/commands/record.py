"""`eca record FILE` captures every message on the bus; `eca replay FILE` publishes it again."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import zmq

from eca.protocol.bus import BusTimeout, Publisher, Subscriber
from eca.protocol.codec import encode
from eca.protocol.endpoints import BusConfigError, load_bus_config
from eca.services.tools import cli_args
from eca.services.tools.recording import RecordingError, RecordingWriter, read_recording


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("record", help="capture the bus traffic into a compact msgpack log")
    p.add_argument("file", type=Path)
    p.add_argument("--config", default=None)
    p.add_argument("--instance", default=None)
    p.add_argument("--seconds", type=cli_args.seconds, default=None, help="stop after this long (default: Ctrl-C)")
    p.add_argument("--topic", action="append", default=[], help="only these topic prefixes")
    p.add_argument("--heartbeats", action="store_true", help="keep heartbeats too")
    p.set_defaults(func=run_record)
    p = sub.add_parser("replay", help="re-publish a recording at its original pace or faster")
    p.add_argument("file", type=Path)
    p.add_argument("--config", default=None)
    p.add_argument("--instance", default=None)
    p.add_argument("--speed", type=cli_args.pace, default=1.0, help="pace factor; 0 = as fast as possible")
    p.add_argument("--topic", action="append", default=[], help="only these topic prefixes")
    p.set_defaults(func=run_replay)


def run_record(args: argparse.Namespace) -> int:
    try:
        config = load_bus_config(args.config, args.instance)
    except BusConfigError as exc:
        print(f"eca record: {exc}", file=sys.stderr)
        return 2
    try:
        writer = RecordingWriter(args.file, config.instance, time.monotonic_ns())
    except OSError as exc:
        print(f"eca record: cannot write {args.file}: {exc.strerror}", file=sys.stderr)
        return 2
    ctx = zmq.Context()
    sub = Subscriber(ctx, config, args.topic or [""])
    try:
        # the readiness barrier: nothing published from now on is missed, and no broker is an error
        early = sub.wait_ready(5.0)
    except BusTimeout as exc:
        print(f"eca record: {exc}", file=sys.stderr)
        writer.close()
        sub.close()
        ctx.term()
        return 1
    deadline = None if args.seconds is None else time.monotonic() + args.seconds
    print(f"recording {config.backend} into {args.file}", flush=True)
    try:
        for got in early:  # the current states, handed over by the broker's cache
            if got.message is not None:
                writer.write(time.monotonic_ns(), got.topic.encode(), encode(got.message))
        while deadline is None or time.monotonic() < deadline:
            if not sub.socket.poll(100):
                continue
            for frames in sub.read_frames(10_000):
                if len(frames) != 2 or (not args.heartbeats and frames[0].endswith(b".heartbeat")):
                    continue
                if frames[0].startswith(b"sys.") and frames[0].endswith(b".hello"):
                    continue
                writer.write(time.monotonic_ns(), frames[0], frames[1])
    except KeyboardInterrupt:
        pass
    finally:
        writer.close()
        sub.close()
        ctx.term()
    print(f"recorded {writer.count} messages", flush=True)
    return 0


def run_replay(args: argparse.Namespace) -> int:
    try:
        config = load_bus_config(args.config, args.instance)
        _, records = read_recording(args.file)  # all of it is checked before anything is sent
    except (BusConfigError, RecordingError) as exc:
        print(f"eca replay: {exc}", file=sys.stderr)
        return 1
    records = [r for r in records if not args.topic or any(r.topic.startswith(t.encode()) for t in args.topic)]
    ctx = zmq.Context()
    pub = Publisher(ctx, config, "eca-replay")
    try:
        pub.wait_ready()
    except BusTimeout as exc:
        print(f"eca replay: {exc}", file=sys.stderr)
        return 1
    start = time.monotonic()
    first = records[0].received_ns if records else 0
    for rec in records:
        if args.speed > 0:
            due = start + (rec.received_ns - first) / 1e9 / args.speed
            while (left := due - time.monotonic()) > 0:
                time.sleep(min(left, 0.05))
        pub.send_raw(rec.topic, rec.payload)
    pub.close()
    ctx.term()
    print(f"replayed {len(records)} messages", flush=True)
    return 0
