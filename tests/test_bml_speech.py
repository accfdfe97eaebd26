"""A BML speech voiced before its block is scheduled (services/processes/bml/speech.py): the marks' times are the
speech engine's own, in text order, within the voice; an engine without marks places them by characters; a given
audio file takes no marks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from eca.agent.bml import parse_block
from eca.services.processes.audio.tts import EngineSettings
from eca.services.processes.bml.speech import _mark_shares, voice

BML = "http://www.bml-initiative.org/bml/bml-1.0"


def speech(text: str, extra: str = ""):  # noqa: ANN201
    return parse_block(f'<bml xmlns="{BML}" xmlns:eca="urn:eca:bml:1.0" id="b"><speech id="s" {extra}>'
                       f"<text>{text}</text></speech></bml>").behaviours[0].params


def test_the_engines_marks_come_in_text_order_within_the_voice() -> None:
    audio = voice(speech('One two <sync id="a"/>three four five <sync id="b"/>six.'), EngineSettings())
    marks = audio.timing.marks
    assert 0.1 < marks["a"] < marks["b"] < audio.timing.duration_s and not audio.approximate_marks
    samples = np.frombuffer(audio.pcm or b"", "<i2")
    assert len(samples) / audio.sample_rate == pytest.approx(audio.timing.duration_s)


def test_marks_without_an_engines_timing_go_by_the_characters_before_them() -> None:
    shares = _mark_shares(speech('Hello <sync id="a"/>there &amp; you <sync id="b"/>end'))
    assert shares == pytest.approx({"a": 6 / 21, "b": 18 / 21})


def test_an_audio_file_gives_its_length_and_refuses_marks(tmp_path: Path) -> None:
    path = tmp_path / "v.wav"
    sf.write(path, np.zeros(8000, np.int16), 16000)
    audio = voice(speech("hi", f'eca:audio="{path}"'), EngineSettings())
    assert audio.audio_path == str(path.resolve()) and audio.timing.duration_s == pytest.approx(0.5)
    with pytest.raises(ValueError, match="cannot hold sync marks"):
        voice(speech('hi <sync id="a"/>there', f'eca:audio="{path}"'), EngineSettings())
    with pytest.raises(ValueError, match="cannot read the audio file"):
        voice(speech("hi", f'eca:audio="{tmp_path / "none.wav"}"'), EngineSettings())
