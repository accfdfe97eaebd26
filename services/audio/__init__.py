"""The audio engine: plays utterances through a sink, is the master clock, emits lifecycle and mouth events
and, when asked, every block the output takes (the voice, for outputs in other processes).

The service process is a thin wrapper: it maps the plain events of `Player` onto bus messages.
"""

from services.audio.events import (
    AudioEvent,
    ClockAnchor,
    MouthKeys,
    MouthReset,
    SpeechFailed,
    SpeechFinished,
    SpeechInterrupted,
    SpeechStarted,
    VoiceBlock,
)
from services.audio.output import open_sink
from services.audio.player import Player
from services.audio.sinks import FakeSink, NullSink, Sink

__all__ = [
    "AudioEvent",
    "ClockAnchor",
    "FakeSink",
    "MouthKeys",
    "MouthReset",
    "NullSink",
    "Player",
    "Sink",
    "SpeechFailed",
    "SpeechFinished",
    "SpeechInterrupted",
    "SpeechStarted",
    "VoiceBlock",
    "open_sink",
]
