"""Bridges from the web service's bus loop (one thread) to its WebRTC tracks (the asyncio thread).

The loop draws each agent's face at every frame slot and receives the agent's voice blocks from the
audio service; the tracks, on the event loop, take them when their encoders want the next frame. Both
sides hold at most a fixed amount: a frame feed keeps only the newest frame per agent (a viewer whose
network stalls skips frames, it never queues them), a voice feed keeps at most `max_s` of samples.
"""

from __future__ import annotations

import asyncio
import threading
from collections import deque
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Picture:
    """One drawn frame: the display time it was composed for (master clock, ns) and its pixels."""

    frame_ns: int
    yuv: np.ndarray  # yuv420p planes stacked as av.VideoFrame.from_ndarray(format="yuv420p") takes them
    width: int
    height: int
    early: bool = False  # drawn ahead of its slot to show a commanded change at once: every viewer takes it


class FrameFeed:
    """The newest picture per agent, and a wake-up for every track waiting on that agent."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._latest: dict[str, Picture] = {}
        self._waiters: dict[str, list[tuple[asyncio.AbstractEventLoop, asyncio.Event]]] = {}

    def put(self, agent: str, picture: Picture) -> None:
        """From the drawing thread: replace the agent's picture and wake its tracks."""
        with self._lock:
            self._latest[agent] = picture
            waiters = self._waiters.pop(agent, [])
        for loop, event in waiters:
            loop.call_soon_threadsafe(event.set)

    async def next_after(self, agent: str, frame_ns: int, early_after_ns: int | None = None) -> Picture:
        """On the event loop: the agent's newest picture for a time after `frame_ns`, or an early one
        after `early_after_ns` (waits for one)."""
        loop = asyncio.get_running_loop()
        early_after = frame_ns if early_after_ns is None else min(frame_ns, early_after_ns)
        while True:
            with self._lock:
                picture = self._latest.get(agent)
                if picture is not None and (picture.frame_ns > frame_ns
                                            or picture.early and picture.frame_ns > early_after):
                    return picture
                event = asyncio.Event()
                self._waiters.setdefault(agent, []).append((loop, event))
            await event.wait()

    def forget(self, agent: str) -> None:
        with self._lock:
            self._latest.pop(agent, None)


class VoiceFeed:
    """One agent's voice as a timeline of samples at the output rate, from blocks stamped with the
    master clock; a track takes the samples of any span of that clock, silence where no block covers it
    (blocks that came late or never). Holds at most `max_s` of samples."""

    def __init__(self, sample_rate: int = 48_000, max_s: float = 2.0) -> None:
        self.sample_rate = sample_rate
        self._max_samples = round(max_s * sample_rate)
        self._lock = threading.Lock()
        self._blocks: deque[tuple[int, np.ndarray]] = deque()  # (dac time of the first sample, int16 samples)
        self._held = 0
        self.last_block_ns: int | None = None  # the newest block's start: where the voice is now
        self._waiters: list[tuple[asyncio.AbstractEventLoop, asyncio.Event]] = []  # tracks waiting for sound

    def add(self, dac_time_ns: int, samples: np.ndarray, sample_rate: int) -> None:
        """From the bus loop: one block of the voice (int16 mono)."""
        if sample_rate != self.sample_rate:
            raise ValueError(f"voice at {sample_rate} Hz, this feed takes {self.sample_rate} Hz")
        with self._lock:
            self._blocks.append((dac_time_ns, samples))
            self._held += len(samples)
            while self._held > self._max_samples:
                _, old = self._blocks.popleft()
                self._held -= len(old)
            self.last_block_ns = dac_time_ns
            waiters, self._waiters = self._waiters, []
        for loop, event in waiters:
            loop.call_soon_threadsafe(event.set)

    def _end_ns(self, first_ns: int, samples: np.ndarray) -> int:
        """When a block that starts at `first_ns` ends (master clock)."""
        return first_ns + len(samples) * 1_000_000_000 // self.sample_rate

    async def wait_for_sound(self, after_ns: int) -> int:
        """On the event loop: the master-clock time from which the voice next has samples at or after `after_ns`
        (`after_ns` itself while a block covers it); waits until a block brings some. Only sounding voice comes
        in blocks (silence is a gap between them), so a track that skips silent frames sleeps through a pause
        instead of waking for each of its frames."""
        loop = asyncio.get_running_loop()
        while True:
            with self._lock:
                best: int | None = None
                for first_ns, samples in self._blocks:
                    if self._end_ns(first_ns, samples) <= after_ns:
                        continue
                    if first_ns <= after_ns:
                        return after_ns
                    best = first_ns if best is None else min(best, first_ns)
                if best is not None:
                    return best
                event = asyncio.Event()
                self._waiters.append((loop, event))
            await event.wait()

    def sounding(self, t_ns: int, window_ns: int = 20_000_000, floor: int = 64) -> bool:
        """Whether the voice is heard around master-clock time `t_ns` (a sample louder than `floor` within
        `window_ns` of it), without letting any block go: a browser-drawn mouth follows it."""
        rate = self.sample_rate
        lo_ns, hi_ns = t_ns - window_ns // 2, t_ns + window_ns // 2
        for first_ns, samples in self._blocks_around(lo_ns, hi_ns):
            a = max(0, (lo_ns - first_ns) * rate // 1_000_000_000)
            b = min(len(samples), (hi_ns - first_ns) * rate // 1_000_000_000 + 1)
            if a < b and int(np.abs(samples[a:b].astype(np.int32)).max()) > floor:
                return True
        return False

    def _blocks_around(self, lo_ns: int, hi_ns: int) -> list[tuple[int, np.ndarray]]:
        """The held blocks that overlap [lo_ns, hi_ns), as they are (a block's samples are never changed once
        added). Blocks come in time order and a frame's time is near the newest, so they are looked for from the
        newest back: a feed holds up to `max_s` of blocks, and walking all of them for every agent at every frame
        slot was a tenth of the face frames' cost. The lock is held only to pick them: the bus loop and the event
        loop share this feed, and a thread that took the lock and then lost the interpreter's lock in numpy would
        hold the other one up for a switch interval or more (a voice frame sent late)."""
        found: list[tuple[int, np.ndarray]] = []
        with self._lock:
            for first_ns, samples in reversed(self._blocks):
                if first_ns >= hi_ns:
                    continue
                if self._end_ns(first_ns, samples) <= lo_ns:
                    break
                found.append((first_ns, samples))
        return found

    def take(self, start_ns: int, count: int) -> np.ndarray:
        """The `count` samples from master-clock time `start_ns` on (int16): what the blocks hold there,
        zeros elsewhere. Blocks wholly before that span are let go."""
        out = np.zeros(count, dtype=np.int16)
        rate = self.sample_rate
        end_ns = start_ns + count * 1_000_000_000 // rate
        with self._lock:
            while self._blocks:
                first_ns, samples = self._blocks[0]
                if self._end_ns(first_ns, samples) > start_ns:
                    break
                self._blocks.popleft()
                self._held -= len(samples)
            blocks = tuple(self._blocks)  # copied under the lock, read outside it (_blocks_around says why)
        for first_ns, samples in blocks:
            if first_ns >= end_ns:
                break
            # positions in samples from start_ns, rounded to the nearest sample
            offset = round((first_ns - start_ns) * rate / 1e9)
            lo, hi = max(0, offset), min(count, offset + len(samples))
            if lo < hi:
                out[lo:hi] = samples[lo - offset:hi - offset]
        return out
