"""The wire bytes of every message type, pinned: a refactoring of the message definitions (how they are
declared, registered or shared) must leave what goes on the wire byte for byte as it was. A deliberate
change to the protocol regenerates the file: ECA_UPDATE_GOLDEN=1 pytest tests/test_protocol_golden_wire.py,
and the diff of tests/golden/wire_bytes.json shows exactly what changed."""

from __future__ import annotations

import json
import os
import types
import typing
from pathlib import Path
from typing import Any, Literal

from eca.protocol.codec import FieldSpec, decode, encode, field_specs
from eca.protocol.messages import ALL_AGENTS, ALL_MESSAGES, AgentsState, Message
from eca.protocol.topics import topic_for

GOLDEN = Path(__file__).parent / "golden" / "wire_bytes.json"


def _sample(name: str, kind: Any, spec: FieldSpec) -> Any:
    """A deterministic value of every field that is not its default: each field shows on the wire."""
    origin = typing.get_origin(kind)
    if origin in (typing.Union, types.UnionType):
        return _sample(name, next(k for k in typing.get_args(kind) if k is not type(None)), spec)
    if origin is Literal:
        return typing.get_args(kind)[-1]
    if origin is list:
        return [_sample(name, typing.get_args(kind)[0], spec)] * (spec.min_len or 1)
    if origin is dict:
        return {"say_ah": _sample(name, typing.get_args(kind)[1], spec)}
    if name == "agent":
        return "ada"
    if kind is bool:
        return True
    if kind is bytes:
        return b"\x01\x02\xfe"
    if kind is str:
        return f"{name}-x"[: spec.item_max_len or spec.max_len or 64]
    lo = spec.lo if spec.lo is not None else 0
    hi = spec.hi if spec.hi is not None else lo + 1000
    if kind is int:
        return int(lo + min(hi - lo, 1_000_003) // 3)
    return float(lo + (hi - lo) / 3)


def full(cls: type[Message]) -> Message:
    values = {s.name: _sample(s.name, s.kind, s) for s in field_specs(cls)}
    if cls.AGENT_SCOPE == "all":
        values["agent"] = ALL_AGENTS
    if cls is AgentsState:  # lists that agree: a configured agent, then a created one copying it
        values.update(agents=["agents-x", "created-x"], created=["created-x"], like=["agents-x"])
    return cls(**values)


def current() -> dict[str, dict[str, str]]:
    out = {}
    for cls in ALL_MESSAGES:
        msg = full(cls)
        out[cls.TYPE] = {"topic": topic_for(msg), "payload": encode(msg).hex()}
    return out


def test_every_message_type_encodes_to_its_pinned_bytes() -> None:
    got = current()
    if os.environ.get("ECA_UPDATE_GOLDEN"):
        GOLDEN.write_text(json.dumps(got, indent=1, sort_keys=True) + "\n")
    pinned = json.loads(GOLDEN.read_text())
    assert set(got) == set(pinned), "message types added or removed: regenerate the golden file deliberately"
    changed = [t for t in got if got[t] != pinned[t]]
    assert not changed, f"wire bytes changed for {changed}"


def test_the_pinned_bytes_decode_to_the_same_messages() -> None:
    pinned = json.loads(GOLDEN.read_text())
    for cls in ALL_MESSAGES:
        assert decode(bytes.fromhex(pinned[cls.TYPE]["payload"])) == full(cls), cls.TYPE
