"""Topic names: `<category>.<agent>.<type>`, so a SUB prefix selects a kind of message or one agent.

Categories: `cmd` (requests from clients), `state` (current state, kept by the broker's last-value
cache), `event` (things that happened), `stream` (continuous data), `play` (the dialogue service's
accepted requests for the audio service), `audio` (the audio service's raw lifecycle, re-published
once per request by the dialogue service as `event`), `sys` (heartbeats, broker replies) and
`error`. Examples: `state.` = every state, `state.ada.` = ada's state, `cmd.ada.say` = one kind.
"""

from __future__ import annotations

from eca.protocol.messages import Message

STATE_PREFIX = b"state."
CATEGORIES = ("cmd", "state", "event", "stream", "play", "audio", "sys", "error")


def topic_for(msg: Message, category: str | None = None) -> str:
    cat = category or msg.CATEGORY
    return f"{cat}.{msg.agent}.{msg.TYPE}"


def prefix(category: str, agent: str | None = None, type_name: str | None = None) -> str:
    """The subscription prefix for a category, optionally narrowed to one agent and one type."""
    if category not in CATEGORIES:
        raise ValueError(f"unknown topic category {category!r}; known: {', '.join(CATEGORIES)}")
    parts = [category]
    if agent is not None:
        parts.append(agent)
        if type_name is not None:
            parts.append(type_name)
    return ".".join(parts) + ("." if type_name is None else "")


def split_topic(topic: str) -> tuple[str, str, str]:
    """(category, agent, type) of a topic; raises ValueError for a topic not of that shape."""
    parts = topic.split(".")
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"topic {topic!r} is not <category>.<agent>.<type>")
    return parts[0], parts[1], parts[2]
