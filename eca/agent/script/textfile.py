"""Turning a file's bytes into lines of text, refusing what is not text."""

from __future__ import annotations

from pathlib import Path

from eca.agent.script.errors import ScriptError

# Scripts are hand-written and small; a bound keeps a wrong path (a video, a disk image) from
# being read whole into memory before it is refused.
MAX_FILE_BYTES = 8 * 1024 * 1024


def position_of(data: bytes, offset: int) -> tuple[int, int]:
    """1-based (line, column) of byte `offset`, the column in characters of the valid prefix."""
    before = data[:offset]
    line = before.count(b"\n") + 1
    last = before.rfind(b"\n")
    column_bytes = before[last + 1 :]
    return line, len(column_bytes.decode("utf-8", errors="replace")) + 1


def decode_text(data: bytes, name: str) -> str:
    """The UTF-8 text of a file; ScriptError for empty, oversized and binary (NUL, not UTF-8) data."""
    if len(data) > MAX_FILE_BYTES:
        raise ScriptError(name, 1, 1, f"file is too large ({len(data)} bytes; at most {MAX_FILE_BYTES})")
    nul = data.find(b"\x00")
    if nul >= 0:
        line, column = position_of(data, nul)
        raise ScriptError(name, line, column, "binary file: NUL byte; scripts are UTF-8 text")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line, column = position_of(data, exc.start)
        raise ScriptError(name, line, column, "binary file: bytes are not UTF-8 text") from None
    text = text.removeprefix("\ufeff")
    if not text.strip():
        raise ScriptError(name, 1, 1, "empty file")
    return text


def split_lines(text: str) -> list[str]:
    """Lines split on LF only (CRLF tolerated): str.splitlines would also split on form feeds and
    Unicode separators and so disagree with an editor's line numbers."""
    return [line.removesuffix("\r") for line in text.split("\n")]


def read_bytes(path: str | Path) -> bytes:
    """A file's bytes, with ScriptError for a missing, unreadable or oversized file."""
    try:
        with open(path, "rb") as fh:
            data = fh.read(MAX_FILE_BYTES + 1)
    except FileNotFoundError:
        raise ScriptError(path, 1, 1, "file not found") from None
    except IsADirectoryError:
        raise ScriptError(path, 1, 1, "is a directory, not a file") from None
    except OSError as exc:
        raise ScriptError(path, 1, 1, f"cannot read file: {exc.strerror or exc}") from None
    return data
