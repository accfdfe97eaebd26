"""Audio engine settings from configs/audio.toml."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from eca.agent.config import ConfigError, load_toml, require
from eca.protocol.messages import MAX_AUDIO_BLOCK_BYTES, VoiceBlock
from eca.services.processes.audio.tts import EngineSettings

# The device rates a voice block can carry (the protocol's limits on its `sample_rate`).
_VOICE_RATE = next(f.metadata for f in dataclasses.fields(VoiceBlock) if f.name == "sample_rate")


@dataclass(frozen=True)
class AudioConfig:
    sample_rate: int = 48_000
    block_frames: int = 480
    latency: str | float = "low"
    device: str | int | None = None
    anchor_hz: float = 100.0
    publisher_hz: float = 120.0
    max_utterance_s: float = 600.0
    read_ahead_s: float = 8.0
    prepare_slice_s: float = 0.2
    offset_window_s: float = 2.0
    max_dac_ahead_s: float = 1.0
    publish_voice: bool = True
    null_latency_s: float = 0.05
    tts: EngineSettings = field(default_factory=EngineSettings)

    @classmethod
    def load(cls, name: str = "audio") -> AudioConfig:
        return cls.from_dict(load_toml(name), where=f"configs/{name}.toml")

    @classmethod
    def from_dict(cls, data: dict[str, Any], where: str = "audio config") -> AudioConfig:
        dev = require(data, "device", dict, where)
        player = require(data, "player", dict, where)
        clock = require(data, "clock", dict, where)
        output = data.get("output", {})
        if not isinstance(output, dict):
            raise ConfigError(f"{where}: [output] must be a table")
        publish_voice = output.get("publish_voice", True)
        if not isinstance(publish_voice, bool):
            raise ConfigError(f"{where} [output]: 'publish_voice' must be true or false, got {publish_voice!r}")
        null_latency_s = output.get("null_latency_s", 0.05)
        if isinstance(null_latency_s, bool) or not isinstance(null_latency_s, int | float) \
                or not 0 <= null_latency_s <= 1:
            raise ConfigError(f"{where} [output]: 'null_latency_s' must be seconds in [0, 1], got {null_latency_s!r}")
        device = dev.get("device", "")
        if not isinstance(device, str | int) or isinstance(device, bool):
            raise ConfigError(f"{where} [device]: 'device' must be a name or an index, got {device!r}")
        latency = dev.get("latency", "low")
        if isinstance(latency, str) and latency not in ("low", "high"):
            raise ConfigError(f"{where} [device]: 'latency' must be 'low', 'high' or seconds, got {latency!r}")
        cfg = cls(
            sample_rate=require(dev, "sample_rate", int, f"{where} [device]"),
            block_frames=require(dev, "block_frames", int, f"{where} [device]"),
            latency=latency,
            device=None if device == "" else device,
            anchor_hz=require(player, "anchor_hz", float, f"{where} [player]"),
            publisher_hz=require(player, "publisher_hz", float, f"{where} [player]"),
            max_utterance_s=require(player, "max_utterance_s", float, f"{where} [player]"),
            read_ahead_s=require(player, "read_ahead_s", float, f"{where} [player]"),
            prepare_slice_s=require(player, "prepare_slice_s", float, f"{where} [player]"),
            offset_window_s=require(clock, "offset_window_s", float, f"{where} [clock]"),
            max_dac_ahead_s=require(clock, "max_dac_ahead_s", float, f"{where} [clock]"),
            publish_voice=publish_voice,
            null_latency_s=float(null_latency_s),
            tts=_tts_from(data.get("tts", {}), f"{where} [tts]"),
        )
        for name in ("sample_rate", "block_frames", "anchor_hz", "publisher_hz", "max_utterance_s", "read_ahead_s",
                     "prepare_slice_s"):
            if getattr(cfg, name) <= 0:
                raise ConfigError(f"{where}: '{name}' must be > 0, got {getattr(cfg, name)}")
        if cfg.anchor_hz < 60.0:
            raise ConfigError(f"{where} [player]: 'anchor_hz' must be >= 60 (one anchor per video frame)")
        if cfg.prepare_slice_s > cfg.read_ahead_s:
            raise ConfigError(f"{where} [player]: 'prepare_slice_s' must not exceed 'read_ahead_s'")
        if cfg.publish_voice:  # each output block goes out as one voice message
            if cfg.block_frames * 2 > MAX_AUDIO_BLOCK_BYTES:
                raise ConfigError(f"{where} [device]: 'block_frames' over {MAX_AUDIO_BLOCK_BYTES // 2} does not fit "
                                  "in a voice message; set [output] publish_voice = false or use smaller blocks")
            if not _VOICE_RATE["lo"] <= cfg.sample_rate <= _VOICE_RATE["hi"]:
                raise ConfigError(f"{where} [device]: a voice message carries {_VOICE_RATE['lo']:g}-"
                                  f"{_VOICE_RATE['hi']:g} Hz, not {cfg.sample_rate}; set [output] "
                                  "publish_voice = false or change 'sample_rate'")
        return cfg


def _tts_from(table: Any, where: str) -> EngineSettings:
    if not isinstance(table, dict):
        raise ConfigError(f"{where} must be a table")
    try:
        return EngineSettings.from_table(table, where)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
