"""The dialogue service's current state on disk: the copy that outlives both the broker and the service.

The broker's last-value cache dies with the broker. A dialogue service killed while the broker was down
(or before it could publish its state again to a new broker) would come back with defaults. So the
state's owner writes each batch of changes to `<runtime dir>/state.msgpack` before it publishes them
(an acknowledged command is always on disk), atomically (a temporary file renamed over the old one),
and a starting service takes, topic by topic, the newer of this snapshot and the cache (by `t_ns`).

The file holds the encoded messages exactly as they were published, decoded again with the codec on
reading, and per agent the ids of the say requests that recently ended (so a successor never ends one
twice); a damaged or foreign file costs one warning, never the service. It belongs to the instance:
`eca up` removes it when it starts an instance afresh and when it stops one.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import msgpack

from eca.protocol.codec import ProtocolError, decode, packb
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import Message

SNAPSHOT_FILE = "state.msgpack"
MAX_SNAPSHOT_BYTES = 16 * 1024 * 1024
MAX_SNAPSHOT_ITEMS = 65_536


def snapshot_path(config: BusConfig) -> Path:
    return config.runtime_dir / SNAPSHOT_FILE


class StateSnapshot:
    def __init__(self, path: Path) -> None:
        self.path = path
        self._tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")

    def save(self, encoded: Iterable[bytes], ended: dict[str, list[str]]) -> None:
        """Write the state: its messages as published (encoded by the codec) and the ended request ids per agent."""
        data = packb({"messages": list(encoded), "ended": ended})
        with open(self._tmp, "wb") as fh:
            fh.write(data)
        os.replace(self._tmp, self.path)

    def load(self) -> tuple[list[Message], dict[str, list[str]], str | None]:
        """The messages the file holds, the ended request ids per agent, and what was wrong with the file
        (None when nothing was)."""
        try:
            size = self.path.stat().st_size
        except FileNotFoundError:
            return [], {}, None
        except OSError as exc:
            return [], {}, f"cannot read {self.path}: {exc.strerror}"
        if size > MAX_SNAPSHOT_BYTES:
            return [], {}, f"{self.path} is {size} bytes, over the limit of {MAX_SNAPSHOT_BYTES}: ignored"
        try:
            raw = msgpack.unpackb(self.path.read_bytes(), raw=False, max_array_len=MAX_SNAPSHOT_ITEMS,
                                  max_map_len=MAX_SNAPSHOT_ITEMS)
        except (OSError, ValueError) as exc:  # msgpack's errors are ValueErrors
            return [], {}, f"{self.path} is not a state snapshot ({type(exc).__name__}): ignored"
        if not _is_snapshot(raw):
            return [], {}, f"{self.path} is not a state snapshot (not the layout this version writes): ignored"
        messages: list[Message] = []
        problems = 0
        for item in raw["messages"]:
            try:
                messages.append(decode(item))
            except ProtocolError:
                problems += 1
        return messages, raw["ended"], (f"{problems} damaged message(s) skipped" if problems else None)

    def remove(self) -> None:
        self.path.unlink(missing_ok=True)


def _is_snapshot(raw: object) -> bool:
    if type(raw) is not dict or set(raw) != {"messages", "ended"}:
        return False
    messages, ended = raw["messages"], raw["ended"]
    return (type(messages) is list and all(type(m) is bytes for m in messages) and type(ended) is dict
            and all(type(k) is str and type(v) is list and all(type(i) is str for i in v) for k, v in ended.items()))
