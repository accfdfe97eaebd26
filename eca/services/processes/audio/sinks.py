"""Where samples go: the sink interface, a null sink paced by the monotonic clock, and a fake for tests
(the PortAudio stream is in sounddevice_sink.py; output.py picks the one a machine has).

Every sink pulls fixed-size blocks from a render function, the way a PortAudio callback does:
`render(out, stamp)` fills `out` (float32 mono) and keeps `stamp`, an opaque record of when the block
was requested; `sink.dac_time_ns(stamp)` later turns it into the monotonic time at which the block's
first sample reaches the DAC. That conversion happens outside the callback.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from eca.agent.clock import Clock, MonotonicClock, VirtualClock
from eca.services.processes.audio.pacer import BlockPacer, PacedOutput, RenderFn, pacer_for

log = logging.getLogger(__name__)

__all__ = ["FakeSink", "NullSink", "RenderFn", "Sink"]


class Sink(Protocol):
    sample_rate: int
    block_frames: int
    realtime: bool  # True: blocks are pulled by another thread; False: the caller drives (tests)

    def start(self, render: RenderFn, on_block: Callable[[], None] | None = None) -> None: ...

    def stop(self) -> None: ...

    def dac_time_ns(self, stamp: Any) -> int: ...


class FakeSink:
    """Pulls blocks only when told to (`advance`), on a VirtualClock; keeps everything it played.

    Block k is requested at clock time t_k and plays over [t_k + latency, t_k+1 + latency). After each
    block the clock moves to t_k+1 and `on_block` (the player's publisher step) runs, synchronously.
    """

    realtime = False

    def __init__(self, clock: VirtualClock, sample_rate: int = 48_000, block_frames: int = 480,
                 latency_s: float = 0.0) -> None:
        self.clock = clock
        self.sample_rate = int(sample_rate)
        self.block_frames = int(block_frames)
        self.latency_ns = round(latency_s * 1e9)
        self._render: RenderFn | None = None
        self._on_block: Callable[[], None] | None = None
        self._t0_ns = clock.now_ns()
        self.blocks_played = 0
        self._played: list[np.ndarray] = []

    def start(self, render: RenderFn, on_block: Callable[[], None] | None = None) -> None:
        self._render, self._on_block = render, on_block
        self._t0_ns = self.clock.now_ns()
        self.blocks_played = 0

    def stop(self) -> None:
        self._render = None

    def dac_time_ns(self, stamp: Any) -> int:
        return int(stamp)

    def block_time_ns(self, k: int) -> int:
        """Clock time at which block k (counted from start) is requested."""
        return self._t0_ns + (k * self.block_frames * 1_000_000_000) // self.sample_rate

    def advance(self, n_blocks: int = 1) -> np.ndarray:
        """Play n blocks; returns the samples handed to the 'DAC'."""
        if self._render is None:
            raise RuntimeError("FakeSink is not started")
        out = np.zeros((n_blocks, self.block_frames), dtype=np.float32)
        for i in range(n_blocks):
            k = self.blocks_played
            self.clock.set_ns(max(self.clock.now_ns(), self.block_time_ns(k)))
            self._render(out[i], self.block_time_ns(k) + self.latency_ns)
            self.blocks_played += 1
            self.clock.set_ns(max(self.clock.now_ns(), self.block_time_ns(k + 1)))
            if self._on_block is not None:
                self._on_block()
        flat = out.reshape(-1)
        self._played.append(flat)
        return flat

    @property
    def output(self) -> np.ndarray:
        return np.concatenate(self._played) if self._played else np.zeros(0, dtype=np.float32)


class NullSink:
    """No sound device: blocks pulled on the clock, so timing stays real. Every NullSink of a process with the
    same clock and block length shares one pacing thread (pacer.py), which also runs each output's publisher
    step after its block (`drives_publisher`): an added agent costs its own work, not two threads' wake-ups."""

    realtime = True
    drives_publisher = True

    def __init__(self, sample_rate: int = 48_000, block_frames: int = 480, clock: Clock | None = None,
                 latency_s: float = 0.0) -> None:
        self.sample_rate = int(sample_rate)
        self.block_frames = int(block_frames)
        self.clock = clock if clock is not None else MonotonicClock()
        self.latency_ns = round(latency_s * 1e9)
        self._output: PacedOutput | None = None
        self._pacer: BlockPacer | None = None

    def start(self, render: RenderFn, on_block: Callable[[], None] | None = None) -> None:
        if self._output is not None:
            raise RuntimeError("NullSink already started")
        self._pacer = pacer_for(self.clock, self.sample_rate, self.block_frames)
        self._output = self._pacer.add(render, on_block, self.latency_ns)

    def stop(self) -> None:
        if self._output is not None and self._pacer is not None:
            self._pacer.remove(self._output)
        self._output = None

    def dac_time_ns(self, stamp: Any) -> int:
        return int(stamp)
