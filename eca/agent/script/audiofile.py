"""Audio files: what can be wrong with one before any decoder reads it, and a script's WAV measure.

Problems are worded to follow the file's name, so a script reports them as
`file:line:column: <turn>: audio 'x.wav' is empty (0 bytes)` and the audio service as
`audio file '/path/x.wav' is empty (0 bytes)`: one check and one error for both
(services/processes/audio/files.py adds what a decoder finds). Only WAV is measured here (stdlib); the service
layer passes a measuring hook that reads every format the audio service plays.
"""

from __future__ import annotations

import os
import stat
import wave
from pathlib import Path

MAX_SHOWN_PATH = 200  # characters of a path quoted in a message; longer ones keep their end


class AudioFileError(ValueError):
    """What is wrong with an audio file: `problem` completes `audio 'x.wav' ...` (never empty);
    `str()` names the file too, for callers that show it alone."""

    def __init__(self, path: str | os.PathLike[str], problem: str) -> None:
        self.path = os.fspath(path)
        self.problem = problem
        super().__init__(f"audio file {shown_path(self.path)} {problem}")

    def __reduce__(self) -> tuple[type, tuple[str, str]]:
        return (type(self), (self.path, self.problem))


class UnmeasurableAudio(AudioFileError):
    """A format this reader cannot measure (not a fault of the file): fine when a turn gives its duration."""


def shown_path(path: str | os.PathLike[str]) -> str:
    """The path quoted for a message: on one line, at most MAX_SHOWN_PATH characters (the end kept,
    since the file name is what tells files apart)."""
    text = "".join(c if c.isprintable() else "?" for c in os.fspath(path))
    if len(text) > MAX_SHOWN_PATH:
        text = "..." + text[-(MAX_SHOWN_PATH - 3):]
    return f"'{text}'"


def describe(exc: BaseException) -> str:
    """An exception's own words, or its type where it has none (EOFError from an empty file has none)."""
    text = str(exc).strip()
    return text or type(exc).__name__


def audio_file_problem(path: str | os.PathLike[str]) -> str | None:
    """Why `path` cannot be a sound file to play, before any decoder looks at it, or None: it is not
    there, is a directory or not a regular file (a pipe would block), is empty, or may not be read.
    Decoders tell these apart badly (libsndfile calls most of them "Format not recognised")."""
    name = os.fspath(path)
    try:
        info = os.stat(name)
    except FileNotFoundError:
        return "not found"
    except NotADirectoryError:
        return "not found (a directory in its path is a file)"
    except PermissionError:
        return "cannot be read: permission denied on a directory in its path"
    except (OSError, ValueError) as exc:  # a name too long for the OS, one holding a NUL
        return f"cannot be opened: {_os_reason(exc)}"
    if stat.S_ISDIR(info.st_mode):
        return "is a directory, not a sound file"
    if not stat.S_ISREG(info.st_mode):
        return "is not a regular file"
    if info.st_size == 0:
        return "is empty (0 bytes)"
    try:  # ask the OS itself: permission bits do not tell (root, ACLs)
        os.close(os.open(name, os.O_RDONLY))
    except PermissionError:
        return "cannot be read: permission denied"
    except OSError as exc:
        return f"cannot be opened: {_os_reason(exc)}"
    return None


def _os_reason(exc: BaseException) -> str:
    strerror = getattr(exc, "strerror", None)
    return strerror.lower() if strerror else describe(exc)


def wav_duration(path: Path) -> float:
    """Seconds of a WAV file (stdlib only); AudioFileError naming the cause when it cannot be read."""
    path = Path(path)
    if path.suffix.lower() not in (".wav", ".wave"):
        kind = f"{path.suffix} audio" if path.suffix else "audio without an extension"
        raise UnmeasurableAudio(path, f"is {kind}, which only the audio services can measure; use WAV or "
                                "give the turn a duration")
    problem = audio_file_problem(path)
    if problem is not None:
        raise AudioFileError(path, problem)
    try:
        with wave.open(str(path), "rb") as wav:
            frames, rate = wav.getnframes(), wav.getframerate()
    except (wave.Error, EOFError, OSError) as exc:
        raise AudioFileError(path, f"is not a WAV file Python's wave module can read: {describe(exc)}") from None
    if rate <= 0:
        raise AudioFileError(path, f"is not a WAV file Python's wave module can read: sample rate {rate}")
    return frames / float(rate)
