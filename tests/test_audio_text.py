"""A say with only text: the player's text-to-speech engine voices it on the preparer; a missing, failing
or hanging engine fails that request with a reason naming it, never a hang."""

from __future__ import annotations

import numpy as np
import pytest

from eca.agent.clock import VirtualClock
from eca.services.processes.audio import FakeSink, Player, PlayerFailed, PlayerFinished, PlayerStarted
from eca.services.processes.audio.tts import EngineSettings, SpeechSynthesisError, engine

SR = 48_000
BLOCK = 480


class ToneSpeech:
    """An engine whose speech is known: a 0.3 s tone at 16 kHz per call."""

    name = "test tone"

    def __init__(self) -> None:
        self.texts: list[str] = []

    def speak(self, text: str) -> tuple[np.ndarray, int]:
        self.texts.append(text)
        t = np.arange(4800) / 16_000
        return (0.5 * np.sin(2 * np.pi * 200 * t)).astype(np.float32), 16_000


class BrokenSpeech:
    name = "broken"

    def speak(self, text: str) -> tuple[np.ndarray, int]:
        raise SpeechSynthesisError("broken: the voice model is missing")


def play(tts: object, text: str = "Hello there.") -> tuple[list[object], np.ndarray]:
    clock = VirtualClock(1_000_000_000)
    sink = FakeSink(clock, SR, BLOCK)
    events: list[object] = []
    with Player(sink, events.append, agent_id="ada", clock=clock, tts=tts) as player:
        player.say_text("t1", text)
        for _ in range(2000):
            if player.idle:
                break
            sink.advance(1)
        assert player.idle
    return events, sink.output


def lifecycle(events: list[object]) -> list[str]:
    return [type(e).__name__ for e in events if isinstance(e, PlayerStarted | PlayerFinished | PlayerFailed)]


def test_the_text_is_spoken_through_the_engine_and_ends_once() -> None:
    tts = ToneSpeech()
    events, played = play(tts, "Hello there.")
    assert tts.texts == ["Hello there."]
    assert lifecycle(events) == ["PlayerStarted", "PlayerFinished"]
    finished = [e for e in events if isinstance(e, PlayerFinished)][0]
    assert finished.played_s == pytest.approx(0.3, abs=0.002)
    assert np.sqrt(np.mean(played ** 2)) > 0.05


@pytest.mark.parametrize("tts, words", [
    (BrokenSpeech(), "the text could not be spoken: broken: the voice model is missing"),
    (None, "no text-to-speech engine is set up"),
    (engine(EngineSettings(engine="command", command=("no-such-tts-program", "--voice", "{voice}"))),
     "the program 'no-such-tts-program' is not installed"),
    (engine(EngineSettings(engine="command", command=("sleep", "10"), timeout_s=1.0)), "no speech within 1 s"),
    (engine(EngineSettings(engine="command", command=("echo", "not a wav"))), "is not a WAV file"),
])
def test_an_engine_that_cannot_speak_fails_the_request_with_its_reason(tts: object, words: str) -> None:
    events, _ = play(tts)
    assert lifecycle(events) == ["PlayerFailed"]
    assert words in [e for e in events if isinstance(e, PlayerFailed)][0].reason


def test_espeak_through_the_command_engine_speaks_too() -> None:
    """The command engine takes any program that reads text and writes a WAV: here espeak-ng itself."""
    samples, rate = engine(EngineSettings(engine="command", command=("espeak-ng", "-v", "{voice}", "-s", "{rate}",
                                                                     "--stdout", "--stdin"))).speak("Testing.")
    assert rate > 8000 and len(samples) / rate > 0.3 and np.abs(samples).max() > 0.1


@pytest.mark.parametrize("table, words", [
    ({"engine": "festival"}, "engine must be"),
    ({"engine": "command"}, "needs command"),
    ({"words_per_minute": 5}, "words_per_minute"),
    ({"voice": "en; rm -rf /"}, "is not a voice name"),
    ({"colour": "blue"}, "unknown keys"),
])
def test_bad_engine_settings_are_refused_naming_the_key(table: dict[str, object], words: str) -> None:
    with pytest.raises(ValueError, match=words):
        EngineSettings.from_table(table)
