"""Whole-bus recordings: a compact msgpack log of [received_ns, topic, payload] after a header map.

Frames are stored as they travelled (payloads stay encoded), so a replay re-publishes exactly what
was seen, and a reader can decode any of it later with the protocol codec.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import msgpack

MAGIC = "eca-recording"
FORMAT_VERSION = 1


class RecordingError(ValueError):
    """A recording file that cannot be read; the message names the file and the record."""


@dataclass(frozen=True)
class Record:
    received_ns: int
    topic: bytes
    payload: bytes


class RecordingWriter:
    def __init__(self, path: Path, instance: str, started_ns: int) -> None:
        self.path = path
        self._fh: BinaryIO = open(path, "wb")  # noqa: SIM115 - closed in close()
        self._packer = msgpack.Packer(use_bin_type=True)
        self._fh.write(self._packer.pack({"magic": MAGIC, "version": FORMAT_VERSION, "instance": instance,
                                          "started_ns": started_ns}))
        self.count = 0

    def write(self, received_ns: int, topic: bytes, payload: bytes) -> None:
        self._fh.write(self._packer.pack([received_ns, topic, payload]))
        self.count += 1

    def close(self) -> None:
        self._fh.close()


def read_recording(path: Path) -> tuple[dict, list[Record]]:
    """The header and every record; raises RecordingError naming the file and record on any fault."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise RecordingError(f"{path}: {exc.strerror}") from None
    unpacker = msgpack.Unpacker(raw=False, strict_map_key=True, max_buffer_size=max(len(data), 1024))
    unpacker.feed(data)
    items: Iterator[object] = iter(unpacker)
    try:
        header = next(items)
    except StopIteration:
        raise RecordingError(f"{path}: empty file, not an eca recording") from None
    except Exception as exc:
        raise RecordingError(f"{path}: not an eca recording ({exc})") from None
    if not isinstance(header, dict) or header.get("magic") != MAGIC:
        raise RecordingError(f"{path}: not an eca recording (no '{MAGIC}' header)")
    if header.get("version") != FORMAT_VERSION:
        raise RecordingError(f"{path}: recording format {header.get('version')!r} is not {FORMAT_VERSION}")
    records: list[Record] = []
    index = 0
    while True:
        try:
            item = next(items)
        except StopIteration:
            break
        except Exception as exc:
            raise RecordingError(f"{path}: record {index} is damaged ({type(exc).__name__})") from None
        if (not isinstance(item, list) or len(item) != 3 or not isinstance(item[0], int)
                or not isinstance(item[1], bytes) or not isinstance(item[2], bytes)):
            raise RecordingError(f"{path}: record {index} is not [received_ns, topic, payload]")
        if records and item[0] < records[-1].received_ns:
            raise RecordingError(f"{path}: record {index} goes back in time")
        records.append(Record(item[0], item[1], item[2]))
        index += 1
    return header, records
