"""Plain events the player emits; the audio service maps each onto one bus message.

Times are integer nanoseconds of the monotonic clock; sample positions count from an utterance's
first sample at the device sample rate.
"""

from __future__ import annotations

from dataclasses import dataclass

from agent.lipsync import MouthKey


@dataclass(frozen=True, slots=True)
class SpeechStarted:
    agent_id: str
    utterance_id: str
    sample_rate: int
    dac_time_ns: int  # when the utterance's first sample reaches the DAC


@dataclass(frozen=True, slots=True)
class SpeechFinished:
    agent_id: str
    utterance_id: str
    played_s: float
    dac_time_ns: int  # when the last sample left the DAC


@dataclass(frozen=True, slots=True)
class SpeechInterrupted:
    agent_id: str
    utterance_id: str
    played_s: float  # samples actually handed to the DAC before the cut; 0 for one still queued
    dac_time_ns: int  # when the voice stops at the DAC


@dataclass(frozen=True, slots=True)
class SpeechFailed:
    agent_id: str
    utterance_id: str
    reason: str


@dataclass(frozen=True, slots=True)
class ClockAnchor:
    agent_id: str
    utterance_id: str
    sample_index: int
    sample_rate: int
    dac_time_ns: int  # sample `sample_index` of the utterance is at the DAC at this monotonic time


@dataclass(frozen=True, slots=True)
class MouthKeys:
    agent_id: str
    utterance_id: str
    sample_rate: int
    keys: tuple[MouthKey, ...]


@dataclass(frozen=True, slots=True)
class MouthReset:
    """Close the mouth now and drop every mouth key queued for this agent (interruption)."""

    agent_id: str
    utterance_id: str
    dac_time_ns: int


@dataclass(frozen=True, slots=True)
class VoiceBlock:
    """One block exactly as the output took it, silence included: consecutive blocks form one track."""

    agent_id: str
    utterance_id: str  # the utterance whose sample starts the block; "" when it starts in silence
    first_sample: int  # index of its first sample since the output started
    sample_rate: int
    dac_time_ns: int  # when its first sample reaches the DAC (the mapping the clock anchors use)
    pcm: bytes  # mono, signed 16-bit little-endian


AudioEvent = (SpeechStarted | SpeechFinished | SpeechInterrupted | SpeechFailed | ClockAnchor | MouthKeys
              | MouthReset | VoiceBlock)
TERMINAL_EVENTS = (SpeechFinished, SpeechInterrupted, SpeechFailed)
