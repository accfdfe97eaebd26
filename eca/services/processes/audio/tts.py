"""Text to speech: what voices a `say` that has text and no audio, and the CLI's and the demo's speech.

An engine turns text into mono samples. Two kinds, chosen in configs/audio.toml `[tts]`:
- `espeak-ng` (the default): the `espeak-ng` program, with a voice, a rate in words per minute and a
  pitch;
- `command`: any program that reads the text on its standard input and writes a WAV file on its standard
  output (`{voice}`, `{rate}` and `{pitch}` in its arguments are filled in): a neural voice, a cloud
  client, another language's engine.
Each runs as its own process with a time limit, so an engine that crashes or hangs fails that one
request (with a reason saying which engine and why), never the audio service.
"""

from __future__ import annotations

import io
import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import soundfile as sf

from eca.services.processes.realtime import ordinary_children


class SpeechSynthesisError(RuntimeError):
    """The text could not be spoken: the message names the engine and the cause."""


class TextToSpeech(Protocol):
    name: str

    def speak(self, text: str) -> tuple[np.ndarray, int]:
        """`text` spoken: float32 mono samples in [-1, 1] and their rate. SpeechSynthesisError otherwise."""


@dataclass(frozen=True)
class EngineSettings:
    engine: str = "espeak-ng"  # or "command"
    voice: str = "en-us"
    words_per_minute: int = 160
    pitch: int = 50
    command: tuple[str, ...] = field(default=())  # for engine "command": argv, reads text, writes WAV
    timeout_s: float = 60.0

    def check(self, where: str = "[tts]") -> EngineSettings:
        if self.engine not in ("espeak-ng", "command"):
            raise ValueError(f"{where}: engine must be \"espeak-ng\" or \"command\", got {self.engine!r}")
        if self.engine == "command" and not self.command:
            raise ValueError(f"{where}: engine \"command\" needs command = [\"program\", \"arg\", ...]")
        if not 80 <= self.words_per_minute <= 450:
            raise ValueError(f"{where}: words_per_minute must lie in 80..450, got {self.words_per_minute}")
        if not 0 <= self.pitch <= 99:
            raise ValueError(f"{where}: pitch must lie in 0..99, got {self.pitch}")
        if not 1 <= self.timeout_s <= 600:
            raise ValueError(f"{where}: timeout_s must lie in [1, 600], got {self.timeout_s}")
        if not self.voice or not self.voice.replace("-", "").replace("+", "").replace("_", "").isalnum():
            raise ValueError(f"{where}: voice {self.voice!r} is not a voice name")
        return self

    @classmethod
    def from_table(cls, table: dict[str, Any], where: str = "[tts]") -> EngineSettings:
        known = {"engine", "voice", "words_per_minute", "pitch", "command", "timeout_s"}
        unknown = set(table) - known
        if unknown:
            raise ValueError(f"{where}: unknown keys {sorted(unknown)}; known: {', '.join(sorted(known))}")
        values = dict(table)
        if "command" in values:
            values["command"] = tuple(str(a) for a in values["command"])
        try:
            return cls(**values).check(where)
        except TypeError as exc:
            raise ValueError(f"{where}: {exc}") from None


class _Engine:
    """Runs one program per request; what it writes on standard output is a WAV file."""

    name = "text-to-speech"

    def __init__(self, settings: EngineSettings) -> None:
        self.settings = settings

    def argv(self) -> list[str]:
        raise NotImplementedError

    def speak(self, text: str) -> tuple[np.ndarray, int]:
        if not text.strip():
            raise SpeechSynthesisError("nothing to say: the text is empty")
        argv = self.argv()
        if shutil.which(argv[0]) is None:
            raise SpeechSynthesisError(f"{self.name}: the program {argv[0]!r} is not installed")
        ordinary_children()  # an engine may take a core for a second: never at the voice's real-time priority
        try:
            done = subprocess.run(argv, input=text.encode("utf-8"), capture_output=True,
                                  timeout=self.settings.timeout_s)
        except subprocess.TimeoutExpired:
            raise SpeechSynthesisError(f"{self.name}: no speech within {self.settings.timeout_s:g} s") from None
        except OSError as exc:
            raise SpeechSynthesisError(f"{self.name}: cannot run {argv[0]!r}: {exc.strerror}") from None
        if done.returncode != 0:
            cause = " ".join(done.stderr.decode("utf-8", "replace").split())[:200] or f"exit code {done.returncode}"
            raise SpeechSynthesisError(f"{self.name} failed: {cause}")
        try:
            samples, rate = sf.read(io.BytesIO(done.stdout), dtype="float32", always_2d=True)
        except Exception:  # soundfile raises its own error types for what is not a sound file
            raise SpeechSynthesisError(f"{self.name}: what it wrote is not a WAV file "
                                       f"({len(done.stdout)} bytes)") from None
        return samples.mean(axis=1).astype(np.float32, copy=False), int(rate)


class EspeakSpeech(_Engine):
    name = "espeak-ng"

    def argv(self) -> list[str]:
        s = self.settings
        # --stdin: the text never passes through the command line (length, leading dashes)
        return ["espeak-ng", "-v", s.voice, "-s", str(s.words_per_minute), "-p", str(s.pitch), "--stdout",
                "--stdin"]


class CommandSpeech(_Engine):
    def __init__(self, settings: EngineSettings) -> None:
        super().__init__(settings)
        self.name = f"text-to-speech command {settings.command[0]!r}"

    def argv(self) -> list[str]:
        s = self.settings
        fill = {"voice": s.voice, "rate": str(s.words_per_minute), "pitch": str(s.pitch)}
        return [arg.format(**fill) for arg in s.command]


def engine(settings: EngineSettings | None = None) -> TextToSpeech:
    settings = (settings or EngineSettings()).check()
    return EspeakSpeech(settings) if settings.engine == "espeak-ng" else CommandSpeech(settings)


def espeak_available() -> bool:
    return shutil.which("espeak-ng") is not None


def synthesize(text: str, out_path: Path, voice: str = "en-us", words_per_minute: int = 160,
               pitch: int = 50) -> Path:
    """Write `text` spoken by espeak-ng to a WAV file and return its path (the demo's and scripts' voices)."""
    samples, rate = EspeakSpeech(EngineSettings(voice=voice, words_per_minute=words_per_minute,
                                                pitch=pitch)).speak(text)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    sf.write(out_path, samples, rate)
    return out_path
