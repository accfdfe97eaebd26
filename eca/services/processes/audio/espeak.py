"""Speech with phoneme timing from libespeak-ng, through ctypes (no Python binding needed).

The command-line `espeak-ng` prints phonemes but not when they occur (`--pho` needs an MBROLA voice);
the library reports a phoneme event with its sample position, which gives labelled speech for
validating lip-sync and a local voice for demos.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import threading
from dataclasses import dataclass

import numpy as np

_AUDIO_OUTPUT_SYNCHRONOUS = 2
_INITIALIZE_PHONEME_EVENTS = 0x0001
_POS_CHARACTER = 1
_EVENT_LIST_TERMINATED = 0
_EVENT_WORD = 1
_EVENT_MARK = 3
_EVENT_PHONEME = 7
_SSML = 0x10  # espeakSSML: the text is SSML (<speak>, <mark name/>, <break/>)


class _EventId(ctypes.Union):
    _fields_ = [("number", ctypes.c_int), ("name", ctypes.c_char_p), ("string", ctypes.c_char * 8)]


class _Event(ctypes.Structure):
    _fields_ = [
        ("type", ctypes.c_int),
        ("unique_identifier", ctypes.c_uint),
        ("text_position", ctypes.c_int),
        ("length", ctypes.c_int),
        ("audio_position", ctypes.c_int),
        ("sample", ctypes.c_int),
        ("user_data", ctypes.c_void_p),
        ("id", _EventId),
    ]


_Callback = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(ctypes.c_short), ctypes.c_int, ctypes.POINTER(_Event))


class EspeakUnavailable(RuntimeError):
    """libespeak-ng cannot be loaded or initialised."""


@dataclass(frozen=True, slots=True)
class Phoneme:
    name: str  # espeak mnemonic as printed by `espeak-ng -x`, e.g. "A:", "m", "s"
    start: int  # first sample of the phoneme


@dataclass(frozen=True, slots=True)
class Mark:
    name: str  # an SSML <mark name/>
    time_ms: int  # when the speech reaches it, from the first sample (the engine's own timing)


@dataclass(frozen=True, slots=True)
class Word:
    text_position: int  # first character of the word in the text, from 1
    time_ms: int  # when the word starts


@dataclass(frozen=True, slots=True)
class Speech:
    samples: np.ndarray  # float32 mono in [-1, 1]
    sample_rate: int
    phonemes: tuple[Phoneme, ...]
    marks: tuple[Mark, ...] = ()
    words: tuple[Word, ...] = ()


class _Engine:
    """libespeak-ng keeps global state: one initialised engine per process, used under a lock."""

    def __init__(self) -> None:
        name = ctypes.util.find_library("espeak-ng") or "libespeak-ng.so.1"
        try:
            self.lib = ctypes.CDLL(name)
        except OSError as exc:
            raise EspeakUnavailable(f"cannot load libespeak-ng ({exc})") from None
        self.lib.espeak_Synth.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_uint, ctypes.c_int,
                                          ctypes.c_uint, ctypes.c_uint, ctypes.c_void_p, ctypes.c_void_p]
        self.lib.espeak_SetVoiceByName.argtypes = [ctypes.c_char_p]
        self.sample_rate = int(self.lib.espeak_Initialize(_AUDIO_OUTPUT_SYNCHRONOUS, 0, None,
                                                          _INITIALIZE_PHONEME_EVENTS))
        if self.sample_rate <= 0:
            raise EspeakUnavailable("espeak_Initialize failed (espeak-ng-data missing?)")
        self._chunks: list[np.ndarray] = []
        self._phonemes: list[Phoneme] = []
        self._marks: list[Mark] = []
        self._words: list[Word] = []
        self._callback = _Callback(self._on_synth)  # kept alive: the library holds the pointer
        self.lib.espeak_SetSynthCallback(self._callback)
        self.lock = threading.Lock()

    def _on_synth(self, wav: ctypes.POINTER(ctypes.c_short), n: int, events: ctypes.POINTER(_Event)) -> int:
        i = 0
        while events[i].type != _EVENT_LIST_TERMINATED:
            ev = events[i]
            if ev.type == _EVENT_PHONEME:
                self._phonemes.append(Phoneme(ev.id.string.decode("ascii", "replace"), int(ev.sample)))
            elif ev.type == _EVENT_MARK and ev.id.name:
                self._marks.append(Mark(ev.id.name.decode("utf-8", "replace"), int(ev.audio_position)))
            elif ev.type == _EVENT_WORD:
                self._words.append(Word(int(ev.text_position), int(ev.audio_position)))
            i += 1
        if n > 0 and wav:
            self._chunks.append(np.ctypeslib.as_array(wav, shape=(n,)).astype(np.float32) / 32768.0)
        return 0

    def synth(self, text: str, voice: str, rate_wpm: int | None, pitch: int | None = None,
              ssml: bool = False) -> Speech:
        with self.lock:
            self._chunks, self._phonemes, self._marks, self._words = [], [], [], []
            if self.lib.espeak_SetVoiceByName(voice.encode()) != 0:
                raise EspeakUnavailable(f"espeak-ng has no voice {voice!r}")
            if rate_wpm is not None:
                self.lib.espeak_SetParameter(1, int(rate_wpm), 0)  # espeakRATE, absolute
            if pitch is not None:
                self.lib.espeak_SetParameter(3, int(pitch), 0)  # espeakPITCH, 0..100
            data = text.encode("utf-8")
            flags = _SSML if ssml else 0
            self.lib.espeak_Synth(data, len(data) + 1, 0, _POS_CHARACTER, 0, flags, None, None)
            self.lib.espeak_Synchronize()
            samples = np.concatenate(self._chunks) if self._chunks else np.zeros(0, np.float32)
            return Speech(samples, self.sample_rate, tuple(self._phonemes), tuple(self._marks), tuple(self._words))


_engine: _Engine | None = None
_engine_lock = threading.Lock()


def synthesize(text: str, voice: str = "en", rate_wpm: int | None = None, *, pitch: int | None = None,
               ssml: bool = False) -> Speech:
    """Speak `text` (SSML with `ssml`: its <mark name/>s come back with their times) into memory; raises
    EspeakUnavailable when libespeak-ng is not installed."""
    global _engine
    with _engine_lock:
        if _engine is None:
            _engine = _Engine()
    return _engine.synth(text, voice, rate_wpm, pitch, ssml)
