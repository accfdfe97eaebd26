"""The real output: a sounddevice (PortAudio) OutputStream.

The callback only hands the output buffer to the player's render function (which copies prepared
samples, and a copy of the block when the voice is published) and stamps it with the stream's DAC time,
current time and the monotonic clock. Mapping those onto the monotonic clock (`ClockMap`) happens later
in the publisher thread.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np
import sounddevice as sd

from eca.services.processes.audio.clockmap import CallbackStamp, ClockMap
from eca.services.processes.audio.sinks import RenderFn


def no_output_reason(device: str | int | None = None) -> str | None:
    """Why no output stream can be opened, or None when one can."""
    try:
        devices = sd.query_devices()
    except sd.PortAudioError as exc:
        return f"PortAudio cannot list devices ({exc})"
    if not any(d["max_output_channels"] > 0 for d in devices):
        return "PortAudio lists no output device"
    try:
        sd.check_output_settings(device=device, channels=1)
    except (sd.PortAudioError, ValueError) as exc:
        return f"output device {device!r} unusable ({exc})"
    return None


class SoundDeviceSink:
    realtime = True

    def __init__(self, sample_rate: int = 48_000, block_frames: int = 480, *, device: str | int | None = None,
                 latency: str | float = "low", offset_window_s: float = 2.0, max_dac_ahead_s: float = 1.0) -> None:
        self.sample_rate = int(sample_rate)
        self.block_frames = int(block_frames)
        self.device = device
        self.latency = latency
        self.offset_window_s = offset_window_s
        self.max_dac_ahead_s = max_dac_ahead_s
        self._stream: sd.OutputStream | None = None
        self._clockmap: ClockMap | None = None
        self.status_count = 0  # callbacks that reported a status (underflow...), for diagnostics

    def start(self, render: RenderFn, on_block: Callable[[], None] | None = None) -> None:
        monotonic_ns = time.monotonic_ns

        def callback(outdata: np.ndarray, frames: int, time_info: Any, status: sd.CallbackFlags) -> None:
            # Real-time thread: no logging, no locks, no allocation beyond the small stamp and the player's
            # records (with the voice published, a copy of the block: 2 KB).
            if status:  # CallbackFlags: truthy on underflow etc.; count only, never raise in here
                self.status_count += 1
            stamp = CallbackStamp(time_info.outputBufferDacTime, time_info.currentTime, monotonic_ns(),
                                  frames)
            render(outdata[:, 0], stamp)

        self._stream = sd.OutputStream(samplerate=self.sample_rate, blocksize=self.block_frames,
                                       device=self.device, channels=1, dtype="float32",
                                       latency=self.latency, callback=callback)
        self._clockmap = ClockMap(self.sample_rate, float(self._stream.latency),
                                  window_s=self.offset_window_s, max_ahead_s=self.max_dac_ahead_s)
        self._stream.start()

    def stop(self) -> None:
        if self._stream is not None:
            self._stream.stop()
            self._stream.close()
            self._stream = None

    @property
    def output_latency_s(self) -> float:
        return float(self._stream.latency) if self._stream is not None else 0.0

    @property
    def clock_fallbacks(self) -> int:
        return self._clockmap.fallbacks if self._clockmap is not None else 0

    def dac_time_ns(self, stamp: Any) -> int:
        assert self._clockmap is not None, "sink not started"
        return self._clockmap.to_monotonic_ns(stamp)
