"""A speech behaviour's words and sync marks, in every dialect in use, as plain text and as SSML.

Marks: BML 1.0's `<sync id/>` inside `<text>`, SSML's `<mark name/>` (SmartBody, and a `<description
type="application/ssml+xml">`), Greta's `<tm id/>`. SmartBody may put the words straight inside `<speech>`.
The SSML keeps only the words and the marks (no prosody): what espeak-ng -m and other SSML engines read, with
each mark reported back by name when it is spoken.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import NoReturn
from xml.sax.saxutils import escape

from eca.agent.bml.model import CORE_NAMESPACES, MAX_MARKS, SpeechParams, XmlElement, is_id

SSML_TYPE = "application/ssml+xml"
RESERVED_MARKS = frozenset({"start", "end"})  # the speech's own sync points
_WHITESPACE = re.compile(r"\s+")
# A reference reads a trailing "-2" or "+0.5" as an offset, so a mark named like that could never be referred to.
_LOOKS_LIKE_OFFSET = re.compile(r".*[+-][0-9.]+")

Fail = Callable[[XmlElement, str], NoReturn]


@dataclass(frozen=True)
class Mark:
    id: str


def speech_params(speech: XmlElement, audio_path: str | None, fail: Fail) -> SpeechParams:
    """The words and marks of one <speech> element; `fail` refuses the block at an element's position."""
    texts = [child for child in speech.elements() if child.name == "text" and child.namespace in CORE_NAMESPACES]
    pieces: list[str | Mark] = []
    for holder in texts or [speech]:  # SmartBody: the words straight inside <speech>
        _collect(holder, pieces, fail)
    if not _has_content(pieces):
        ssml = _ssml_description(speech)
        if ssml is not None:
            pieces = []
            _collect(ssml, pieces, fail)
    marks = tuple(piece.id for piece in pieces if isinstance(piece, Mark))
    if len(marks) > MAX_MARKS:
        fail(speech, f"a speech holds at most {MAX_MARKS} sync marks, this one {len(marks)}")
    text = _collapse("".join(piece for piece in pieces if isinstance(piece, str)))
    if not text and audio_path is None:
        fail(speech, "speech has no words (and no eca:audio file)")
    body = "".join(escape(piece) if isinstance(piece, str) else f'<mark name="{piece.id}"/>' for piece in pieces)
    return SpeechParams(text, f"<speak>{_collapse(body)}</speak>", marks, audio_path)


def _collect(node: XmlElement, pieces: list[str | Mark], fail: Fail) -> None:
    for item in node.content:
        if isinstance(item, str):
            pieces.append(item)
            continue
        mark_attr = _mark_attribute(item)
        if mark_attr is not None:
            pieces.append(Mark(_mark_id(item, mark_attr, pieces, fail)))
        elif item.name == "break":
            pieces.append(" ")  # an SSML pause still separates two words
        elif item.name != "description":  # <description> is another form of the same speech, not more words
            _collect(item, pieces, fail)  # SSML's prosody, emphasis, s, p, say-as: their words count


def _mark_attribute(element: XmlElement) -> str | None:
    if element.name == "sync" and element.namespace in CORE_NAMESPACES:
        return "id"
    if element.name == "mark":
        return "name"
    if element.name == "tm":  # Greta's time marker
        return "id"
    return None


def _mark_id(element: XmlElement, attribute: str, pieces: list[str | Mark], fail: Fail) -> str:
    mark = (element.attr(attribute) or "").strip()
    if not mark:
        fail(element, f"<{element.tag}> needs the attribute '{attribute}'")
    if not is_id(mark):
        fail(element, f"sync mark '{mark[:64]}' is not an id (letters, digits, '_', '.', '-'; at most 64)")
    if mark in RESERVED_MARKS:
        fail(element, f"sync mark '{mark}' would hide the speech's own {mark}")
    if _LOOKS_LIKE_OFFSET.fullmatch(mark):
        fail(element, f"sync mark '{mark}' ends like an offset (+/- seconds), so no reference could name it")
    if any(isinstance(piece, Mark) and piece.id == mark for piece in pieces):
        fail(element, f"sync mark '{mark}' appears twice in this speech")
    return mark


def _ssml_description(speech: XmlElement) -> XmlElement | None:
    """The SSML <description> of highest priority (the first of equal ones), if any."""
    best: tuple[int, XmlElement] | None = None
    for child in speech.elements():
        if child.name != "description" or (child.attr("type") or "").strip() != SSML_TYPE:
            continue
        priority_text = (child.attr("priority") or "0").strip()
        priority = int(priority_text) if priority_text.isdigit() and len(priority_text) < 7 else 0
        if best is None or priority > best[0]:
            best = (priority, child)
    return best[1] if best else None


def _has_content(pieces: list[str | Mark]) -> bool:
    return any(isinstance(piece, Mark) or piece.strip() for piece in pieces)


def _collapse(text: str) -> str:
    return _WHITESPACE.sub(" ", text).strip()
