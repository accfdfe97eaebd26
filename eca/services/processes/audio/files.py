"""Opening and reading sound files with errors a person can act on.

soundfile (libsndfile) reports most problems as "Error opening '...': Format not recognised." - an
empty file, a directory and a text file all read the same, and a missing file reads as "System error".
Here each problem is told apart before (agent.script.audiofile, shared with the scripts' checks) or
while libsndfile looks at the file, and reported as one plain sentence that names the file:
`AudioFileError`.
"""

from __future__ import annotations

import os

import numpy as np
import soundfile

from eca.agent.script.audiofile import AudioFileError, audio_file_problem

__all__ = ["AudioFileError", "MonoReader", "open_sound_file", "plain_cause", "read_sound_file"]

# Formats whose frame count libsndfile only estimates (from the bit rate), so a file that ends a
# little before it is no sign of damage.
_ESTIMATED_LENGTH_FORMATS = frozenset({"MP3"})


def plain_cause(exc: BaseException) -> str:
    """What soundfile says went wrong, on one line, without its "Error opening '<path>':" preamble or
    a Python class name."""
    text = getattr(exc, "error_string", None) or str(exc)
    text = " ".join(str(text).split())
    if text.startswith("Error opening ") and ": " in text:
        text = text.split(": ", 1)[1]
    text = text.removeprefix("Error : ").strip().rstrip(".")
    return text[:200] or "no reason given"


def open_sound_file(path: str | os.PathLike[str], max_seconds: float | None = None) -> soundfile.SoundFile:
    """Open a sound file for reading, or raise AudioFileError saying what is wrong with it: it is not
    there, is a directory (or not a regular file), cannot be read, is empty, is not a sound file
    libsndfile reads, holds no samples, or lasts longer than `max_seconds`."""
    name = os.fspath(path)
    problem = audio_file_problem(name)
    if problem is not None:
        raise AudioFileError(name, problem)
    try:
        fh = soundfile.SoundFile(name)
    except (soundfile.SoundFileError, RuntimeError, TypeError, ValueError) as exc:
        raise AudioFileError(name, f"is not a sound file soundfile can read: {plain_cause(exc)}") from None
    try:
        if fh.frames <= 0:
            raise AudioFileError(name, "holds no samples (its header announces none)")
        seconds = fh.frames / fh.samplerate
        if max_seconds is not None and seconds > max_seconds:
            raise AudioFileError(name, f"lasts {seconds:.1f} s, longer than the limit of {max_seconds:g} s")
    except BaseException:
        fh.close()
        raise
    return fh


class MonoReader:
    """Reads an open sound file in slices, as mono float32 at the file's rate.

    A decoding error, or a file that ends before the length its header announced (cut short while it
    plays), raises AudioFileError saying how far it got.
    """

    def __init__(self, fh: soundfile.SoundFile, path: str | os.PathLike[str]) -> None:
        self.fh = fh
        self.path = os.fspath(path)
        self.sample_rate = int(fh.samplerate)
        self.frames = int(fh.frames)  # as announced when the file was opened
        self.position = 0

    @property
    def done(self) -> bool:
        return self.position >= self.frames

    def read(self, max_frames: int) -> np.ndarray:
        """Up to `max_frames` frames from the current position; empty once the file is done."""
        want = min(max_frames, self.frames - self.position)
        if want <= 0:
            return np.zeros(0, dtype=np.float32)
        try:
            block = self.fh.read(want, dtype="float32", always_2d=True)
        except (soundfile.SoundFileError, RuntimeError, OSError) as exc:
            raise AudioFileError(self.path, f"could not be decoded after {self._at()}: {plain_cause(exc)}") from None
        if len(block) == 0:
            if self.fh.format in _ESTIMATED_LENGTH_FORMATS:
                self.frames = self.position
                return np.zeros(0, dtype=np.float32)
            raise AudioFileError(self.path, f"ended after {self._at()} of the {self.frames / self.sample_rate:.1f} s "
                                 "its header announces (it was cut short or changed while it played)")
        self.position += len(block)
        mono = block[:, 0] if block.shape[1] == 1 else block.mean(axis=1, dtype=np.float32)
        return np.ascontiguousarray(mono, dtype=np.float32)

    def _at(self) -> str:
        return f"{self.position / self.sample_rate:.1f} s"

    def close(self) -> None:
        self.fh.close()


def read_sound_file(path: str | os.PathLike[str], max_seconds: float | None = None,
                    slice_frames: int = 1 << 16) -> tuple[np.ndarray, int]:
    """The whole file as mono float32, and its sample rate; AudioFileError on any problem."""
    reader = MonoReader(open_sound_file(path, max_seconds), path)
    try:
        pieces = []
        while not reader.done:
            piece = reader.read(slice_frames)
            if len(piece) == 0:
                break
            pieces.append(piece)
    finally:
        reader.close()
    return (np.concatenate(pieces) if pieces else np.zeros(0, dtype=np.float32)), reader.sample_rate
