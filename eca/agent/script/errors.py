"""The exceptions script and parameter file problems raise, with their positions.

`ScriptError` is one problem. The parsers collect every problem they can find and raise them together
as `ScriptErrors`, a ScriptError that reads like the first one (`file`, `line`, `column`, `message`)
for callers that want only that, and holds them all in `errors`.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any


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

    @property
    def errors(self) -> tuple[ScriptError, ...]:
        """Every problem this exception reports: here just itself."""
        return (self,)

    def __reduce__(self) -> tuple[type, tuple[Any, ...]]:
        # Keeps the error picklable across process pools despite the custom signature.
        return (ScriptError, (self.file, self.line, self.column, self.message))


class ScriptErrors(ScriptError):
    """Several problems at once; `str()` is one `file:line:column: message` line per problem.

    Its own file, line, column and message are those of the first problem.
    """

    def __init__(self, errors: Iterable[ScriptError]) -> None:
        unique: dict[tuple[str, int, int, str], ScriptError] = {}
        for error in errors:
            for one in error.errors:  # a ScriptErrors among them contributes its own list
                unique.setdefault((one.file, one.line, one.column, one.message), one)
        if not unique:
            raise ValueError("ScriptErrors needs at least one error")
        self._errors = tuple(unique.values())
        first = self._errors[0]
        super().__init__(first.file, first.line, first.column, first.message)

    @property
    def errors(self) -> tuple[ScriptError, ...]:
        return self._errors

    def __str__(self) -> str:
        return "\n".join(str(error.args[0]) for error in self._errors)

    def __reduce__(self) -> tuple[type, tuple[Any, ...]]:
        return (ScriptErrors, (self._errors,))


def in_file_order(errors: Iterable[ScriptError], first_file: str | None = None) -> list[ScriptError]:
    """The errors grouped by file (`first_file` first, then the others as they first appear), each
    file's in line, then column order; errors at one position keep the order they were found in."""
    flat = [one for error in errors for one in error.errors]
    files = list(dict.fromkeys([*([first_file] if first_file is not None else []), *(e.file for e in flat)]))
    rank = {name: i for i, name in enumerate(files)}
    return sorted(flat, key=lambda e: (rank[e.file], e.line, e.column))


def raise_collected(errors: list[ScriptError], first_file: str | None = None) -> None:
    """Raise every collected error at once, in file order; nothing when there are none."""
    if errors:
        raise ScriptErrors(in_file_order(errors, first_file))
