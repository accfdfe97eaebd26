"""The file around a glTF document: a GLB's header and chunks, or a .gltf's JSON, and the external files and data
URIs its buffers and images name.

Everything here is checked before it is followed: the file's size before it is read, a GLB's header (magic,
version 2, total length equal to the file's) and each chunk's length before it is sliced, the JSON's size before
it is parsed and its depth and value count before anything walks it (non-finite numbers refused while parsing),
a data URI's decoded size before it is decoded, and an external file's path (inside the model's folder, a
regular file, not a device that never ends) and size before it is read. All files read together stay within
`max_file_bytes`.
"""

from __future__ import annotations

import base64
import binascii
import json
import math
import os
import re
import stat
import struct
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import unquote

from eca.services.processes.avatar.errors import AvatarError, show
from eca.services.processes.avatar.fields import JSON
from eca.services.processes.avatar.limits import AvatarLimits

GLB_MAGIC = b"glTF"
CHUNK_JSON = 0x4E4F534A
CHUNK_BIN = 0x004E4942
MAX_CHUNKS = 64  # a GLB has a JSON chunk, at most one BIN chunk, and rarely an extension's chunk or two
_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.\-]*:")


@dataclass
class Container:
    """A document's JSON (checked for size, depth and finite numbers), its GLB BIN chunk, and its folder."""

    document: dict[str, JSON]
    bin_chunk: memoryview | None
    folder: Path
    is_glb: bool
    budget: ReadBudget


@dataclass
class ReadBudget:
    """Bytes left to read from disk and data URIs for one model (the file counts first)."""

    left: int
    spent: list[str] = field(default_factory=list)

    def take(self, n: int, what: str) -> None:
        if n > self.left:
            raise AvatarError(f"{what} needs {n} bytes, more than the {self.left} bytes left of the file size "
                              "limit (max_file_bytes counts the model and every file it names)")
        self.left -= n


def read_container(path: Path, limits: AvatarLimits) -> Container:
    """The document of a .glb/.vrm (binary) or .gltf (JSON) file, by its first bytes rather than its name."""
    budget = ReadBudget(limits.max_file_bytes)
    data = read_regular_file(path, limits.max_file_bytes, "the file")
    budget.take(len(data), "the file")
    if data[:4] == GLB_MAGIC:
        json_chunk, bin_chunk = split_glb(memoryview(data))
        return Container(parse_json(json_chunk, limits, "the JSON chunk"), bin_chunk, path.parent, True, budget)
    head = data[:64].lstrip(b"\xef\xbb\xbf \t\r\n")
    if head[:1] == b"{":
        return Container(parse_json(memoryview(data), limits, "the glTF JSON"), None, path.parent, False, budget)
    raise AvatarError(f"neither a binary glTF (GLB files start with 'glTF', this one with {show(data[:4])}) nor "
                      "glTF JSON (a JSON object)")


def read_regular_file(path: Path, limit: int, what: str, prefix: bool = False) -> bytes:
    """At most `limit` bytes of a regular file, refused when bigger (checked before reading, and while reading);
    with `prefix`, a bigger file gives its first `limit` bytes instead (a buffer's file may be padded)."""
    try:
        info = os.stat(path)
    except OSError as error:
        raise AvatarError(f"cannot open {what}: {error.strerror or error}") from None
    if not stat.S_ISREG(info.st_mode):
        raise AvatarError(f"{what} is not a regular file")
    if info.st_size > limit and not prefix:
        raise AvatarError(f"{what} has {info.st_size} bytes, more than the limit of {limit} (max_file_bytes)")
    # read what the file says it holds (and one byte more, to see it grow): never a limit-sized buffer up front
    want = min(limit, info.st_size) if prefix else min(limit, info.st_size) + 1
    try:
        with open(path, "rb") as handle:
            data = handle.read(want)
    except OSError as error:
        raise AvatarError(f"cannot read {what}: {error.strerror or error}") from None
    if len(data) > limit:
        raise AvatarError(f"{what} grew past the limit of {limit} bytes while being read")
    return data


def split_glb(data: memoryview) -> tuple[memoryview, memoryview | None]:
    """A GLB's JSON chunk and its BIN chunk (None when it has none): glTF 2.0's binary container, with every
    length checked against the bytes there are."""
    if len(data) < 12:
        raise AvatarError(f"a GLB header is 12 bytes, the file has {len(data)}")
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    if magic != GLB_MAGIC:
        raise AvatarError(f"not a GLB file: it starts with {show(bytes(magic))}, not 'glTF'")
    if version != 2:
        raise AvatarError(f"GLB version {version}: eca reads version 2 (glTF 2.0)")
    if length != len(data):
        raise AvatarError(f"the GLB header says the file has {length} bytes, it has {len(data)}")
    offset, index = 12, 0
    json_chunk: memoryview | None = None
    bin_chunk: memoryview | None = None
    while offset < length:
        if index >= MAX_CHUNKS:
            raise AvatarError(f"more than {MAX_CHUNKS} GLB chunks")
        if length - offset < 8:
            raise AvatarError(f"GLB chunk {index} at byte {offset}: its 8-byte header is cut off")
        chunk_length, chunk_type = struct.unpack_from("<II", data, offset)
        start = offset + 8
        if chunk_length > length - start:
            raise AvatarError(f"GLB chunk {index} at byte {offset} claims {chunk_length} bytes, only "
                              f"{length - start} follow")
        chunk = data[start:start + chunk_length]
        if index == 0 and chunk_type != CHUNK_JSON:
            raise AvatarError(f"the first GLB chunk must be JSON, it is of type 0x{chunk_type:08x}")
        if chunk_type == CHUNK_JSON:
            if json_chunk is not None:
                raise AvatarError(f"GLB chunk {index} is a second JSON chunk")
            json_chunk = chunk
        elif chunk_type == CHUNK_BIN:
            if bin_chunk is not None:
                raise AvatarError(f"GLB chunk {index} is a second BIN chunk")
            bin_chunk = chunk
        offset = start + chunk_length  # other chunk types are skipped, as glTF says
        index += 1
    if json_chunk is None:
        raise AvatarError("the GLB has no chunks")
    return json_chunk, bin_chunk


class _NonFinite(ValueError):
    pass


def _refuse_constant(name: str) -> float:
    raise _NonFinite(f"the JSON holds {name}, which glTF numbers cannot be")


def _finite_float(text: str) -> float:
    number = float(text)
    if not math.isfinite(number):
        raise _NonFinite(f"the JSON number {show(text)} is too big for a float")
    return number


def parse_json(raw: memoryview, limits: AvatarLimits, what: str) -> dict[str, JSON]:
    """The document object of UTF-8 JSON bytes: refused when too big, not UTF-8, not JSON, holding non-finite
    numbers, not an object, nested deeper than `max_json_depth` or holding more than `max_json_values` values."""
    if len(raw) > limits.max_json_bytes:
        raise AvatarError(f"{what} has {len(raw)} bytes, more than the limit of {limits.max_json_bytes} "
                          "(max_json_bytes)")
    try:
        text = str(raw, "utf-8")
    except UnicodeDecodeError as error:
        raise AvatarError(f"{what} is not UTF-8 text (byte {error.start})") from None
    text = text.removeprefix("\ufeff")
    try:
        document = json.loads(text, parse_constant=_refuse_constant, parse_float=_finite_float)
    except _NonFinite as error:
        raise AvatarError(f"{what}: {error}") from None
    except RecursionError:
        raise AvatarError(f"{what} nests deeper than the limit of {limits.max_json_depth} (max_json_depth)") from None
    except ValueError as error:  # json.JSONDecodeError, and an integer of too many digits
        raise AvatarError(f"{what} is not valid JSON: {show(str(error), 120)}") from None
    if not isinstance(document, dict):
        raise AvatarError(f"{what} must be a JSON object, it is a {type(document).__name__}")
    check_json_shape(document, limits, what)
    return document


def check_json_shape(document: dict[str, JSON], limits: AvatarLimits, what: str) -> None:
    """Refuses a document nested deeper than max_json_depth or holding more than max_json_values values: walked
    without recursion, stopping at the first excess."""
    stack: list[tuple[JSON, int]] = [(document, 1)]
    count = 0
    while stack:
        value, depth = stack.pop()
        count += 1
        if count > limits.max_json_values:
            raise AvatarError(f"{what} holds more than {limits.max_json_values} values (max_json_values)")
        items: Iterable[JSON]
        if isinstance(value, dict):
            items = value.values()
        elif isinstance(value, list):
            items = value
        else:
            continue
        if depth >= limits.max_json_depth and len(value):
            raise AvatarError(f"{what} nests deeper than the limit of {limits.max_json_depth} (max_json_depth)")
        stack.extend((item, depth + 1) for item in items)


def read_uri(container: Container, uri: str, where: str, max_bytes: int, prefix: bool = False) -> bytes:
    """The bytes a buffer's or image's `uri` names: a base64 data URI, or a relative path inside the model's
    folder (percent-escapes decoded). At most `max_bytes` (with `prefix`, a longer file gives its first
    `max_bytes`), and within what is left of the read budget."""
    if uri.startswith("data:"):
        header, sep, payload = uri.partition(",")
        if not sep or not header.endswith(";base64"):
            raise AvatarError(f"{where}: a data URI must be base64 ('data:...;base64,...'), got {show(uri[:40])}")
        decoded_size = len(payload) * 3 // 4
        if decoded_size > max_bytes + 2 and not prefix:
            raise AvatarError(f"{where}: its data URI holds {decoded_size} bytes, more than the limit of {max_bytes}")
        container.budget.take(decoded_size, where)
        try:
            return base64.b64decode(payload, validate=True)
        except (binascii.Error, ValueError):
            raise AvatarError(f"{where}: its data URI is not valid base64") from None
    if _SCHEME.match(uri) or uri.startswith(("/", "\\")):
        raise AvatarError(f"{where}: uri {show(uri)} is neither a data URI nor a path relative to the model's file")
    relative = unquote(uri)
    if "\x00" in relative:
        raise AvatarError(f"{where}: uri {show(uri)} holds a NUL character")
    folder = container.folder.resolve()
    target = (folder / relative).resolve()
    if not target.is_relative_to(folder):
        raise AvatarError(f"{where}: uri {show(uri)} points outside the model's folder")
    if max_bytes > container.budget.left:
        container.budget.take(max_bytes, where)  # refuses, naming the budget
    data = read_regular_file(target, max_bytes, f"{where} ({show(uri)})", prefix)
    container.budget.take(len(data), where)
    return data
