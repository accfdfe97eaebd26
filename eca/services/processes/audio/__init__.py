"""The audio engine: plays utterances through a sink, is the master clock, emits lifecycle and mouth events
and, when asked, every block the output takes (the voice, for outputs in other processes).

The service process is a thin wrapper: it maps the plain events of `Player` onto bus messages.
"""

from eca.services.processes.audio.events import (
    AudioEvent,
    PlayerAnchor,
    PlayerFailed,
    PlayerFinished,
    PlayerInterrupted,
    PlayerMouthKeys,
    PlayerMouthReset,
    PlayerStarted,
    PlayerVoiceBlock,
)
from eca.services.processes.audio.output import open_sink
from eca.services.processes.audio.player import Player
from eca.services.processes.audio.sinks import FakeSink, NullSink, Sink

__all__ = [
    "AudioEvent",
    "PlayerAnchor",
    "FakeSink",
    "PlayerMouthKeys",
    "PlayerMouthReset",
    "NullSink",
    "Player",
    "Sink",
    "PlayerFailed",
    "PlayerFinished",
    "PlayerInterrupted",
    "PlayerStarted",
    "PlayerVoiceBlock",
    "open_sink",
]
