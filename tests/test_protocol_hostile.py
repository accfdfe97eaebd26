"""Hostile values in every place a message can hold them: decoding fails only with a `ProtocolError` whose
reason is a plain, short sentence, however deep or large the value, and an error about a command still
names the command's agent and request id.

A value nested 1,000 deep once made the codec's error message (`repr` of the value) raise RecursionError,
which killed whichever process read it; these tests put such values (and huge ones) in the envelope, in
the type and version keys, in every field of every message type, and as map keys.
"""

from __future__ import annotations

from typing import Any

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from eca.protocol.bus import MAX_TOPIC_BYTES, parse_frames
from eca.protocol.codec import ProtocolError, decode, describe, encode, field_specs
from eca.protocol.messages import ALL_MESSAGES, SetEmotion

SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
MAX_REASON_CHARS = 1000  # far above any reason the codec writes; a value printed whole would exceed it


def nested(depth: int, leaf: Any = 0, as_map: bool = False) -> Any:
    value = leaf
    for _ in range(depth):
        value = {"k": value} if as_map else [value]
    return value


HOSTILE_VALUES = st.one_of(
    st.integers(1, 1000).map(nested),  # the msgpack unpacker itself accepts up to about 1,024 levels
    st.integers(1, 1000).map(lambda d: nested(d, as_map=True)),
    st.integers(10_000, 200_000).map(lambda n: list(range(n))),
    st.integers(10_000, 100_000).map(lambda n: {f"k{i}": i for i in range(n)}),
    st.integers(10_000, 1_000_000).map(lambda n: "x" * n),
    st.integers(10_000, 1_000_000).map(lambda n: b"\xff" * n),
    st.just(float("nan")), st.just(-(2**63)), st.just(2**64 - 1), st.none(), st.booleans(),
)
PLACES = st.sampled_from(["v", "type", "agent", "seq", "t_ns", "source", "request_id", "field", "extra key"])


def decode_problem(raw: Any) -> ProtocolError:
    with pytest.raises(ProtocolError) as info:
        decode(msgpack.packb(raw, use_bin_type=True))
    return info.value


@SETTINGS
@given(cls=st.sampled_from(ALL_MESSAGES), value=HOSTILE_VALUES, place=PLACES, data=st.data())
def test_a_hostile_value_anywhere_is_one_short_protocol_error(cls: type, value: Any, place: str,
                                                              data: st.DataObject) -> None:
    raw: dict[Any, Any] = {"v": 1, "type": cls.TYPE, "agent": "ada", "request_id": "r-1"}
    if place == "field":
        specs = [s for s in field_specs(cls) if s.name not in ("agent", "seq", "t_ns", "source")]
        if not specs:
            return
        raw[data.draw(st.sampled_from(specs)).name] = value
    elif place == "extra key":
        raw[describe(value)] = value
    else:
        raw[place] = value
    try:
        decode(msgpack.packb(raw, use_bin_type=True))
    except ProtocolError as exc:
        assert len(str(exc)) <= MAX_REASON_CHARS, str(exc)[:200]
        assert "Traceback" not in str(exc)
    # (a hostile value may also be a valid one for some field: a bool, say; then the message decodes)


def test_the_one_kilobyte_message_that_used_to_kill_a_process_is_an_error() -> None:
    deep = nested(1000)
    for raw in ({"v": 1, "type": deep, "agent": "ada"}, {"v": deep, "type": "set_role"}):
        payload = msgpack.packb(raw)
        assert len(payload) < 1100
        problem = decode_problem(raw)
        assert problem.kind in ("unknown_type", "unknown_version")
        assert "array" in str(problem) and len(str(problem)) < 200


def test_describe_is_bounded_whatever_it_is_given() -> None:
    for value in (nested(5000), list(range(10**6)), "y" * 10**6, b"z" * 10**6, {str(i): i for i in range(10**5)},
                  10**300, 1e308, None, True, object()):
        assert len(describe(value)) < 150
    assert describe([1, 2, 3]) == "an array of 3 items"
    assert describe("abc") == "'abc'"


@pytest.mark.parametrize("payload, words", [
    (b"\xff\xff\xff", "more than one msgpack value"),
    (b"\x92\x01", "ends in the middle"),
    (b"\xc1", "not valid msgpack"),
    (b"\xa2\xff\xfe", "not valid UTF-8"),
    (msgpack.packb({1: 2}), "map key"),
    (b"\x91" * 2000 + b"\x00", "nested too deeply"),
])
def test_msgpack_failures_read_as_plain_sentences(payload: bytes, words: str) -> None:
    with pytest.raises(ProtocolError) as info:
        decode(payload)
    reason = str(info.value)
    assert words in reason
    for internal in ("unpack(b)", "ExtraData", "FormatError", "StackError", "Unpack failed"):
        assert internal not in reason


@pytest.mark.parametrize("raw, words", [
    ({"type": "set_role", "agent": "ada"}, "protocol version is missing"),
    ({"v": "1", "type": "set_role"}, "must be the integer 1, got string"),
    ({"v": 7, "type": "set_role"}, "protocol version 7 is not supported"),
    ({"v": 1, "agent": "ada"}, "message type is missing"),
])
def test_version_and_type_problems_say_what_is_wrong(raw: dict[str, Any], words: str) -> None:
    reason = str(decode_problem(raw))
    assert words in reason and "None" not in reason


def test_an_error_about_a_command_names_its_agent_and_request_id() -> None:
    good = msgpack.unpackb(encode(SetEmotion(agent="ada", name="happy", request_id="r-42")))
    for mutate in (lambda m: m.update(intensity=2.0), lambda m: m.update(mood="great"),
                   lambda m: m.update(v=9), lambda m: m.update(type="set_mood"), lambda m: m.pop("name")):
        raw = dict(good)
        mutate(raw)
        problem = decode_problem(raw)
        assert (problem.agent, problem.request_id) == ("ada", "r-42"), problem.kind
    raw = dict(good, agent="not an agent!", request_id="x" * 65, intensity=2.0)
    problem = decode_problem(raw)
    assert (problem.agent, problem.request_id) == ("", "")  # only well-formed claims are passed on


FRAMES = st.lists(st.binary(max_size=300), min_size=0, max_size=5)


@SETTINGS
@given(frames=FRAMES)
def test_parse_frames_never_raises(frames: list[bytes]) -> None:
    got = parse_frames(frames)
    assert (got.message is None) != (got.error is None)
    assert len(got.topic) <= MAX_TOPIC_BYTES


def test_a_message_with_the_wrong_number_of_frames_keeps_its_topic() -> None:
    payload = encode(SetEmotion(agent="ada", name="happy"))
    got = parse_frames([b"cmd.ada.set_emotion", payload, b"third"])
    assert got.error is not None and got.error.kind == "bad_frames" and got.topic == "cmd.ada.set_emotion"
    got = parse_frames([b"x" * 10_000, payload])
    assert got.error is not None and got.error.kind == "bad_topic" and len(got.topic) == MAX_TOPIC_BYTES


def test_a_rejected_message_holds_no_frames_of_the_reader() -> None:
    """An error kept in a Received must not hold the decoder's frames (through its traceback or the
    exception it was raised from): their callers' locals hold the reader's whole batch, in a cycle that
    only a full collection frees, and under a flood of garbage that memory stayed."""
    for payload in (b"\xc1", msgpack.packb({"v": 1, "type": "set_emotion", "agent": "ada", "intensity": 9.0}),
                    msgpack.packb({"v": 1, "type": "set_emotion", "agent": "ada", "name": "x", "mood": 1})):
        got = parse_frames([b"cmd.ada.set_emotion", payload])
        assert got.error is not None
        assert got.error.__traceback__ is None and got.error.__context__ is None and got.error.__cause__ is None


def _rig_map() -> dict[str, Any]:
    from eca.protocol.messages import RigPose

    frame = RigPose(agent="ada", frame_ns=1, arkit=[0.0] * 52, head_deg=[0.0] * 3, eyes_deg=[0.0] * 4,
                    visemes=[1.0] + [0.0] * 14, vrm=[0.0] * 17 + [1.0])
    return dict(msgpack.unpackb(encode(frame)))


@pytest.mark.parametrize("field, value, kind", [
    ("arkit", [0.5] * 51, "out_of_range"),                 # one weight short of the fixed 52
    ("arkit", [0.5] * 53, "out_of_range"),
    ("arkit", [0.5] * 51 + [1.5], "out_of_range"),         # a weight over 1
    ("arkit", [0.5] * 51 + [float("nan")], "not_finite"),
    ("arkit", [0.5] * 200_000, "out_of_range"),          # a long list is refused by its length
    ("head_deg", [0.0, 0.0, 400.0], "out_of_range"),
    ("eyes_deg", [0.0, 0.0, 0.0, -91.0], "out_of_range"),
    ("visemes", {"sil": 1.0}, "wrong_type"),
    ("vrm", "neutral", "wrong_type"),
    ("frame_ns", -1, "out_of_range"),
])
def test_a_hostile_rig_frame_is_one_short_error_naming_its_field(field: str, value: Any, kind: str) -> None:
    """A rig frame's lists have fixed lengths and ranges: a client that indexes them can trust any frame that
    decodes, and one that does not is refused in a sentence, however large it is."""
    raw = _rig_map()
    raw[field] = value
    problem = decode_problem(raw)
    assert problem.kind == kind and problem.field.startswith(field), (problem.kind, problem.field)
    assert field in str(problem) and len(str(problem)) < 200
