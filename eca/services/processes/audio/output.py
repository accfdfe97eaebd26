"""The output a machine has: a PortAudio stream when one can be opened, otherwise a silent sink paced by
the clock, after one clear warning (sinks.py, sounddevice_sink.py)."""

from __future__ import annotations

import logging

from eca.agent.clock import Clock
from eca.services.processes.audio.config import AudioConfig
from eca.services.processes.audio.sinks import NullSink, Sink

log = logging.getLogger(__name__)

_warned_no_device = False


def open_sink(sample_rate: int = 48_000, block_frames: int = 480, *, device: str | int | None = None,
              latency: str | float = "low", clock: Clock | None = None,
              config: AudioConfig | None = None, silent: bool = False) -> Sink:
    """A PortAudio sink when one can be opened, otherwise a NullSink after one clear warning.

    With `config` (configs/audio.toml via AudioConfig.load()), its device settings replace the others.
    `silent`: the voice is heard elsewhere (a pipecat transport, a browser): the silent sink, no sound card
    tried, and nothing to warn about.
    """
    global _warned_no_device
    latency_s = config.null_latency_s if config is not None else 0.0
    if config is not None:
        sample_rate, block_frames = config.sample_rate, config.block_frames
        device, latency = config.device, config.latency
    window_s = config.offset_window_s if config is not None else 2.0
    max_ahead_s = config.max_dac_ahead_s if config is not None else 1.0
    if silent:
        return NullSink(sample_rate, block_frames, clock=clock, latency_s=latency_s)
    reason: str | None = None
    try:
        from eca.services.processes.audio.sounddevice_sink import (  # PortAudio loads here
            SoundDeviceSink,
            no_output_reason,
        )

        reason = no_output_reason(device)
        if reason is None:
            return SoundDeviceSink(sample_rate, block_frames, device=device, latency=latency,
                                   offset_window_s=window_s, max_dac_ahead_s=max_ahead_s)
    except (ImportError, OSError) as exc:  # sounddevice raises OSError when libportaudio is missing
        reason = f"PortAudio is not available ({exc})"
    if not _warned_no_device:
        _warned_no_device = True
        log.warning("no audio output: %s; playing into a silent sink paced by the monotonic clock "
                    "(timing, lifecycle and lip-sync behave the same, nothing is heard)", reason)
    return NullSink(sample_rate, block_frames, clock=clock, latency_s=latency_s)
