"""A small XML tree that remembers where each element starts, built on expat with DTDs refused.

xml.etree drops positions, which element-level errors need. Refusing every DOCTYPE (and so every
entity declaration) closes the entity-expansion and external-entity attacks at the source.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NoReturn
from xml.parsers import expat

from eca.agent.script.errors import ScriptError
from eca.agent.script.textfile import decode_text, position_of

MAX_DEPTH = 32


@dataclass
class Node:
    tag: str
    attrs: dict[str, str]
    line: int
    column: int
    children: list[Node] = field(default_factory=list)
    text: str = ""  # all character data directly inside, children's tails included

    def attr_names(self) -> set[str]:
        return set(self.attrs)


class _Refused(Exception):
    def __init__(self, line: int, column: int, message: str) -> None:
        super().__init__(message)
        self.line, self.column, self.message = line, column, message


def parse_xml(data: bytes, name: str) -> Node:
    """The root node of an XML document; ScriptError with the position of any problem."""
    decode_text(data, name)  # same empty/binary/size refusals as parameter files
    parser = expat.ParserCreate(encoding="UTF-8")
    parser.SetParamEntityParsing(expat.XML_PARAM_ENTITY_PARSING_NEVER)
    stack: list[Node] = []
    root: list[Node] = []

    def here() -> tuple[int, int]:
        return parser.CurrentLineNumber, parser.CurrentColumnNumber + 1

    def refuse(message: str) -> NoReturn:
        raise _Refused(*here(), message)

    def start(tag: str, attrs: dict[str, str]) -> None:
        if len(stack) >= MAX_DEPTH:
            refuse(f"elements nested deeper than {MAX_DEPTH}")
        node = Node(tag, dict(attrs), *here())
        if stack:
            stack[-1].children.append(node)
        else:
            root.append(node)
        stack.append(node)

    def end(tag: str) -> None:
        stack.pop()

    def chars(text: str) -> None:
        if stack:
            stack[-1].text += text

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = chars
    def doctype(*_: object) -> None:
        # expat reports the end of the declaration's opening; point at its first character instead
        at = data.find(b"<!DOCTYPE")
        where = position_of(data, at) if at >= 0 else here()
        raise _Refused(*where, "DOCTYPE declarations are not allowed")

    parser.StartDoctypeDeclHandler = doctype
    parser.EntityDeclHandler = lambda *a: refuse("entity declarations are not allowed")
    parser.ExternalEntityRefHandler = lambda *a: refuse("external entities are not allowed")
    try:
        parser.Parse(data, True)
    except _Refused as exc:
        raise ScriptError(name, exc.line, exc.column, exc.message) from None
    except expat.ExpatError as exc:
        message = expat.ErrorString(exc.code) if exc.code else str(exc)
        raise ScriptError(name, exc.lineno, exc.offset + 1, f"not well-formed XML: {message}") from None
    except (ValueError, RecursionError) as exc:
        raise ScriptError(name, 1, 1, f"unreadable XML: {exc}") from None
    if not root:
        raise ScriptError(name, 1, 1, "no root element")
    return root[0]
