"""`AvatarError`: the one exception the avatar loader raises, for any file it cannot take.

Its message names the file and what is wrong with it ("head.glb: accessors[3] (meshes[0].primitives[0]
.attributes.POSITION): 4096 elements of 12 bytes run past bufferViews[1] (1024 bytes)"), so a person can fix the
file or pick another one. The loader's modules raise it without a file (`path` empty); `load_avatar` adds the file.
"""

from __future__ import annotations

from typing import Any


class AvatarError(ValueError):
    """A glTF/VRM file eca cannot load or drive: `path` (the file, when known) and `what` (the problem)."""

    def __init__(self, what: str, path: str = "") -> None:
        self.what = what
        self.path = path
        super().__init__(f"{path}: {what}" if path else what)

    def at(self, path: str) -> AvatarError:
        """The same problem, naming `path` (a nested file's own name is kept)."""
        return self if self.path else AvatarError(self.what, path)

    def __reduce__(self) -> tuple[type, tuple[Any, ...]]:
        # Picklable across process pools despite the custom signature.
        return (AvatarError, (self.what, self.path))


def show(value: object, limit: int = 60) -> str:
    """`repr(value)` cut to `limit` characters: messages quote what the file says, never all of it."""
    text = repr(value) if not isinstance(value, str) else repr(value[: limit + 1])
    return text if len(text) <= limit else text[: limit - 3] + "..."


def kind(value: object) -> str:
    """The JSON kind of a value, for "must be X, got Y" messages."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, int):
        return f"the integer {show(value)}"
    if isinstance(value, float):
        return f"the number {show(value)}"
    if isinstance(value, str):
        return f"the string {show(value)}"
    if isinstance(value, list):
        return f"a list of {len(value)}"
    if isinstance(value, dict):
        return "an object"
    return type(value).__name__
