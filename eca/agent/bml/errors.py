"""What a BML block can go wrong with: one error that refuses the whole block, or warnings that drop a part.

The warning types are the BML 1.0 standard's `warningFeedback` types, so a realizer can send either straight
back to the sender (feedback.py). Lines and columns count from 1, as in script errors; 0 means unknown.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

# The standard's warningFeedback types (BML 1.0 "Feedback"; OpenBMLParser BMLWarningFeedback).
PARSING_FAILURE = "PARSING_FAILURE"
NO_SUCH_TARGET = "NO_SUCH_TARGET"
IMPOSSIBLE_TO_SCHEDULE = "IMPOSSIBLE_TO_SCHEDULE"
BEHAVIOR_TYPE_NOT_SUPPORTED = "BEHAVIOR_TYPE_NOT_SUPPORTED"
CUSTOM_BEHAVIOUR_NOT_SUPPORTED = "CUSTOM_BEHAVIOUR_NOT_SUPPORTED"
CUSTOM_ATTRIBUTE_NOT_SUPPORTED = "CUSTOM_ATTRIBUTE_NOT_SUPPORTED"
CANNOT_CREATE_BEHAVIOR = "CANNOT_CREATE_BEHAVIOR"

WARNING_TYPES: tuple[str, ...] = (
    PARSING_FAILURE,
    NO_SUCH_TARGET,
    IMPOSSIBLE_TO_SCHEDULE,
    BEHAVIOR_TYPE_NOT_SUPPORTED,
    CUSTOM_BEHAVIOUR_NOT_SUPPORTED,
    CUSTOM_ATTRIBUTE_NOT_SUPPORTED,
    CANNOT_CREATE_BEHAVIOR,
)


class BmlError(Exception):
    """One problem that refuses the whole block.

    `str()` reads `name:line:column: block 'b1', behaviour 'h1': message`; the parts that are unknown (line 0,
    column 0, an empty block or behaviour) are left out, so a message never shows a made-up position.
    """

    def __init__(
        self,
        message: str,
        *,
        name: str = "bml",
        line: int = 0,
        column: int = 0,
        block: str = "",
        behaviour: str = "",
        warning_type: str = PARSING_FAILURE,
    ) -> None:
        self.message = message
        self.name = name
        self.line = int(line)
        self.column = int(column)
        self.block = block
        self.behaviour = behaviour
        self.warning_type = warning_type
        super().__init__(self._text())

    def _text(self) -> str:
        where = self.name
        if self.line > 0:
            where += f":{self.line}"
            if self.column > 0:
                where += f":{self.column}"
        subject = []
        if self.block:
            subject.append(f"block '{self.block}'")
        if self.behaviour:
            subject.append(f"behaviour '{self.behaviour}'")
        about = ", ".join(subject) + ": " if subject else ""
        return f"{where}: {about}{self.message}"

    def __str__(self) -> str:
        return self._text()

    def __reduce__(self) -> tuple[Any, ...]:
        # keyword-only arguments: rebuild through the state, so the error crosses process pools intact
        return (_rebuild, (self.message, dict(self.__dict__)))


def _rebuild(message: str, state: dict[str, Any]) -> BmlError:
    error = BmlError(message)
    error.__dict__.update(state)
    return error


@dataclass(frozen=True)
class BmlWarning:
    """A part of the block that will not be performed (or an attribute that is ignored); the rest runs."""

    type: str  # one of WARNING_TYPES
    block: str
    behaviour: str  # "" when the warning is about no behaviour in particular
    line: int
    text: str  # names the element or behaviour and the line, for a person reading a log
