"""Text to speech with espeak-ng, for the CLI, the demo and tests (the product takes any audio)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path


class SpeechSynthesisError(RuntimeError):
    pass


def espeak_available() -> bool:
    return shutil.which("espeak-ng") is not None


def synthesize(text: str, out_path: Path, voice: str = "en-us", words_per_minute: int = 160,
               pitch: int = 50) -> Path:
    """Write `text` spoken by espeak-ng to a WAV file (22,050 Hz mono) and return its path."""
    if not espeak_available():
        raise SpeechSynthesisError("espeak-ng is not installed (Debian: apt-get install espeak-ng)")
    if not text.strip():
        raise SpeechSynthesisError("nothing to say: the text is empty")
    out_path.parent.mkdir(parents=True, exist_ok=True)
    argv = ["espeak-ng", "-v", voice, "-s", str(words_per_minute), "-p", str(pitch), "-w", str(out_path), "--",
            text]
    done = subprocess.run(argv, capture_output=True, timeout=60)
    if done.returncode != 0 or not out_path.exists():
        raise SpeechSynthesisError(f"espeak-ng failed: {done.stderr.decode(errors='replace').strip()}")
    return out_path
