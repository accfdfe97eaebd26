"""The codec: every message type round-trips, and malformed input only ever raises `ProtocolError`.

Valid messages are built by hypothesis strategies derived from `field_specs`, so a new message type
or field is covered without touching this file. Targeted mutations of valid messages check that the
error names the right kind and field; untargeted fuzzing (random bytes, random msgpack values, random
maps shaped like messages) checks that nothing but `ProtocolError` escapes `decode`.
"""

from __future__ import annotations

import dataclasses
import math
import re
import types
import typing
from pathlib import Path
from typing import Any, Literal

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from eca.protocol.bus import Publisher, Subscriber, parse_frames
from eca.protocol.codec import (
    DEFAULT_MAX_BYTES,
    PACK_BUFFER_BYTES,
    FieldSpec,
    ProtocolError,
    decode,
    encode,
    field_specs,
    packb,
)
from eca.protocol.messages import (
    ALL_AGENTS,
    ALL_MESSAGES,
    MESSAGE_TYPES,
    PROTOCOL_VERSION,
    AgentsState,
    ClockAnchor,
    EmotionState,
    Error,
    Expression,
    EyeStates,
    FaceFrame,
    Message,
    MouthKeys,
    PlaybackState,
    Say,
    SetEmotion,
    SpeechState,
)
from eca.protocol.topics import topic_for
from tests.support.bus import BrokerThread, private_bus_config

ENVELOPE = tuple(f.name for f in dataclasses.fields(Message))
DOC = Path(__file__).resolve().parent.parent / "docs" / "protocol.md"
FAST = settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
ERROR_KINDS = {"inconsistent", "not_msgpack", "wrong_type", "unknown_version", "unknown_type", "extra_field",
               "missing_field", "not_finite", "out_of_range", "oversize"}

# --- strategies derived from the field specs ------------------------------------------------------

ONE_AGENT = st.from_regex(r"\A[A-Za-z0-9_-]{1,32}\Z")
AGENT_IDS = st.one_of(st.just(ALL_AGENTS), ONE_AGENT)
KEYS = st.text(min_size=1, max_size=12)


def agent_ids(cls: type[Message]) -> st.SearchStrategy[str]:
    """The agent ids a type takes (its AGENT_SCOPE): one agent, only '*', or either."""
    return {"one": ONE_AGENT, "all": st.just(ALL_AGENTS), "any": AGENT_IDS}[cls.AGENT_SCOPE]


def an_agent_of(cls: type[Message]) -> str:
    return ALL_AGENTS if cls.AGENT_SCOPE == "all" else "ada"


def _optional_inner(kind: Any) -> Any | None:
    """The inner annotation of `X | None`, or None when `kind` is not optional."""
    if typing.get_origin(kind) in (types.UnionType, typing.Union) and type(None) in typing.get_args(kind):
        return next(a for a in typing.get_args(kind) if a is not type(None))
    return None


def _scalar(spec: FieldSpec, kind: Any) -> st.SearchStrategy[Any]:
    if kind is bool:
        return st.booleans()
    if kind is int:
        return st.integers(int(spec.lo) if spec.lo is not None else -(2**63),
                           int(spec.hi) if spec.hi is not None else 2**63 - 1)
    if kind is float:
        return st.floats(spec.lo, spec.hi, allow_nan=False, allow_infinity=False)
    if kind is str:
        return st.text(max_size=min(spec.max_len or 40, 40))
    if kind is bytes:
        return st.binary(max_size=64)
    raise AssertionError(f"no strategy for {kind!r}")


def value_strategy(spec: FieldSpec, kind: Any | None = None) -> st.SearchStrategy[Any]:
    kind = spec.kind if kind is None else kind
    if spec.name == "agent":
        return AGENT_IDS
    inner = _optional_inner(kind)
    if inner is not None:
        return st.none() | value_strategy(spec, inner)
    origin = typing.get_origin(kind)
    if origin is Literal:
        return st.sampled_from(typing.get_args(kind))
    size = min(spec.max_len or 8, 8)
    if origin is list:
        item = typing.get_args(kind)[0]
        fewest = spec.min_len or 0  # a list of a fixed length (a rig frame's weights) has exactly that many
        if typing.get_origin(item) is Literal:
            return st.lists(st.sampled_from(typing.get_args(item)), min_size=fewest, max_size=max(size, fewest))
        return st.lists(_scalar(dataclasses.replace(spec, max_len=spec.item_max_len), item), min_size=fewest,
                        max_size=max(size, fewest))
    if origin is dict:
        item = typing.get_args(kind)[1]
        if typing.get_origin(item) is list:
            values: st.SearchStrategy[Any] = st.lists(_scalar(spec, typing.get_args(item)[0]), max_size=4)
        else:
            values = _scalar(spec, item)
        return st.dictionaries(KEYS, values, max_size=size)
    return _scalar(spec, kind)


@st.composite
def messages(draw: st.DrawFn, cls: type[Message] | None = None) -> Message:
    """A valid instance of `cls` (or of any type); optional fields are sometimes left at their default."""
    cls = cls or draw(st.sampled_from(ALL_MESSAGES))
    values = {}
    for spec in field_specs(cls):
        if spec.required or draw(st.booleans()):
            values[spec.name] = draw(agent_ids(cls) if spec.name == "agent" else value_strategy(spec))
    if cls is AgentsState:  # distinct agents; the created ones last, each copying a configured one
        agents = list(dict.fromkeys(draw(st.lists(ONE_AGENT, max_size=8))))
        configured = draw(st.integers(min(1, len(agents)), len(agents)))
        values["agents"], values["created"] = agents, agents[configured:]
        values["like"] = [draw(st.sampled_from(agents[:configured])) for _ in agents[configured:]]
    if cls is EyeStates:  # distinct agents (the other lists follow them below)
        values["agents"] = list(dict.fromkeys(draw(st.lists(ONE_AGENT, max_size=8))))
    if cls is Expression:  # its times in order, or the message is inconsistent
        times = sorted(values.get(k, 0) for k in ("onset_ns", "peak_ns", "relax_ns", "end_ns"))
        values.update(zip(("onset_ns", "peak_ns", "relax_ns", "end_ns"), times, strict=True))
    if cls is MouthKeys:  # one weight per sample position, or the message is inconsistent
        n = len(values.get("sample_index", []))
        values["weights"] = {k: (v * n)[:n] if v else [0.0] * n for k, v in values.get("weights", {}).items()}
    for key, parallel in PARALLEL_LISTS.get(cls, ()):  # one entry per request id, each id non-empty and once
        ids = list(dict.fromkeys(i for i in values.get(key, []) if i))
        values[key] = ids
        for spec in field_specs(cls):
            if spec.name in parallel:
                item = typing.get_args(spec.kind)[0]
                default = typing.get_args(item)[0] if typing.get_origin(item) is Literal else item()
                drawn = values.get(spec.name) or [default]  # False, 0, "" or the first choice
                values[spec.name] = (drawn * len(ids))[: len(ids)]
    if cls is PlaybackState:
        values["request_ids"] = [i for i in values.get("request_ids", []) if i]
    return cls(**values)


# Message types whose lists run in parallel: a list of ids, and the lists with one entry per id.
ENDINGS = ("ended_ids", ("ended_as", "ended_played_s", "ended_reasons"))
PARALLEL_LISTS: dict[type[Message], tuple[tuple[str, tuple[str, ...]], ...]] = {
    SpeechState: (("request_ids", ("streamed", "next_chunk", "chunks_done", "started", "audio_started_ns")),
                  ENDINGS),
    PlaybackState: (ENDINGS,),
    EyeStates: (("agents", ("yaw_deg", "pitch_deg", "lid", "mode")),),
}


def test_mouth_keys_whose_lists_disagree_are_inconsistent() -> None:
    raw = wire(MouthKeys(agent="ada", request_id="r", sample_rate=100, sample_index=[0, 10],
                         weights={"say_ah": [0.1, 0.2]}))
    raw["weights"] = {"say_ah": [0.1]}
    err = rejection(raw)
    assert (err.kind, err.field) == ("inconsistent", "weights.say_ah")
    with pytest.raises(ProtocolError, match="1 values for 2 sample positions"):
        encode(MouthKeys(agent="ada", request_id="r", sample_rate=100, sample_index=[0, 10],
                         weights={"say_ah": [0.1]}))


def wire(msg: Message) -> dict[str, Any]:
    """The msgpack map of a message, to mutate."""
    return msgpack.unpackb(encode(msg), raw=False)


def pack(raw: Any) -> bytes:
    return msgpack.packb(raw, use_bin_type=True)


def rejection(raw: Any, max_bytes: int = DEFAULT_MAX_BYTES) -> ProtocolError:
    data = raw if isinstance(raw, bytes) else pack(raw)
    with pytest.raises(ProtocolError) as info:
        decode(data, max_bytes)
    return info.value


def minimal(cls: type[Message]) -> Message:
    """A valid instance built from the smallest legal value of every required field."""
    values = {s.name: _smallest(s) for s in field_specs(cls) if s.required}
    values["agent"] = an_agent_of(cls)
    return cls(**values)


def _smallest(spec: FieldSpec) -> Any:
    if spec.name == "agent":
        return "ada"
    kind = spec.kind
    origin = typing.get_origin(kind)
    if origin is Literal:
        return typing.get_args(kind)[0]
    if origin is list:  # a required list is one of a fixed length: that many of the item's smallest value
        item = typing.get_args(kind)[0]
        return [item(spec.lo if spec.lo is not None else 0)] * (spec.min_len or 0)
    if kind in (int, float):
        return kind(spec.lo if spec.lo is not None else 0)
    return {str: "r1", bytes: b"\x00\x01", bool: False}[kind]


# --- coverage of the message list itself --------------------------------------------------------


def _subclasses(cls: type) -> set[type]:
    out = set()
    for sub in cls.__subclasses__():
        out |= {sub} | _subclasses(sub)
    return out


def test_every_message_class_is_registered_once_under_a_unique_type() -> None:
    # a class without a type is a shared base of fields (SpeechEndings), never sent on its own
    assert {c for c in _subclasses(Message) if c.TYPE} == set(ALL_MESSAGES)
    assert len(MESSAGE_TYPES) == len(ALL_MESSAGES)
    for cls in ALL_MESSAGES:
        assert re.fullmatch(r"[a-z_]+", cls.TYPE), cls
        assert cls.CATEGORY in {"cmd", "state", "event", "stream", "sys", "error"}, cls
        assert [s.name for s in field_specs(cls)][: len(ENVELOPE)] == list(ENVELOPE)


# --- round trips ------------------------------------------------------------------------------------


@pytest.mark.parametrize("cls", ALL_MESSAGES, ids=lambda c: c.TYPE)
@FAST
@given(data=st.data())
def test_round_trip_of_every_message_type(cls: type[Message], data: st.DataObject) -> None:
    msg = data.draw(messages(cls))
    payload = encode(msg)
    assert decode(payload) == msg
    raw = msgpack.unpackb(payload, raw=False)
    assert raw["v"] == PROTOCOL_VERSION and raw["type"] == cls.TYPE
    assert set(raw) == {"v", "type", *(s.name for s in field_specs(cls))}
    assert encode(decode(payload)) == payload  # the encoding is canonical: decode loses nothing


@pytest.mark.parametrize("cls", ALL_MESSAGES, ids=lambda c: c.TYPE)
def test_only_required_fields_on_the_wire_decode_with_defaults(cls: type[Message]) -> None:
    msg = minimal(cls)
    required = {s.name for s in field_specs(cls) if s.required}
    raw = {"v": PROTOCOL_VERSION, "type": cls.TYPE, **{k: v for k, v in wire(msg).items() if k in required}}
    assert decode(pack(raw)) == msg


def test_integers_are_accepted_for_float_fields_and_come_back_as_floats() -> None:
    raw = wire(SetEmotion(agent="ada", name="happy"))
    raw["intensity"], raw["transition_s"] = 1, 0
    msg = decode(pack(raw))
    assert isinstance(msg, SetEmotion)
    assert (msg.intensity, msg.transition_s) == (1.0, 0.0)
    assert isinstance(msg.intensity, float)


def test_nil_is_accepted_only_where_the_field_is_optional() -> None:
    raw = wire(Say(agent="ada", request_id="r1", audio_path="a.wav"))
    raw["audio_path"] = None
    assert decode(pack(raw)).audio_path is None  # type: ignore[attr-defined]
    raw["request_id"] = None
    err = rejection(raw)
    assert (err.kind, err.field) == ("wrong_type", "request_id")


def test_limits_are_inclusive() -> None:
    assert decode(encode(SetEmotion(agent="a" * 32, name="n" * 32, intensity=1.0, transition_s=30.0)))
    assert decode(encode(FaceFrame(agent="ada", frame_ns=2**63 - 1, flexors={f"f{i}": -1.0 for i in range(64)})))


# --- targeted mutations: the right kind and field ------------------------------------------------


def wrong_type_values(spec: FieldSpec) -> list[Any]:
    """Values of a msgpack type the field does not take."""
    kind = _optional_inner(spec.kind) or spec.kind
    origin = typing.get_origin(kind)
    if origin is list:
        return ["text", {"k": 1}, 3]
    if origin is dict:
        return [[1.0, 2.0], "text", 3]
    if origin is Literal or kind is str:
        return [5, b"bytes", ["x"], True]
    if kind is int:
        return [1.5, "7", True, b"\x01", [1]]
    if kind is float:
        return ["0.5", True, b"\x00", [0.5], {"x": 1.0}]
    if kind is bool:
        return [0, 1, "true", 1.0]
    if kind is bytes:
        return ["text", 5, [1, 2]]
    raise AssertionError(kind)


def out_of_range_values(spec: FieldSpec) -> list[Any]:
    kind = _optional_inner(spec.kind) or spec.kind
    origin = typing.get_origin(kind)
    if spec.name == "agent":
        return ["", "a b", "ada.x", "x" * 33, "ä"]
    if origin is Literal:
        return ["bogus", typing.get_args(kind)[0].upper() + "!"]
    if origin is list:
        out: list[Any] = [[0] * (spec.max_len + 1)] if spec.max_len is not None else []
        item = typing.get_args(kind)[0]
        fill: list[Any] = []
        if spec.min_len:  # one short of a fixed length
            fill = [item(spec.lo if spec.lo is not None else 0)] * (spec.min_len - 1)
            out.append(fill)
        if spec.lo is not None:
            out.append([item(spec.lo), *fill[1:], item(spec.lo) - 1])
        if spec.hi is not None:
            out.append([*fill, item(spec.hi) + 1])
        return out
    if origin is dict:
        out = [{f"k{i}": [] for i in range((spec.max_len or 0) + 1)}] if spec.max_len is not None else []
        leaf = typing.get_args(kind)[1]
        wrap = (lambda v: [v]) if typing.get_origin(leaf) is list else (lambda v: v)
        if spec.lo is not None:
            out.append({"jaw": wrap(spec.lo - 0.5)})
        if spec.hi is not None:
            out.append({"jaw": wrap(spec.hi + 0.5)})
        return out
    if kind in (int, float):
        step = 1 if kind is int else max(1e-6, abs(spec.hi or spec.lo or 1) * 1e-6)
        out = []
        if spec.lo is not None:
            out.append(kind(spec.lo) - step)
        if spec.hi is not None:
            out.append(kind(spec.hi) + step)
        return out
    if kind is str and spec.max_len is not None:
        return ["x" * (spec.max_len + 1)]
    return []


def non_finite_values(spec: FieldSpec) -> list[Any]:
    kind = spec.kind
    origin = typing.get_origin(kind)
    bad = [math.nan, math.inf, -math.inf]
    if kind is float:
        return bad
    if origin is dict:
        leaf = typing.get_args(kind)[1]
        if typing.get_origin(leaf) is list:
            return [{"jaw": [0.5, v]} for v in bad]
        if leaf is float:
            return [{"jaw": v} for v in bad]
    return []


def mutations(cls: type[Message]) -> list[tuple[str, Any, str, str]]:
    """(description, mutate(raw) -> raw, expected kind, expected field) for every field of `cls`."""
    out: list[tuple[str, Any, str, str]] = []

    def setter(name: str, value: Any) -> Any:
        return lambda raw: {**raw, name: value}

    for spec in field_specs(cls):
        if spec.required:
            out.append((f"{spec.name} removed", lambda raw, n=spec.name: {k: v for k, v in raw.items() if k != n},
                        "missing_field", spec.name))
        for value in wrong_type_values(spec):
            kind = "wrong_type"
            out.append((f"{spec.name}={value!r:.40}", setter(spec.name, value), kind, spec.name))
        for value in out_of_range_values(spec):
            out.append((f"{spec.name}={value!r:.40}", setter(spec.name, value), "out_of_range", spec.name))
        for value in non_finite_values(spec):
            out.append((f"{spec.name}={value!r:.40}", setter(spec.name, value), "not_finite", spec.name))
    out.append(("extra field", setter("colour", "red"), "extra_field", "colour"))
    out.append(("extra field named like another type's field", setter("zz_not_a_field", 1), "extra_field",
                "zz_not_a_field"))
    out.append(("v removed", lambda raw: {k: v for k, v in raw.items() if k != "v"}, "unknown_version", "v"))
    out.append(("type removed", lambda raw: {k: v for k, v in raw.items() if k != "type"}, "unknown_type", "type"))
    for version in (0, 2, "1", None, -1):
        out.append((f"v={version!r}", setter("v", version), "unknown_version", "v"))
    for type_name in ("nope", cls.TYPE.upper(), 7, None, ""):
        out.append((f"type={type_name!r}", setter("type", type_name), "unknown_type", "type"))
    return out


def _field_matches(actual: str, expected: str) -> bool:
    """An error inside a list or map names the path below the field: `weights.jaw[1]`, `flexors.jaw`."""
    return actual == expected or actual.startswith((f"{expected}.", f"{expected}["))


@pytest.mark.parametrize("cls", ALL_MESSAGES, ids=lambda c: c.TYPE)
def test_each_targeted_mutation_is_rejected_with_its_kind_and_field(cls: type[Message]) -> None:
    base = wire(minimal(cls))
    failures = []
    cases = mutations(cls)
    assert len(cases) > 10
    for what, mutate, kind, field in cases:
        try:
            decode(pack(mutate(base)))
        except ProtocolError as exc:
            if exc.kind != kind or not _field_matches(exc.field, field):
                failures.append(f"{what}: got ({exc.kind}, {exc.field!r}), expected ({kind}, {field!r})")
            elif field not in str(exc):
                failures.append(f"{what}: the message {str(exc)!r} does not name the field")
        else:
            failures.append(f"{what}: accepted")
    assert not failures, "\n".join(failures)


@FAST
@given(data=st.data())
def test_a_mutated_random_message_is_rejected_with_its_kind_and_field(data: st.DataObject) -> None:
    msg = data.draw(messages())
    what, mutate, kind, field = data.draw(st.sampled_from(mutations(type(msg))))
    err = rejection(mutate(wire(msg)))
    assert err.kind == kind, what
    assert _field_matches(err.field, field), (what, err.field)


@pytest.mark.parametrize("version", [True, 1.0], ids=["true", "1.0"])
def test_the_version_must_be_the_integer_1(version: Any) -> None:
    raw = {**wire(SetEmotion(agent="ada", name="happy")), "v": version}
    err = rejection(raw)
    assert (err.kind, err.field) == ("unknown_version", "v")


def test_map_keys_must_be_short_strings() -> None:
    for key in ("", "k" * 65):
        err = rejection({**wire(FaceFrame(agent="ada", frame_ns=1)), "flexors": {key: 0.1}})
        assert (err.kind, err.field) == ("wrong_type", "flexors")
    err = rejection({**wire(MouthKeys(agent="ada", request_id="r", sample_rate=16000)), "weights": {b"jaw": [0.1]}})
    assert (err.kind, err.field) == ("wrong_type", "weights")
    # a non-string key in the top-level map is not even accepted by the unpacker
    assert rejection(pack({**wire(SetEmotion(agent="ada", name="x")), 1: 2})).kind == "not_msgpack"


def test_a_payload_that_is_not_a_map_is_a_wrong_type() -> None:
    for raw in ([1, 2], 3, "set_emotion", None, b"\x81"):
        err = rejection(pack(raw))
        assert err.kind == "wrong_type" and err.field == ""


def test_trailing_bytes_truncation_and_non_bytes_are_not_msgpack() -> None:
    payload = encode(SetEmotion(agent="ada", name="happy"))
    for data in (payload + b"\x00", payload[:-1], b"", b"\xc1", b"\xff\xff\xff"):
        assert rejection(data).kind == "not_msgpack", data
    with pytest.raises(ProtocolError) as info:
        decode("not bytes")  # type: ignore[arg-type]
    assert info.value.kind == "not_msgpack"


def test_the_size_cap_is_configurable_on_both_sides() -> None:
    msg = Say(agent="ada", request_id="r1", pcm=b"\x00\x01" * 1000, sample_rate=16000)
    payload = encode(msg)
    assert decode(payload, max_bytes=len(payload)) == msg
    err = rejection(payload, max_bytes=len(payload) - 1)
    assert err.kind == "oversize" and str(len(payload)) in str(err)
    with pytest.raises(ProtocolError) as info:
        encode(msg, max_bytes=len(payload) - 1)
    assert info.value.kind == "oversize"
    # the default cap: 4 MiB of inline audio does not fit, with or without the envelope
    big = Say(agent="ada", request_id="r1", pcm=bytes(DEFAULT_MAX_BYTES), sample_rate=16000)
    with pytest.raises(ProtocolError) as info:
        encode(big)
    assert info.value.kind == "oversize"
    raw_big = pack({**wire(msg), "pcm": bytes(DEFAULT_MAX_BYTES)})
    assert rejection(raw_big).kind == "oversize"


def test_encode_refuses_what_decode_would_refuse() -> None:
    for bad in (SetEmotion(agent="ada", name="happy", intensity=1.5), SetEmotion(agent="a b", name="happy"),
                SetEmotion(agent="ada", name="happy", intensity=math.nan)):
        with pytest.raises(ProtocolError):
            encode(bad)


# --- untargeted fuzzing: nothing but ProtocolError escapes --------------------------------------

MSGPACK_SCALARS = (st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1) | st.floats() | st.text(max_size=20)
                   | st.binary(max_size=20))
MSGPACK_VALUES = st.recursive(MSGPACK_SCALARS, lambda children: st.lists(children, max_size=5)
                              | st.dictionaries(st.text(max_size=10), children, max_size=5), max_leaves=20)


def _decode_or_protocol_error(data: bytes, max_bytes: int = DEFAULT_MAX_BYTES) -> Message | None:
    """Decode; a valid result must survive a re-encode unchanged. Any other exception fails the test."""
    try:
        msg = decode(data, max_bytes)
    except ProtocolError as exc:
        assert exc.kind in ERROR_KINDS, exc.kind
        return None
    assert decode(encode(msg)) == msg
    return msg


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200))
def test_random_bytes_raise_only_protocol_errors(data: bytes) -> None:
    _decode_or_protocol_error(data)


@settings(max_examples=150, deadline=None)
@given(MSGPACK_VALUES)
def test_random_msgpack_values_raise_only_protocol_errors(value: Any) -> None:
    assert _decode_or_protocol_error(pack(value)) is None  # nothing random is a valid message


@st.composite
def message_shaped_maps(draw: st.DrawFn) -> dict[Any, Any]:
    """Maps with a valid version and type, some of the type's keys, random values: deep in the checks."""
    cls = draw(st.sampled_from(ALL_MESSAGES))
    valid = wire(draw(messages(cls)))
    names = [s.name for s in field_specs(cls)]
    raw: dict[Any, Any] = {"v": PROTOCOL_VERSION, "type": cls.TYPE}
    for name in names:
        choice = draw(st.integers(0, 3))
        if choice == 0 and name in valid:
            raw[name] = valid[name]
        elif choice == 1:
            raw[name] = draw(MSGPACK_VALUES)
    if draw(st.booleans()):
        raw[draw(st.text(max_size=8))] = draw(MSGPACK_SCALARS)
    return raw


@settings(max_examples=150, deadline=None)
@given(message_shaped_maps())
def test_message_shaped_maps_raise_only_protocol_errors(raw: dict[Any, Any]) -> None:
    _decode_or_protocol_error(pack(raw))


@settings(max_examples=100, deadline=None)
@given(data=st.data())
def test_valid_messages_with_random_bytes_flipped_raise_only_protocol_errors(data: st.DataObject) -> None:
    payload = bytearray(encode(data.draw(messages())))
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(payload) - 1))
        payload[i] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(1, len(payload)))
    _decode_or_protocol_error(bytes(payload[:cut]), max_bytes=data.draw(st.sampled_from([64, DEFAULT_MAX_BYTES])))


def test_deep_nesting_is_a_protocol_error_not_a_crash() -> None:
    deep = b"\x91" * 100_000 + b"\xc0"  # an array inside an array ... 100 000 deep
    assert rejection(deep).kind == "not_msgpack"


# --- topics: parse_frames rejects a topic that disagrees with the content ------------------------


def test_parse_frames_accepts_a_matching_topic() -> None:
    msg = EmotionState(agent="ada", name="happy", seq=3, source="dialogue")
    got = parse_frames([topic_for(msg).encode(), encode(msg)])
    assert (got.topic, got.message, got.error) == ("state.ada.emotion", msg, None)


@pytest.mark.parametrize("topic", [b"state.bob.emotion", b"state.ada.role", b"state.ada.emotion.x", b"state.ada",
                                   b"state..emotion", b"", b"\xff\xfe.ada.emotion"])
def test_parse_frames_rejects_a_topic_that_disagrees(topic: bytes) -> None:
    got = parse_frames([topic, encode(EmotionState(agent="ada", name="happy"))])
    assert got.message is None and got.error is not None
    assert got.error.kind == "bad_topic"


@pytest.mark.parametrize("frames", [[b"state.ada.emotion"], [b"a", b"b", b"c"], []], ids=["1", "3", "0"])
def test_parse_frames_rejects_anything_but_two_frames(frames: list[bytes]) -> None:
    got = parse_frames(frames)
    assert got.message is None and got.error is not None and got.error.kind == "bad_frames"


def test_parse_frames_reports_the_codec_error_of_a_bad_payload() -> None:
    got = parse_frames([b"cmd.ada.set_emotion", b"\xff\xff\xff"])
    assert got.topic == "cmd.ada.set_emotion" and got.error is not None and got.error.kind == "not_msgpack"
    raw = {**wire(SetEmotion(agent="ada", name="happy")), "intensity": 2.0}
    got = parse_frames([b"cmd.ada.set_emotion", pack(raw)])
    assert got.error is not None and (got.error.kind, got.error.field) == ("out_of_range", "intensity")


@settings(max_examples=200, deadline=None)
@given(st.lists(st.binary(max_size=40), max_size=4), st.data())
def test_parse_frames_never_raises(frames: list[bytes], data: st.DataObject) -> None:
    if len(frames) == 2 and data.draw(st.booleans()):
        msg = data.draw(messages())
        frames[1] = encode(msg)
        if data.draw(st.booleans()):
            frames[0] = topic_for(msg).encode()
    got = parse_frames(frames)
    assert (got.message is None) != (got.error is None)
    if got.message is not None:
        assert got.topic.split(".")[1:] == [got.message.agent, got.message.TYPE]


# --- the protocol document cannot fall behind the message definitions --------------------------


def _doc_sections() -> dict[str, str]:
    text = DOC.read_text(encoding="utf-8")
    parts = re.split(r"^#### `([a-z_]+)`", text, flags=re.MULTILINE)
    sections = {}
    for name, body in zip(parts[1::2], parts[2::2], strict=True):
        sections[name] = re.split(r"^#{1,4} ", body, maxsplit=1, flags=re.MULTILINE)[0]
    return sections


def test_the_protocol_document_has_a_table_for_every_message_and_field() -> None:
    sections = _doc_sections()
    assert set(sections) == set(MESSAGE_TYPES), "docs/protocol.md: one '#### `type`' section per message type"
    problems = []
    for cls in ALL_MESSAGES:
        body = sections[cls.TYPE]
        heading = body.splitlines()[0]
        if f"{cls.CATEGORY}." not in heading:
            problems.append(f"{cls.TYPE}: heading does not name the category {cls.CATEGORY}")
        for spec in field_specs(cls):
            if spec.name in ENVELOPE:
                continue
            row = next((line for line in body.splitlines() if line.startswith(f"| `{spec.name}` |")), None)
            if row is None:
                problems.append(f"{cls.TYPE}.{spec.name}: no table row")
                continue
            if ("**required**" in row) != spec.required:
                problems.append(f"{cls.TYPE}.{spec.name}: required is {spec.required} but the row says otherwise")
            for limit in (spec.lo, spec.hi, spec.max_len, spec.min_len):
                if limit is not None and _doc_number(limit) not in row:
                    problems.append(f"{cls.TYPE}.{spec.name}: limit {limit} ({_doc_number(limit)}) not in the row")
            if typing.get_origin(spec.kind) is Literal:
                problems += [f"{cls.TYPE}.{spec.name}: choice {c!r} missing" for c in typing.get_args(spec.kind)
                             if f"`{c}`" not in row]
    assert not problems, "\n".join(problems)


def test_the_protocol_document_describes_the_envelope_and_every_error_kind() -> None:
    text = DOC.read_text(encoding="utf-8")
    for key in ("v", "type", *ENVELOPE):
        assert re.search(rf"^\| `{key}` \|", text, flags=re.MULTILINE), key
    for kind in (*ERROR_KINDS, "bad_frames", "bad_topic", "rejected", "internal"):
        assert f"| `{kind}` |" in text, kind
    assert f"`{PROTOCOL_VERSION}`" in text
    assert str(DEFAULT_MAX_BYTES) in text
    assert Error.TYPE in text


def _doc_number(x: float) -> str:
    if x == 2**63 - 1:
        return "2^63−1"
    if x in (2**62, 2**31):
        return f"2^{int(math.log2(x))}"
    if float(x).is_integer():
        x = int(x)
        return f"{x:_}".replace("_", " ") if abs(x) >= 10_000 else str(x)
    return str(x)


def test_nothing_valid_is_lost_between_topic_and_payload() -> None:
    """Every message type keeps its topic on a round trip through parse_frames (any agent id it takes)."""
    for cls in ALL_MESSAGES:
        for agent in ("ada", "x-1_Y", ALL_AGENTS):
            if (agent == ALL_AGENTS) != (cls.AGENT_SCOPE == "all") and cls.AGENT_SCOPE != "any":
                continue
            msg = dataclasses.replace(minimal(cls), agent=agent)
            got = parse_frames([topic_for(msg).encode(), encode(msg)])
            assert got.message == msg, (cls.TYPE, agent, got.error)


def test_the_agent_star_is_allowed_where_the_type_says_and_nowhere_else() -> None:
    """'*' (no single agent) is the agent of a heartbeat, an error or the list of agents; a command, a state or an
    event of '*' is out of range, and the list of agents names no single agent."""
    for cls in ALL_MESSAGES:
        for agent in ("ada", ALL_AGENTS):
            raw = {**wire(minimal(cls)), "agent": agent}
            allowed = cls.AGENT_SCOPE == "any" or (agent == ALL_AGENTS) == (cls.AGENT_SCOPE == "all")
            if allowed:
                assert decode(pack(raw)).agent == agent, cls.TYPE
            else:
                err = rejection(raw)
                assert (err.kind, err.field) == ("out_of_range", "agent"), (cls.TYPE, agent)
                with pytest.raises(ProtocolError):
                    encode(dataclasses.replace(minimal(cls), agent=agent))
    assert {c.TYPE for c in ALL_MESSAGES if c.AGENT_SCOPE != "one"} == {"heartbeat", "hello", "error", "agents",
                                                                         "eye_states"}


@pytest.mark.parametrize(("change", "field"), [
    ({"agents": ["ada", "ada"]}, "agents"),
    ({"agents": ["ada", "*"]}, "agents"),
    ({"agents": ["ada", "v1"], "created": ["v2"], "like": ["ada"]}, "created"),
    ({"agents": ["ada", "v1", "v2"], "created": ["v2", "v1"], "like": ["ada", "ada"]}, "created"),
    ({"agents": ["ada", "v1"], "created": ["v1"], "like": []}, "like"),
    ({"agents": ["ada", "v1"], "created": ["v1"], "like": ["v1"]}, "like"),
    ({"agents": ["ada"], "created": ["ada", "v1"], "like": ["ada", "ada"]}, "created"),
])
def test_a_list_of_agents_that_contradicts_itself_is_inconsistent(change: dict[str, Any], field: str) -> None:
    good = AgentsState(agent=ALL_AGENTS, agents=["ada", "v1"], created=["v1"], like=["ada"], max_created=60)
    assert decode(encode(good)) == good
    err = rejection({**wire(good), **change})
    assert (err.kind, err.field) == ("inconsistent", field), err



# --- the subscriber's repeat filter --------------------------------------------------------------


def test_a_restarted_publisher_s_new_state_is_not_taken_for_a_repeat() -> None:
    """A restarted service counts seq from 1 again: its first state must reach a subscriber that saw
    the previous instance's state with the same source and seq number."""
    with private_bus_config() as config, BrokerThread(config) as broker:
        sub = Subscriber(broker.ctx, config, ["state.ada."])
        try:
            sub.wait_ready()
            for name in ("natural", "happy"):  # two instances of one service, one after the other
                pub = Publisher(broker.ctx, config, "dialogue")
                pub.wait_ready()
                sent = pub.publish(EmotionState(agent="ada", name=name))
                assert sent.seq == 1
                got = sub.recv(2.0)
                pub.close()
                assert got is not None and got.message == sent, name
        finally:
            sub.close()


def test_the_subscriber_skips_only_exact_repeats_of_a_cached_state() -> None:
    with private_bus_config() as config, BrokerThread(config) as broker:
        pub = Publisher(broker.ctx, config, "dialogue")
        first = Subscriber(broker.ctx, config, ["state.ada.", "stream.ada."])
        try:
            pub.wait_ready()
            first.wait_ready()
            sent = pub.publish(EmotionState(agent="ada", name="happy"))
            assert first.recv(5.0).message == sent  # type: ignore[union-attr]
            late = Subscriber(broker.ctx, config, ["state.ada."])  # its subscription makes the cache re-send
            try:
                assert [g.message for g in late.wait_ready()] == [sent]
            finally:
                late.close()
            marker = pub.publish(ClockAnchor(agent="ada", request_id="u", sample_index=0, sample_rate=48_000,
                                             dac_time_ns=1))
            got = first.recv(5.0)
            assert got is not None and got.message == marker  # the repeat in between was skipped
        finally:
            pub.close()
            first.close()


def test_a_command_that_sets_a_state_has_that_state_s_fields_and_produces_it() -> None:
    from eca.protocol.messages import StateCommand

    commands = [c for c in ALL_MESSAGES if issubclass(c, StateCommand)]
    assert {c.TYPE for c in commands} == {"set_role", "set_emotion", "move_head", "set_eyes", "set_gaze_target"}
    for cls in commands:
        state_fields = {s.name: s for s in field_specs(cls.STATE)}
        own = {s.name: s for s in field_specs(cls)}
        shared = set(own) - {"request_id"}
        assert shared <= set(state_fields), cls.TYPE
        for name in shared - set(ENVELOPE):  # one definition: same type, limits and default
            assert own[name] == state_fields[name], (cls.TYPE, name)
        msg = minimal(cls)
        state = msg.as_state()
        assert type(state) is cls.STATE and state.agent == msg.agent
        assert all(getattr(state, n) == getattr(msg, n) for n in shared - set(ENVELOPE))


@pytest.mark.parametrize("obj", [{"a": 1}, {"pcm": bytes(5 * PACK_BUFFER_BYTES), "n": [1.5] * 3000}, [], "x" * 70_000])
def test_packb_packs_what_msgpack_does_at_any_size(obj: Any) -> None:
    """The codec's packer starts with a small buffer; a message larger than it grows it, byte for byte the same."""
    assert packb(obj) == msgpack.packb(obj, use_bin_type=True)


def test_the_packer_s_first_buffer_stays_under_the_services_mmap_threshold() -> None:
    """The services keep allocations of heap.LARGE_BYTES and over mapped, so a flood's memory goes back; msgpack's
    own packer starts with a 256 KiB buffer, which was then mapped and unmapped for every message wherever the heap
    had no room for it: 8 us a message instead of 0.7, and a dialogue service acknowledging a flood of commands fell
    seconds behind (bench/reliability.py). The codec's packer starts under that threshold."""
    from eca.services.processes.heap import LARGE_BYTES

    assert PACK_BUFFER_BYTES < LARGE_BYTES
