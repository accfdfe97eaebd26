"""The silent outputs of a process share one pacing thread (audio/pacer.py): blocks on the clock for each, a fault
of one leaves the others playing, a stopped one is never rendered again, and the thread goes when the last does."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from eca.agent.clock import MonotonicClock
from eca.services.processes.audio import NullSink, Player

SR, BLOCK = 48_000, 480
PERIOD_NS = BLOCK * 1_000_000_000 // SR


def pacer_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "audio-pacer"]


def wait_until(condition: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"not within {timeout_s} s: {what}"
        time.sleep(0.005)  # polling a condition, with a deadline


class Recorder:
    def __init__(self) -> None:
        self.stamps: list[int] = []
        self.blocks = 0

    def render(self, out: np.ndarray, stamp: Any) -> None:
        assert out.shape == (BLOCK,)
        self.stamps.append(int(stamp))

    def on_block(self) -> None:
        self.blocks += 1


def test_outputs_on_one_clock_share_one_thread_each_on_its_own_latency() -> None:
    clock = MonotonicClock()
    recorders = [Recorder() for _ in range(3)]
    sinks = [NullSink(SR, BLOCK, clock=clock, latency_s=0.01 * i) for i in range(3)]
    for sink, rec in zip(sinks, recorders, strict=True):
        sink.start(rec.render, rec.on_block)
    try:
        wait_until(lambda: all(len(r.stamps) >= 20 for r in recorders), 10.0, "20 blocks each")
        assert len(pacer_threads()) == 1
        for rec in recorders:
            steps = np.diff(rec.stamps[:20])
            assert np.all(np.abs(steps - PERIOD_NS) <= 1), steps  # one block apart, to the ns rounding
            assert rec.blocks >= len(rec.stamps) - 1  # the publisher step after each block
        # the same grid, each output ahead by its own latency
        first = recorders[0].stamps
        for i, rec in enumerate(recorders[1:], start=1):
            shift = (rec.stamps[0] - 10_000_000 * i - first[0]) % PERIOD_NS
            assert min(shift, PERIOD_NS - shift) <= 1
    finally:
        for sink in sinks:
            sink.stop()
    wait_until(lambda: not pacer_threads(), 5.0, "the pacing thread to end with its last output")


def test_a_failing_output_stops_alone_and_the_others_play_on() -> None:
    good, calls = Recorder(), []

    def bad(out: np.ndarray, stamp: Any) -> None:
        calls.append(stamp)
        raise RuntimeError("a broken output")

    a, b = NullSink(SR, BLOCK), NullSink(SR, BLOCK)
    a.start(bad)
    b.start(good.render, good.on_block)
    try:
        wait_until(lambda: len(good.stamps) >= 30, 10.0, "30 blocks of the good output")
        assert calls == calls[:1]  # rendered once, failed, never again
    finally:
        a.stop()
        b.stop()


def test_a_stopped_output_is_not_rendering_and_never_renders_again() -> None:
    inside, release = threading.Event(), threading.Event()
    after_stop: list[int] = []
    stopped = threading.Event()

    def render(out: np.ndarray, stamp: Any) -> None:
        if stopped.is_set():
            after_stop.append(int(stamp))
        inside.set()
        release.wait(5.0)

    sink = NullSink(SR, BLOCK)
    sink.start(render)
    assert inside.wait(5.0)
    stopper = threading.Thread(target=lambda: (sink.stop(), stopped.set()))
    stopper.start()
    stopper.join(0.2)  # a window in which stop must still be waiting on the render under way
    assert stopper.is_alive(), "stop returned while its output was rendering"
    release.set()
    stopper.join(5.0)
    assert not stopper.is_alive()
    wait_until(lambda: not pacer_threads(), 5.0, "the pacing thread to end")
    assert after_stop == []


def test_a_player_on_the_silent_output_runs_no_publisher_thread_of_its_own() -> None:
    events: list[object] = []
    players = [Player(NullSink(SR, BLOCK), events.append, agent_id=f"a{i}").start() for i in range(4)]
    try:
        names = [t.name for t in threading.enumerate()]
        assert not [n for n in names if n.startswith("audio-publisher-")]
        assert names.count("audio-pacer") == 1
        rid = "hello"
        players[2].say_pcm(rid, np.full(SR // 10, 0.25, np.float32), SR)
        wait_until(lambda: any(getattr(e, "request_id", None) == rid and type(e).__name__ == "PlayerFinished"
                               for e in events), 10.0, "the say to finish (published by the pacing thread)")
    finally:
        for p in players:
            p.close()
