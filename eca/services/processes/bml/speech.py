"""A BML speech behaviour's audio and the times of its sync marks, before the block is scheduled.

Text is voiced by libespeak-ng with the configured voice, rate and pitch ([tts] in configs/audio.toml), as SSML
whose <mark name/>s stand where the block's sync marks were: the engine reports when it reaches each, so the
marks' times are the voice's own. Another configured engine (a command) cannot report marks: its marks are
placed in proportion to the characters before them, and the realizer warns so. A given audio file has no
words: marks in its text are refused.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from xml.etree import ElementTree

import numpy as np
import soundfile as sf

from eca.agent.bml import SpeechParams, SpeechTiming
from eca.services.processes.audio.espeak import EspeakUnavailable, synthesize
from eca.services.processes.audio.tts import EngineSettings, SpeechSynthesisError
from eca.services.processes.audio.tts import engine as tts_engine

MAX_SPEECH_S = 120.0  # one behaviour's audio at most (a say holds at most what the audio service plays)


@dataclass(frozen=True)
class SpeechAudio:
    pcm: bytes | None  # mono int16 little-endian; None with a file
    sample_rate: int  # 0 with a file
    audio_path: str | None
    timing: SpeechTiming
    approximate_marks: bool  # placed by characters, not by the engine


def voice(params: SpeechParams, settings: EngineSettings) -> SpeechAudio:
    """The behaviour's audio and timing; ValueError naming what is wrong (no text, no engine, a bad file)."""
    if params.audio_path is not None:
        return _from_file(params)
    if not params.text.strip():
        raise ValueError("the speech has no text")
    if settings.engine == "espeak-ng":
        try:
            speech = synthesize(params.ssml, settings.voice, settings.words_per_minute, pitch=settings.pitch,
                                ssml=True)
        except EspeakUnavailable as exc:
            raise ValueError(f"the speech cannot be voiced: {exc}") from None
        samples, rate = speech.samples, speech.sample_rate
        marks = {m.name: m.time_ms / 1000.0 for m in speech.marks}
        approximate = False
    else:
        try:
            samples, rate = tts_engine(settings).speak(params.text)
        except SpeechSynthesisError as exc:
            raise ValueError(str(exc)) from None
        marks = {}
        approximate = bool(params.marks)
    duration = len(samples) / rate
    if duration > MAX_SPEECH_S:
        raise ValueError(f"the speech lasts {duration:.0f} s, more than {MAX_SPEECH_S:g} s")
    missing = [m for m in params.marks if m not in marks]
    if missing:  # a mark the engine skipped (or an engine without marks): by its place in the text
        for name, share in _mark_shares(params).items():
            marks.setdefault(name, share * duration)
    pcm = (np.clip(samples, -1.0, 1.0) * 32767.0).round().astype("<i2").tobytes()
    return SpeechAudio(pcm, rate, None, SpeechTiming(duration, marks), approximate)


def _from_file(params: SpeechParams) -> SpeechAudio:
    if params.marks:
        raise ValueError("a speech given as an audio file cannot hold sync marks (the file has no words)")
    path = Path(params.audio_path or "")
    try:
        info = sf.info(str(path))
    except Exception:  # soundfile raises its own error types for what it cannot read
        raise ValueError(f"cannot read the audio file {str(path)[:200]!r}") from None
    duration = info.frames / info.samplerate
    if duration > MAX_SPEECH_S:
        raise ValueError(f"the audio file lasts {duration:.0f} s, more than {MAX_SPEECH_S:g} s")
    return SpeechAudio(None, 0, str(path.resolve()), SpeechTiming(duration, {}), False)


def _mark_shares(params: SpeechParams) -> dict[str, float]:
    """Each mark's place in the speech as the share of the text's characters before it (the SSML is ours:
    agent/bml/speech_text.py writes it, escaped, with a <mark name/> at each sync mark)."""
    speak = ElementTree.fromstring(params.ssml)
    before: dict[str, int] = {}
    count = len(speak.text or "")
    for element in speak:
        if element.tag == "mark":
            before[element.get("name", "")] = count
        count += len(element.text or "") + len(element.tail or "")
    return {name: chars / max(1, count) for name, chars in before.items()}
