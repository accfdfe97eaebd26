"""Plain events the player emits; the audio service maps each onto one bus message.

Each is named Player* so it never reads as the bus message it becomes (services/processes/audio/service.py maps
them); `request_id` is the say request's id, as on the bus. Times are integer nanoseconds of the
monotonic clock; sample positions count from an utterance's first sample at the device sample rate.
"""

from __future__ import annotations

from dataclasses import dataclass

from eca.agent.lipsync import MouthKey


@dataclass(frozen=True, slots=True)
class PlayerStarted:
    agent: str
    request_id: str
    sample_rate: int
    dac_time_ns: int  # when the utterance's first sample reaches the DAC


@dataclass(frozen=True, slots=True)
class PlayerFinished:
    agent: str
    request_id: str
    played_s: float
    dac_time_ns: int  # when the last sample left the DAC


@dataclass(frozen=True, slots=True)
class PlayerInterrupted:
    agent: str
    request_id: str
    played_s: float  # samples actually handed to the DAC before the cut; 0 for one still queued
    dac_time_ns: int  # when the voice stops at the DAC


@dataclass(frozen=True, slots=True)
class PlayerFailed:
    agent: str
    request_id: str
    reason: str


@dataclass(frozen=True, slots=True)
class PlayerAnchor:
    agent: str
    request_id: str
    sample_index: int
    sample_rate: int
    dac_time_ns: int  # sample `sample_index` of the utterance is at the DAC at this monotonic time


@dataclass(frozen=True, slots=True)
class PlayerMouthKeys:
    agent: str
    request_id: str
    sample_rate: int
    keys: tuple[MouthKey, ...]


@dataclass(frozen=True, slots=True)
class PlayerMouthReset:
    """Close the mouth now and drop every mouth key queued for this agent (interruption)."""

    agent: str
    request_id: str
    dac_time_ns: int


@dataclass(frozen=True, slots=True)
class PlayerVoiceBlock:
    """One block exactly as the output took it, when it sounds: `first_sample` counts the silent blocks left out."""

    agent: str
    request_id: str  # the utterance whose sample starts the block; "" when it starts in silence
    first_sample: int  # index of its first sample since the output started
    sample_rate: int
    dac_time_ns: int  # when its first sample reaches the DAC (the mapping the clock anchors use)
    pcm: bytes  # mono, signed 16-bit little-endian


AudioEvent = (PlayerStarted | PlayerFinished | PlayerInterrupted | PlayerFailed | PlayerAnchor | PlayerMouthKeys
              | PlayerMouthReset | PlayerVoiceBlock)
TERMINAL_EVENTS = (PlayerFinished, PlayerInterrupted, PlayerFailed)
