"""A scheduled block as eca's messages (services/processes/bml/realize.py): every message lands on the sync
points the schedule gave (the head's strokes, the face's envelope, the gaze's start and end, the voice's start),
and an interrupted block's face stops at once."""

from __future__ import annotations

import pytest

from eca.agent.bml import SpeechTiming, parse_block, schedule
from eca.agent.face.gestures import HeadGesture as Gesture
from eca.protocol.messages import Expression, GazeTargetState, HeadGesture, MoveHead, Say, SetGazeTarget
from eca.services.processes.bml.realize import HeadAim, cut_messages, realize
from eca.services.processes.bml.speech import SpeechAudio

NS = 1_000_000_000
BML = "http://www.bml-initiative.org/bml/bml-1.0"


def realized(body: str, start_s: float = 100.0, speech: dict[str, SpeechTiming] | None = None):  # noqa: ANN201
    block = parse_block(f'<bml xmlns="{BML}" id="b1">{body}</bml>')
    speech = speech or {}
    timeline = schedule(block, start_s, speech)
    voices = {k: SpeechAudio(b"\0\0" * 10, 16000, None, v, False) for k, v in speech.items()}
    out = realize("ada", block, timeline, voices, lambda beh: f"say-{beh}",
                  lambda agent, target: {"bob": (-32.0, 0.0), "user": (0.0, 0.0)}.get(target),
                  GazeTargetState(agent="ada", yaw_deg=2.0, pitch_deg=1.0, target="user"), None,
                  HeadAim(40.0, 25.0, 0.25))
    return timeline, out


@pytest.mark.parametrize("repetitions", [1, 2, 3])
def test_each_stroke_of_a_head_gesture_falls_on_the_schedules_stroke(repetitions: int) -> None:
    timeline, out = realized(f'<head id="h1" lexeme="NOD" repetition="{repetitions}" start="0.5"/>')
    (msg,) = [m for m in out.now if isinstance(m, HeadGesture)]
    gesture = Gesture(msg.lexeme, msg.onset_ns, round(msg.duration_s * NS), msg.repetitions, 0.3)
    strokes = [timeline.times[("h1", "stroke" if i == 0 else f"stroke:{i + 1}")] for i in range(repetitions)]
    for i, t in enumerate(strokes):
        assert gesture.stroke_ns(i) == pytest.approx(t * NS, abs=1_000)


def test_a_face_lexeme_follows_its_four_sync_points_and_a_speech_starts_on_time() -> None:
    timeline, out = realized('<speech id="s1"><text>Hello <sync id="w"/>you</text></speech>'
                             '<faceLexeme id="f1" lexeme="RAISE_BROWS" amount="1" start="s1:w" end="s1:end"/>',
                             speech={"s1": SpeechTiming(2.0, {"w": 0.7})})
    (face,) = [m for m in out.now if isinstance(m, Expression)]
    (say,) = [m for m in out.now if isinstance(m, Say)]
    at = {sync: round(timeline.times[("f1", sync)] * NS) for sync in ("start", "attackPeak", "relax", "end")}
    assert (face.onset_ns, face.peak_ns, face.relax_ns, face.end_ns) == tuple(at.values())
    assert face.onset_ns == say.start_ns + 700_000_000 and face.end_ns == say.start_ns + 2 * NS
    assert face.flexors["brow_l"] > 0.5 and out.says == {"s1": "say-s1"}


def test_a_gaze_looks_at_its_start_and_hands_back_at_its_end() -> None:
    timeline, out = realized('<gaze id="g1" target="bob" influence="HEAD" start="1" end="2"/>')
    looks = [t for t in out.timed if isinstance(t.message, SetGazeTarget)]
    heads = [t for t in out.timed if isinstance(t.message, MoveHead)]
    assert [(t.at_ns, t.message.target, t.message.yaw_deg) for t in looks] == [
        (101 * NS, "bob", -32.0), (102 * NS, "user", 2.0)]
    assert [t.at_ns for t in heads] == [101 * NS, 102 * NS] and heads[0].message.turn < 0
    eyes_only = realized('<gaze id="g1" target="bob" influence="EYES" start="1" end="2"/>')[1]
    assert not [t for t in eyes_only.timed if isinstance(t.message, MoveHead)]


def test_an_interrupted_block_releases_its_face_and_stops_its_gestures() -> None:
    _, out = realized('<faceLexeme id="f1" lexeme="RAISE_BROWS"/><head id="h1" lexeme="SHAKE" start="5"/>')
    now = 100 * NS + 500_000_000
    cut = cut_messages(out, now)
    (face,) = [m for m in cut if isinstance(m, Expression)]
    (stop,) = [m for m in cut if isinstance(m, HeadGesture)]
    assert face.id == "b1:f1" and face.relax_ns == now and face.end_ns == now + 150_000_000
    assert face.peak_ns <= now
    assert stop.id == "b1:h1" and stop.duration_s == 0.0
