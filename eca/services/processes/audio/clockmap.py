"""Map PortAudio stream times (DAC times) onto the monotonic clock, and reject implausible ones.

PortAudio's time origin differs per host API (ALSA uses the monotonic clock, JACK its own frame time,
others something else), so the offset is measured: at each callback the stream's `currentTime` is
paired with `time.monotonic_ns()` read in the same callback. Scheduling delay only ever makes the
monotonic reading late, so the smallest recent offset is the best estimate (a sliding-window minimum).

A DAC time is implausible when it is zero or not finite, lies before the callback's current time,
further ahead than `max_ahead_s`, or runs backwards; then the buffer is taken to play at
callback time + the stream's output latency.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class CallbackStamp:
    """What the callback records about one output buffer; converted later, outside the callback."""

    dac_time_s: float  # time_info.outputBufferDacTime (stream clock)
    current_time_s: float  # time_info.currentTime (stream clock)
    monotonic_ns: int  # time.monotonic_ns() read in the callback
    frames: int


class ClockMap:
    def __init__(self, sample_rate: int, output_latency_s: float, *, window_s: float = 2.0,
                 max_ahead_s: float = 1.0) -> None:
        self.sample_rate = sample_rate
        self.output_latency_s = max(0.0, float(output_latency_s))
        self.max_ahead_s = max_ahead_s
        self._window_ns = round(window_s * 1e9)
        self._offsets: deque[tuple[int, int]] = deque()  # (monotonic_ns, offset_ns) for the sliding min
        self._last_dac_ns: int | None = None
        self._last_frames = 0
        self.fallbacks = 0  # buffers whose DAC time was rejected

    def to_monotonic_ns(self, stamp: CallbackStamp) -> int:
        """Monotonic time at which the buffer's first frame reaches the DAC."""
        fallback = stamp.monotonic_ns + round(self.output_latency_s * 1e9)
        offset = self._offset_ns(stamp)
        dac = stamp.dac_time_s
        plausible = (
            offset is not None
            and math.isfinite(dac)
            and dac != 0.0
            and dac >= stamp.current_time_s - 1e-4
            and dac - stamp.current_time_s <= self.max_ahead_s
        )
        dac_ns = round(dac * 1e9) + offset if plausible and offset is not None else fallback
        if self._last_dac_ns is not None:
            # The previous buffer's end is the earliest this one can start: never run backwards.
            expected = self._last_dac_ns + round(self._last_frames * 1e9 / self.sample_rate)
            if dac_ns < expected - 1_000_000:
                plausible = False
                dac_ns = max(fallback, expected)
        if not plausible:
            self.fallbacks += 1
        self._last_dac_ns = dac_ns
        self._last_frames = stamp.frames
        return dac_ns

    def _offset_ns(self, stamp: CallbackStamp) -> int | None:
        if not (math.isfinite(stamp.current_time_s) and stamp.current_time_s > 0.0):
            return self._offsets[0][1] if self._offsets else None
        offset = stamp.monotonic_ns - round(stamp.current_time_s * 1e9)
        # Monotone deque of candidates for the sliding-window minimum.
        while self._offsets and self._offsets[-1][1] >= offset:
            self._offsets.pop()
        self._offsets.append((stamp.monotonic_ns, offset))
        while self._offsets[0][0] < stamp.monotonic_ns - self._window_ns:
            self._offsets.popleft()
        return self._offsets[0][1]
