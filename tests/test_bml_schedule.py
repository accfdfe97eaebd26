"""Scheduling BML blocks: stretching between pinned points, offsets, cycles and contradictions refused with their
lines, references to earlier blocks, before/after delays, and the default timings from the config."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from eca import shipped_configs
from eca.agent.bml import (
    IMPOSSIBLE_TO_SCHEDULE,
    BehaviourTimings,
    BmlError,
    SpeechTiming,
    Timeline,
    parse_block,
    schedule,
)
from tests.test_bml_spec_examples import TIMINGS

NO_SPEECH: dict[str, SpeechTiming] = {}


def bml(body: str, block_id: str = "b1") -> str:
    return f'<bml id="{block_id}">\n{body}\n</bml>'


def run(body: str, speech: dict[str, SpeechTiming] = NO_SPEECH, start_s: float = 0.0,
        known: dict[tuple[str, str, str], float] | None = None, block_id: str = "b1") -> Timeline:
    return schedule(parse_block(bml(body, block_id)), start_s, speech, known or {}, timings=TIMINGS)


def refused(body: str, speech: dict[str, SpeechTiming] = NO_SPEECH,
            known: dict[tuple[str, str, str], float] | None = None) -> BmlError:
    with pytest.raises(BmlError) as caught:
        run(body, speech, known=known)
    assert caught.value.warning_type == IMPOSSIBLE_TO_SCHEDULE, str(caught.value)
    return caught.value


def relative(timeline: Timeline, behaviour: str) -> dict[str, float]:
    return {s: round(t - timeline.start_s, 9) for (b, s), t in timeline.times.items() if b == behaviour}


# -- one behaviour: shift and stretch --


def test_one_pin_moves_the_behaviour_whole() -> None:
    times = relative(run('<head id="h" lexeme="NOD" stroke="2"/>'), "h")
    assert times == {"start": 1.6, "ready": 1.7, "strokeStart": 1.7, "stroke": 2.0, "strokeEnd": 2.3, "relax": 2.3,
                     "end": 2.4}


def test_two_pins_stretch_between_and_keep_the_default_spacing_outside() -> None:
    times = relative(run('<faceLexeme id="f" lexeme="RAISE_BROWS" attackPeak="1" relax="3"/>'), "f")
    assert times == {"start": 0.8, "attackPeak": 1.0, "relax": 3.0, "end": 3.2}
    stretched = relative(run('<faceLexeme id="f" lexeme="RAISE_BROWS" start="0" end="2.8"/>'), "f")
    assert stretched == pytest.approx({"start": 0.0, "attackPeak": 0.4, "relax": 2.4, "end": 2.8})


def test_repetitions_add_strokes_in_order() -> None:
    times = relative(run('<head id="h" lexeme="NOD" repetition="3"/>'), "h")
    assert list(times) == ["start", "ready", "strokeStart", "stroke", "stroke:2", "stroke:3", "strokeEnd", "relax",
                           "end"]
    assert [times["stroke"], times["stroke:2"], times["stroke:3"], times["end"]] == pytest.approx([0.4, 1.0, 1.6, 2.0])
    pinned = relative(run('<head id="h" lexeme="NOD" repetition="2"/><head id="g" lexeme="TILT" start="h:stroke:2"/>'),
                      "g")
    assert pinned["start"] == pytest.approx(1.0)


def test_points_pinned_out_of_order_are_refused() -> None:
    error = refused('<head id="h" lexeme="NOD"\n start="3" stroke="2"/>')
    assert error.behaviour == "h" and error.line == 2 and "'stroke'" in error.message


def test_a_speech_moves_but_never_stretches() -> None:
    speech = {"s": SpeechTiming(2.0, {"m": 0.5})}
    times = relative(run('<speech id="s" end="5"><text>a <sync id="m"/>b</text></speech>', speech), "s")
    assert times == {"start": 3.0, "m": 3.5, "end": 5.0}
    error = refused('<speech id="s" start="1" end="5"><text>a</text></speech>', speech)
    assert "cannot be stretched" in error.message


def test_speech_needs_its_timing_and_every_mark() -> None:
    assert "no speech timing" in refused('<speech id="s"><text>a</text></speech>').message
    error = refused('<speech id="s"><text>a <sync id="m"/>b</text></speech>', {"s": SpeechTiming(1.0, {})})
    assert "mark 'm'" in error.message
    # marks come in their spoken order, and a TTS's rounding past the end stays inside the speech
    timeline = run('<speech id="s"><text>a <sync id="x"/>b <sync id="y"/>c</text></speech>',
                   {"s": SpeechTiming(1.0, {"x": 0.7, "y": 1.2})})
    assert list(relative(timeline, "s").items()) == [("start", 0.0), ("x", 0.7), ("y", 1.0), ("end", 1.0)]


def test_references_to_own_points() -> None:
    assert relative(run('<head id="h" lexeme="SHAKE" end="self:start+2"/>'), "h")["end"] == 2.0
    error = refused('<head id="h" lexeme="NOD" start="h:end" end="h:start"/>')
    assert "own sync points" in error.message and error.behaviour == "h"


# -- between behaviours --


def test_offsets_and_the_block_start_on_the_callers_clock() -> None:
    timeline = run('<head id="a" lexeme="NOD" start="bml:start+1"/><head id="b" lexeme="NOD" start="a:end-0.3"/>',
                   start_s=50.0)
    assert (timeline.times[("a", "start")], timeline.times[("b", "start")]) == pytest.approx((51.0, 51.5))
    assert timeline.end_s == pytest.approx(52.3) and timeline.start_s == 50.0


def test_a_free_group_waits_for_its_earliest_member() -> None:
    timeline = run('<head id="a" lexeme="NOD" start="b:start-2"/><head id="b" lexeme="NOD"/>')
    assert relative(timeline, "a")["start"] == 0.0 and relative(timeline, "b")["start"] == 2.0


def test_an_anchored_behaviour_may_not_start_before_its_block() -> None:
    error = refused('<head id="a" lexeme="NOD"\n start="-1"/>')
    assert "before its block" in error.message and error.line == 2
    error = refused('<head id="a" lexeme="NOD" start="b:start-2"/><head id="b" lexeme="NOD" start="1"/>')
    assert error.behaviour == "a"


def test_a_cycle_of_references_names_its_behaviours_and_lines() -> None:
    error = refused('<head id="a" lexeme="NOD" start="b:end"/>\n<head id="b" lexeme="NOD" start="c:end"/>\n'
                    '<head id="c" lexeme="NOD" start="a:stroke"/>')
    assert "cycle" in error.message
    for name, line in (("a", 2), ("b", 3), ("c", 4)):
        assert f"'{name}' (line {line})" in error.message


def test_contradictions_are_refused() -> None:
    error = refused('<head id="a" lexeme="NOD" start="1"/><constraint><synchronize><sync ref="a:start"/>'
                    '<sync ref="2"/></synchronize></constraint>')
    assert "'1'" in error.message and "'2'" in error.message
    assert "asks for both" in refused('<head id="a" lexeme="NOD"/><constraint><synchronize><sync ref="1"/>'
                                      '<sync ref="2"/><sync ref="a:start"/></synchronize></constraint>').message
    # tied at two points, a face stretches to the head; a speech cannot
    both = ('<head id="a" lexeme="NOD"/><{0}<constraint><synchronize><sync ref="a:start"/><sync ref="f:start"/>'
            '</synchronize><synchronize><sync ref="a:end"/><sync ref="f:end"/></synchronize></constraint>')
    face = relative(run(both.format('faceLexeme id="f" lexeme="RAISE_BROWS"/>')), "f")
    assert (face["start"], face["end"]) == pytest.approx((0.0, 0.8))
    error = refused(both.format('speech id="f"><text>Hi</text></speech>'), {"f": SpeechTiming(2.0, {})})
    assert "cannot be stretched" in error.message


def test_synchronize_pins_the_later_to_the_earlier() -> None:
    timeline = run('<head id="a" lexeme="NOD" start="2"/><faceLexeme id="f" lexeme="RAISE_BROWS"/><gaze id="g" '
                   'target="x"/><constraint><synchronize><sync ref="f:attackPeak"/><sync ref="a:stroke"/>'
                   '<sync ref="g:ready+0.1"/></synchronize></constraint>')
    assert timeline.times[("f", "attackPeak")] == pytest.approx(2.4)
    assert timeline.times[("g", "ready")] == pytest.approx(2.3)


def test_missing_behaviours_and_sync_points_are_named() -> None:
    error = refused('<head id="a" lexeme="NOD"\n start="zz:end"/>')
    assert "no behaviour 'zz'" in error.message and error.line == 2
    error = refused('<head id="a" lexeme="NOD"/><constraint>\n<synchronize><sync ref="a:attackPeak"/><sync ref="1"/>'
                    '</synchronize></constraint>')
    assert "no sync point 'attackPeak'" in error.message and error.line == 3


def test_references_to_unrealized_behaviours_resolve() -> None:
    timeline = run('<gesture id="g" lexeme="BEAT" start="2"/><head id="h" lexeme="NOD" stroke="g:stroke"/>')
    assert timeline.times[("h", "stroke")] == pytest.approx(2.5)  # g's seven points spread over 1 s
    assert all(b != "g" for b, _ in timeline.times)


# -- before / after --


def test_after_delays_the_free_side_and_before_delays_the_anchor() -> None:
    timeline = run('<head id="a" lexeme="NOD" start="1"/><head id="b" lexeme="NOD"/><constraint><after ref="a:end">'
                   '<sync ref="b:start"/></after></constraint>')
    assert timeline.times[("b", "start")] == pytest.approx(1.8)
    timeline = run('<head id="a" lexeme="NOD" start="1"/><head id="b" lexeme="NOD"/><constraint><before>'
                   '<sync ref="b:start"/><sync ref="a:end+0.5"/></before></constraint>')
    assert timeline.times[("b", "start")] == pytest.approx(2.3)  # the first <sync> is the anchor here
    satisfied = run('<head id="a" lexeme="NOD" start="1"/><head id="b" lexeme="NOD"/><constraint><after>'
                    '<sync ref="a:start"/><sync ref="b:start+5"/></after></constraint>')
    assert satisfied.times[("b", "start")] == 0.0


def test_before_after_that_nothing_free_can_satisfy_is_refused() -> None:
    error = refused('<head id="a" lexeme="NOD" start="1"/><head id="b" lexeme="NOD" start="0"/><constraint>\n'
                    '<after ref="a:end"><sync ref="b:start"/></after></constraint>')
    assert "neither can move" in error.message and error.line == 3
    # both sides in one group: delaying it moves both
    refused('<head id="a" lexeme="NOD"/><head id="b" lexeme="NOD" start="a:end"/><constraint>'
            '<before ref="b:start"><sync ref="a:end+1"/></before></constraint>')


def test_chained_afters_reach_their_fixed_point() -> None:
    timeline = run('<head id="a" lexeme="NOD" start="1"/><head id="b" lexeme="NOD"/><head id="c" lexeme="NOD"/>'
                   '<constraint><after ref="b:end"><sync ref="c:start"/></after><after ref="a:end">'
                   '<sync ref="b:start"/></after></constraint>')
    assert timeline.times[("c", "start")] == pytest.approx(2.6)


# -- across blocks --


def test_references_to_earlier_blocks_read_known() -> None:
    first = run('<head id="h1" lexeme="NOD"/>', block_id="b0", start_s=10.0)
    known = first.as_known()
    assert known[("b0", "bml", "start")] == 10.0 and known[("b0", "bml", "end")] == pytest.approx(10.8)
    second = run('<head id="h" lexeme="NOD" start="b0:h1:end+0.5"/><head id="k" lexeme="NOD" start="b0:2"/>'
                 '<head id="m" lexeme="NOD" start="b0:bml:end"/>', start_s=10.5, known=known)
    assert second.times[("h", "start")] == pytest.approx(11.3)
    assert second.times[("k", "start")] == pytest.approx(12.0)
    assert second.times[("m", "start")] == pytest.approx(10.8)
    error = refused('<head id="h" lexeme="NOD"\n start="b9:h1:end"/>', known=known)
    assert "block 'b9'" in error.message and error.line == 2


def test_an_earlier_blocks_point_in_the_past_is_before_this_block() -> None:
    with pytest.raises(BmlError, match="before its block"):
        run('<head id="h" lexeme="NOD" start="b0:h1:start"/>', start_s=5.0, known={("b0", "h1", "start"): 1.0})


# -- timeline --


def test_in_order_and_the_end_of_the_block() -> None:
    timeline = run('<head id="a" lexeme="NOD" start="1"/><blink id="k" start="0.5"/><eca:role id="r" role="talking"/>')
    order = timeline.in_order()
    assert order == sorted(order, key=lambda row: row[0])
    assert order[0] == (0.0, "r", "start") and order[1] == (0.0, "r", "end")  # ties keep the sync order
    assert timeline.end_s == pytest.approx(1.8)
    assert run("").end_s == 0.0


def test_non_finite_start_is_refused() -> None:
    with pytest.raises(BmlError):
        schedule(parse_block(bml('<head id="a" lexeme="NOD"/>')), float("inf"), {}, timings=TIMINGS)


def test_default_timings_come_from_the_config(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    shipped = BehaviourTimings.from_config()
    default = schedule(parse_block(bml('<head id="h" lexeme="NOD"/>')), 0.0, {})
    assert default.end_s == pytest.approx(shipped.head_prepare_s + shipped.head_stroke_s + shipped.head_retract_s)
    text = (shipped_configs() / "bml.toml").read_text().replace("head_stroke_s = 0.6", "head_stroke_s = 2.0")
    (tmp_path / "bml.toml").write_text(text)
    monkeypatch.setenv("ECA_CONFIG_DIR", str(tmp_path))
    assert BehaviourTimings.from_config() == dataclasses.replace(shipped, head_stroke_s=2.0)
    own = schedule(parse_block(bml('<head id="h" lexeme="NOD"/>')), 0.0, {})
    assert own.end_s == pytest.approx(shipped.head_prepare_s + 2.0 + shipped.head_retract_s)
