"""Malformed create_agent and remove_agent messages, through the real dialogue service on a real broker: each is
answered by one error naming what is wrong (never an ack), nothing is created or removed, and the service serves
on. Hypothesis draws the defects: wrong types, ids too long or out of the grammar, '*' where it is not an agent,
topics that disagree, extra and missing fields, ids that exist or are reserved, templates that are not agents of
the config, and random bytes."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import msgpack
import pytest
import zmq
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from eca.protocol.bus import MAX_TOPIC_BYTES, Publisher, Subscriber
from eca.protocol.messages import ALL_AGENTS, Ack, AgentsState, Error, SetRole
from eca.services.processes.dialogue import DialogueService
from tests.support.bus import ServiceThread

pytestmark = pytest.mark.slow

TYPES = ("create_agent", "remove_agent")
GOOD_ID = st.from_regex(r"\A[A-Za-z0-9_-]{1,32}\Z").filter(lambda a: a not in ("ada", "user"))
BAD_ID = st.one_of(
    st.just(ALL_AGENTS), st.just(""), st.text(min_size=33, max_size=300, alphabet="abcXYZ019_-"),
    st.text(min_size=1, max_size=40).filter(lambda t: any(not (c.isascii() and (c.isalnum() or c in "_-"))
                                                         for c in t)))
SMALL = st.integers(-(2**63), 2**64 - 1)  # what msgpack can pack
NOT_A_STRING = st.one_of(SMALL, st.binary(max_size=8), st.lists(SMALL, max_size=3), st.booleans(),
                         st.floats(allow_nan=True), st.dictionaries(st.text(max_size=3), SMALL, max_size=2))


@st.composite
def malformed(draw: st.DrawFn) -> tuple[bytes, bytes]:
    """(topic, payload) of a create or remove message that must be refused."""
    kind = draw(st.sampled_from(TYPES))
    agent = draw(GOOD_ID)
    body: dict[Any, Any] = {"v": 1, "type": kind, "agent": agent, "request_id": draw(st.text(max_size=64))}
    topic_agent: Any = agent
    defect = draw(st.sampled_from(["bad id", "wrong type", "too long", "extra", "missing", "version", "topic",
                                   "exists", "user", "like", "remove unknown", "bytes"]))
    if defect == "bad id":
        body["agent"] = topic_agent = draw(BAD_ID)
    elif defect == "wrong type":
        field = draw(st.sampled_from(["request_id", "agent", "seq", "source"] + (["like"] if kind == TYPES[0] else [])))
        body[field] = draw(NOT_A_STRING) if field != "seq" else draw(st.one_of(st.text(max_size=3), st.floats()))
    elif defect == "too long":
        body["request_id"] = draw(st.text(min_size=65, max_size=200))
    elif defect == "extra":
        body[draw(st.sampled_from(["colour", "agents", "id", "likes"]))] = draw(SMALL)
    elif defect == "missing":
        del body[draw(st.sampled_from(["v", "type", "agent"]))]
    elif defect == "version":
        body["v"] = draw(st.sampled_from([0, 2, "1", None]))
    elif defect == "topic":
        topic_agent = draw(GOOD_ID.filter(lambda a: a != agent))
    elif defect == "exists":  # a configured agent: not created again, not removed
        body["agent"] = topic_agent = "ada"
    elif defect == "user":
        body["type"], body["agent"], topic_agent = TYPES[0], "user", "user"
    elif defect == "like":
        body["type"] = TYPES[0]
        body["like"] = draw(st.one_of(GOOD_ID, st.just(agent)))  # an agent that is not one of the config
    elif defect == "remove unknown":
        body["type"] = TYPES[1]
    else:
        return f"cmd.{agent}.{body['type']}".encode(), draw(st.binary(max_size=64))
    kind = body.get("type", kind) if isinstance(body.get("type"), str) else kind
    return f"cmd.{topic_agent}.{kind}".encode("utf-8", "replace")[:MAX_TOPIC_BYTES + 20], msgpack.packb(body)


@pytest.fixture
def dialogue(bus) -> Iterator[DialogueService]:
    service = DialogueService(bus)
    with ServiceThread(service):
        yield service


@pytest.fixture
def sockets(bus, dialogue: DialogueService) -> Iterator[tuple[Publisher, Subscriber]]:
    ctx = zmq.Context()
    pub = Publisher(ctx, bus, "fuzzer")
    sub = Subscriber(ctx, bus, ["error.", "event.", f"state.{ALL_AGENTS}.agents"])
    pub.wait_ready()
    early = sub.wait_ready()
    # The service lists its agents once at start; that list comes from the cache or, when the service is slower
    # than this subscriber, a moment later. Either way it is taken here, so no example counts it as an answer.
    while not any(isinstance(got.message, AgentsState) for got in early):
        got = sub.recv(5.0)
        assert got is not None, "the dialogue service did not list its agents at start"
        early.append(got)
    yield pub, sub
    pub.close()
    sub.close()
    ctx.term()


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(frames=malformed())
def test_a_malformed_create_or_remove_is_one_error_and_changes_nothing(
        dialogue: DialogueService, sockets: tuple[Publisher, Subscriber], frames: tuple[bytes, bytes]) -> None:
    pub, sub = sockets
    pub.send_raw(*frames)
    # a marker from the same publisher: the service has handled the message before it answers the marker
    pub.publish(SetRole(agent="ada", role="listening", request_id="marker"))
    answers = []
    while True:
        got = sub.recv(5.0)
        assert got is not None, "the dialogue service did not answer"
        m = got.message
        if isinstance(m, Ack) and m.request_id == "marker":
            break
        if m is not None and not (isinstance(m, Ack) and m.command == "set_role"):
            answers.append(m)
    assert [type(m) for m in answers] == [Error], answers
    error = answers[0]
    assert isinstance(error, Error) and error.topic == frames[0][:MAX_TOPIC_BYTES].decode("utf-8", "replace")
    assert error.kind != "internal", error.reason
    assert dialogue.created == {} and list(dialogue.agents) == ["ada"]
    assert not [m for m in answers if isinstance(m, AgentsState)]
