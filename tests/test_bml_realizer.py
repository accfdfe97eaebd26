"""The realizer's bookkeeping on injected time (agent/bml/realizer.py): feedback in time order and once each, a
speech's points following its heard start, a block ending only when its speech has, an interrupted block
ending once, APPEND after the blocks before it."""

from __future__ import annotations

import pytest

from eca.agent.bml.realizer import NS, AgentRealizer, Feedback

MS = 1_000_000


def kinds(items: list[Feedback]) -> list[tuple[str, str, str]]:
    return [(f.kind, f.behaviour, f.sync) for f in items]


def test_sync_points_are_reported_in_time_order_once_each_and_the_end_last() -> None:
    r = AgentRealizer("ada")
    start = 10 * NS
    times = {("h1", "start"): start, ("h1", "stroke"): start + 300 * MS, ("h1", "end"): start + 600 * MS,
             ("f1", "start"): start + 100 * MS, ("f1", "end"): start + 400 * MS}
    (prediction,) = r.begin("b1", "rid-1", start, times, {})
    assert prediction.kind == "predictionFeedback" and prediction.end_ns == start + 600 * MS
    assert r.due(start - 1) == []
    first = r.due(start + 150 * MS)
    assert kinds(first) == [("blockProgress", "", "start"), ("syncPointProgress", "h1", "start"),
                            ("syncPointProgress", "f1", "start")]
    assert r.due(start + 150 * MS) == []  # nothing twice
    rest = r.due(start + 10 * NS)
    assert kinds(rest) == [("syncPointProgress", "h1", "stroke"), ("syncPointProgress", "f1", "end"),
                           ("syncPointProgress", "h1", "end"), ("blockProgress", "", "end")]
    assert rest[0].time_s == pytest.approx(0.3) and rest[-1].global_ns == start + 600 * MS
    assert all(f.request_id == "rid-1" for f in first + rest)
    assert r.due(start + 20 * NS) == [] and r.running_ids() == set()


def test_a_speechs_points_follow_its_heard_start_and_the_block_waits_for_its_end() -> None:
    r = AgentRealizer("ada")
    start = 5 * NS
    times = {("s1", "start"): start, ("s1", "w1"): start + 700 * MS, ("s1", "end"): start + 2 * NS,
             ("h1", "stroke"): start + 700 * MS}
    r.begin("b1", "", start, times, {"s1": "say-1"})
    got = r.due(start + 3 * NS)  # the voice has not been heard yet: none of its points has happened
    assert ("syncPointProgress", "s1", "start") not in kinds(got) and ("blockProgress", "", "end") not in kinds(got)
    heard = start + 3 * NS + 40 * MS  # the audio started late
    r.speech_started("say-1", heard)
    got = r.due(heard + 800 * MS)
    points = {(f.behaviour, f.sync): f.global_ns for f in got if f.kind == "syncPointProgress"}
    assert points[("s1", "start")] == heard and points[("s1", "w1")] == heard + 700 * MS
    assert ("s1", "end") not in points  # until the audio says it ended
    r.speech_ended("say-1", heard + 1_900 * MS)
    got = r.due(heard + 1_950 * MS)
    assert kinds(got) == [("syncPointProgress", "s1", "end"), ("blockProgress", "", "end")]
    assert got[0].global_ns == heard + 1_900 * MS


def test_an_interrupted_block_ends_once_with_its_reason_and_reports_nothing_more() -> None:
    r = AgentRealizer("ada")
    r.begin("b1", "", 0, {("h1", "start"): 0, ("h1", "end"): 5 * NS}, {})
    r.begin("b2", "", 3 * NS, {("f1", "start"): 3 * NS, ("f1", "end"): 4 * NS}, {})
    r.due(1 * NS)
    cut = r.interrupt(2 * NS, "replaced by block 'b3'")
    assert [(f.block, f.sync, f.text) for f in cut if f.kind == "blockProgress"] == [
        ("b1", "end", "replaced by block 'b3'"), ("b2", "start", ""), ("b2", "end", "replaced by block 'b3'")]
    assert r.interrupt(2 * NS, "again") == [] and r.due(10 * NS) == []


def test_append_starts_after_the_blocks_before_and_references_see_ended_blocks() -> None:
    r = AgentRealizer("ada")
    r.begin("b1", "", 0, {("h1", "start"): 0, ("h1", "end"): 3 * NS}, {})
    assert r.start_for("APPEND", 1 * NS) == 3 * NS and r.start_for("MERGE", 1 * NS) == 1 * NS
    r.due(4 * NS)
    assert r.start_for("APPEND", 5 * NS) == 5 * NS
    known = r.known_times_s()
    assert known[("b1", "h1", "end")] == pytest.approx(3.0) and known[("b1", "bml", "end")] == pytest.approx(3.0)
    assert known[("b1", "bml", "start")] == 0.0


def test_the_blocks_an_agent_holds_are_bounded() -> None:
    r = AgentRealizer("ada", max_blocks=3)
    for k in range(3):
        r.begin(f"b{k}", "", 0, {("h", "end"): 10 * NS}, {})
    with pytest.raises(ValueError, match="already runs 3 blocks"):
        r.begin("b9", "", 0, {("h", "end"): NS}, {})
    r.interrupt(0, "stop")
    for k in range(10):  # ended blocks kept for references: at most max_blocks of them
        r.begin(f"c{k}", "", 0, {("h", "end"): 0}, {})
        r.due(1)
    assert len(r.ended_ids) <= 3 and len({k[0] for k in r.known_times_s()}) <= 3
