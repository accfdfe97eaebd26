"""One pacing thread for every silent output of a process.

An output without a sound card (NullSink: the voice is heard in a browser or a pipecat transport) still has to
pull its blocks on the clock, as a sound card would. With one thread per output, a process playing fifty
agents woke fifty threads a hundred times a second, and as many publisher threads again, each waiting for the
interpreter's lock: most of the audio service's cost per conversation. A BlockPacer wakes once per block for
all the outputs on its clock and block length, renders each in turn and hands each its publisher step
(`on_block`), so the cost of an added output is its own work, not a thread's wake-ups.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from eca.agent.clock import Clock, MonotonicClock

log = logging.getLogger(__name__)

RenderFn = Callable[[np.ndarray, Any], None]


@dataclass(eq=False)
class PacedOutput:
    """One output on a pacer: its render function, its publisher step, its DAC latency and its block buffer."""

    render: RenderFn
    on_block: Callable[[], None] | None
    latency_ns: int
    out: np.ndarray
    lock: threading.Lock = field(default_factory=threading.Lock)  # held while it renders: stop waits for it
    failed: bool = False


class BlockPacer:
    """Pulls one block from each of its outputs every `block_frames / sample_rate` of `clock`."""

    def __init__(self, clock: Clock, sample_rate: int, block_frames: int) -> None:
        self.clock = clock
        self.sample_rate, self.block_frames = sample_rate, block_frames
        self._lock = threading.Lock()
        self._outputs: list[PacedOutput] = []
        self._wake = threading.Event()  # a pacing wait, cut short when the last output leaves
        self._thread: threading.Thread | None = None

    def add(self, render: RenderFn, on_block: Callable[[], None] | None, latency_ns: int) -> PacedOutput:
        """Start pulling blocks from `render` at the next block of the pacer's grid."""
        output = PacedOutput(render, on_block, latency_ns, np.zeros(self.block_frames, dtype=np.float32))
        with self._lock:
            self._outputs = [*self._outputs, output]  # a new list: the pacing thread iterates its own copy
            if self._thread is None:
                self._wake.clear()
                self._thread = threading.Thread(target=self._run, name="audio-pacer", daemon=True)
                self._thread.start()
        return output

    def remove(self, output: PacedOutput) -> None:
        """Stop pulling from `output`; when this returns it is not rendering and never will again (unless called
        from its own render, which then finishes)."""
        with self._lock:
            self._outputs = [o for o in self._outputs if o is not output]
            if not self._outputs:
                self._wake.set()
            thread = self._thread
        if thread is not threading.current_thread():
            with output.lock:
                pass  # a render under way ends before this returns

    @property
    def count(self) -> int:
        return len(self._outputs)

    def _run(self) -> None:
        period_ns = self.block_frames * 1_000_000_000 // self.sample_rate
        remainder = self.block_frames * 1_000_000_000 % self.sample_rate
        t0 = self.clock.now_ns()
        k = 0
        while True:
            with self._lock:
                outputs = self._outputs
                if not outputs:
                    self._thread = None  # the next output starts a new thread on a new grid
                    return
                self._wake.clear()  # under the lock: a removal after this cuts the wait below short
            due = t0 + k * period_ns + (k * remainder) // self.sample_rate
            now = self.clock.now_ns()
            if due > now and self._wake.wait((due - now) / 1e9):
                continue  # pacing wait cut short: the outputs changed, look again
            for output in outputs:
                self._pull(output, due)
            k += 1

    @staticmethod
    def _pull(output: PacedOutput, due_ns: int) -> None:
        if output.failed:
            return
        with output.lock:
            try:
                output.render(output.out, due_ns + output.latency_ns)
                if output.on_block is not None:
                    output.on_block()
            except Exception:  # one output's fault must not silence the others sharing the thread
                output.failed = True
                log.exception("an audio output failed and stopped; the others play on")


_pacers: dict[tuple[object, int, int], BlockPacer] = {}
_pacers_lock = threading.Lock()


def pacer_for(clock: Clock, sample_rate: int, block_frames: int) -> BlockPacer:
    """The process's pacer for outputs on `clock` with this block length (every MonotonicClock is one clock)."""
    key = (MonotonicClock if type(clock) is MonotonicClock else id(clock), sample_rate, block_frames)
    with _pacers_lock:
        pacer = _pacers.get(key)
        if pacer is None:
            pacer = _pacers[key] = BlockPacer(clock, sample_rate, block_frames)
        return pacer
