"""The one exception every script and parameter file problem raises, with its position."""

from __future__ import annotations

from pathlib import Path


class ScriptError(ValueError):
    """A script or parameter file is wrong; `str()` reads `file:line:column: message`.

    Lines and columns count from 1 (the convention of compilers and editors, so a terminal can jump
    there); column counts characters, not bytes.
    """

    def __init__(self, file: str | Path, line: int, column: int, message: str) -> None:
        self.file = str(file)
        self.line = int(line)
        self.column = int(column)
        self.message = message
        super().__init__(f"{self.file}:{self.line}:{self.column}: {message}")

    def __reduce__(self) -> tuple[type[ScriptError], tuple[str, int, int, str]]:
        # Keeps the error picklable across process pools despite the custom signature.
        return (ScriptError, (self.file, self.line, self.column, self.message))
