"""The BML realizer live: `eca up --bml --rig` (dialogue, gaze, audio without a sound card, rig, bml) with two
agents, driven over the bus as a BML planner would. The realized timeline is read back twice: from the
standard's feedback and from what the face did (the rig service's frames, 60 a second: the head's pitch, the
brows), against the voice as the audio service played it.
"""

from __future__ import annotations

import random
import re
import subprocess
from collections.abc import Callable, Iterator
from xml.etree import ElementTree

import numpy as np
import pytest

from eca.agent.rig.names import ARKIT_INDEX
from eca.protocol.bus import BusTimeout
from eca.protocol.client import AgentClient, CommandRejected
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import (
    BmlFeedback,
    GazeTargetState,
    Message,
    RigPose,
    Saccade,
    SpeechInterrupted,
    SpeechStarted,
)
from eca.services.processes.audio.espeak import synthesize
from tests.support.bus import REPO_ROOT, eca_command, private_bus_config, running

pytestmark = pytest.mark.slow
BML = "http://www.bml-initiative.org/bml/bml-1.0"
FRAME_NS = 1_000_000_000 // 60  # the rig's frame period


@pytest.fixture(scope="module")
def instance() -> Iterator[BusConfig]:
    with private_bus_config(services=["dialogue", "gaze", "audio"], agents=["ada", "bob"]) as config:
        argv = eca_command("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet",
                           "--bml", "--rig", "--silent-audio")
        with running(argv) as (_proc, reader):
            reader.wait_for("[up] ready in", 90.0)
            yield config


def block(block_id: str, body: str, composition: str = "MERGE") -> str:
    return f'<bml xmlns="{BML}" id="{block_id}" characterId="ada" composition="{composition}">{body}</bml>'


def feedback_until_end(client: AgentClient, block_id: str, timeout_s: float = 20.0) -> list[BmlFeedback]:
    """Every feedback of the block up to its end (the end included)."""
    got: list[BmlFeedback] = []

    def end(m: Message) -> bool:
        if isinstance(m, BmlFeedback) and m.block == block_id:
            got.append(m)
            return m.kind == "blockProgress" and m.sync == "end"
        return False

    client.wait_for(end, timeout_s)
    return got


def nothing_more(client: AgentClient, what: Callable[[Message], bool], quiet_s: float) -> list[Message]:
    """What the client holds already (returned), then: nothing more matching `what` arrives within quiet_s."""
    held = client.take_held()
    with pytest.raises(BusTimeout):
        client.wait_for(what, quiet_s)
    return held


def sync_time(feedback: list[BmlFeedback], behaviour: str, sync: str) -> int:
    (point,) = [f for f in feedback if f.kind == "syncPointProgress" and (f.behaviour, f.sync) == (behaviour, sync)]
    return point.global_ns


def test_a_nod_on_a_words_mark_strokes_within_a_frame_of_the_word(instance: BusConfig) -> None:
    text = 'I think <sync id="w1"/>this is right.'
    xml = block("nod1", f'<speech id="s1"><text>{text}</text></speech>'
                        '<head id="h1" lexeme="NOD" amount="1" stroke="s1:w1"/>')
    with AgentClient(instance, agent="ada") as client:
        client.sub.subscribe("stream.ada.rig")
        rid = client.new_request_id()
        client.wait_applied(client.bml(xml, request_id=rid), 15.0)
        started = client.wait_for(lambda m: isinstance(m, SpeechStarted), 10.0)
        frames: list[RigPose] = []
        feedback = feedback_until_end(client, "nod1")
        frames = [m for m in client.take_held() if isinstance(m, RigPose)]
    # The word as the voice has it: the engine's own mark time from the heard start of the say.
    mark_ms = {m.name: m.time_ms for m in synthesize('<speak>I think <mark name="w1"/>this is right.</speak>',
                                                       "en-us", 160, pitch=50, ssml=True).marks}["w1"]
    assert isinstance(started, SpeechStarted)
    word_ns = started.dac_time_ns + mark_ms * 1_000_000
    stroke_fb = sync_time(feedback, "h1", "stroke")
    assert abs(stroke_fb - word_ns) <= FRAME_NS, (stroke_fb - word_ns) / 1e6
    assert abs(sync_time(feedback, "s1", "w1") - word_ns) <= FRAME_NS
    # What was drawn: the chin's dip centred on the word. The dip is a smooth bump over the head's own small
    # motion, so its centre is read between the two moments it passes half its depth, not at its lowest frame.
    around = sorted((f for f in frames if word_ns - 700_000_000 <= f.frame_ns <= word_ns + 700_000_000),
                    key=lambda f: f.frame_ns)
    assert len(around) > 60, len(around)
    times = np.array([f.frame_ns for f in around], dtype=np.float64)
    pitch = np.array([f.head_deg[1] for f in around])
    onset = sync_time(feedback, "h1", "start")
    baseline = float(np.median(pitch[times < onset]))
    half = baseline - (baseline - pitch.min()) / 2
    assert baseline - pitch.min() > 5.0, (baseline, pitch.min())  # a nod, not noise
    below = np.flatnonzero(pitch < half)
    first, last = below[0], below[-1]
    down = np.interp(half, [pitch[first], pitch[first - 1]], [times[first], times[first - 1]])
    up = np.interp(half, [pitch[last], pitch[last + 1]], [times[last], times[last + 1]])
    centre = (down + up) / 2
    assert abs(centre - word_ns) <= FRAME_NS, (centre - word_ns) / 1e6
    kinds = [(f.kind, f.sync) for f in feedback if f.kind == "blockProgress"]
    assert kinds == [("blockProgress", "start"), ("blockProgress", "end")]
    assert any(f.kind == "predictionFeedback" for f in feedback)
    assert all(f.request_id == rid for f in feedback)


def test_a_gaze_at_another_agent_during_speech_hands_back_to_the_gaze_model(instance: BusConfig) -> None:
    xml = block("look1", '<speech id="s1"><text>Let me ask my colleague about that, one moment.</text></speech>'
                         '<gaze id="g1" target="bob" influence="EYES" start="s1:start+0.3" end="s1:start+1.3"/>')
    with AgentClient(instance, agent="ada") as client:
        before = client.expect_state(GazeTargetState, timeout_s=5.0)
        client.wait_applied(client.bml(xml), 15.0)
        at_bob = client.expect_state(GazeTargetState, lambda m: m.target == "bob", timeout_s=10.0)
        back = client.expect_state(GazeTargetState, lambda m: m.target == before.target, timeout_s=10.0)
        feedback = feedback_until_end(client, "look1")
        end_ns = sync_time(feedback, "g1", "end")
        # the gaze model goes on with its own saccades from there
        later = client.wait_for(lambda m: isinstance(m, Saccade) and m.onset_ns > end_ns, 10.0)
    assert at_bob.yaw_deg < -20.0  # bob sits to ada's left on the screen: a look to her left
    assert (back.yaw_deg, back.pitch_deg) == (before.yaw_deg, before.pitch_deg)
    assert sync_time(feedback, "g1", "end") - sync_time(feedback, "g1", "start") == pytest.approx(1e9, abs=2e6)
    assert isinstance(later, Saccade)


def test_a_replace_block_interrupts_the_speech_and_each_block_ends_once(instance: BusConfig) -> None:
    long_text = "This is a long answer that goes on and on, so that the next block has something to cut. " * 3
    first = block("talk1", f'<speech id="s1"><text>{long_text}</text></speech>'
                           '<faceLexeme id="f1" lexeme="RAISE_BROWS" start="s1:start" end="s1:end"/>')
    second = block("stop1", '<speech id="s2"><text>Sorry, go ahead.</text></speech>', composition="REPLACE")
    with AgentClient(instance, agent="ada") as client:
        client.wait_applied(client.bml(first), 15.0)
        client.wait_for(lambda m: isinstance(m, SpeechStarted), 10.0)
        client.wait_applied(client.bml(second), 15.0)
        got_second = feedback_until_end(client, "stop1")
        cut = client.wait_for(lambda m: isinstance(m, SpeechInterrupted), 10.0)
        # nothing more of either block comes afterwards
        held = nothing_more(client, lambda m: isinstance(m, BmlFeedback) and m.kind == "blockProgress", 1.5)
        seen = [m for m in held if isinstance(m, BmlFeedback)]
    ends = [f for f in [*seen, *got_second] if f.kind == "blockProgress" and f.sync == "end"]
    assert sorted(f.block for f in ends) == ["stop1", "talk1"], ends
    (talk_end,) = [f for f in ends if f.block == "talk1"]
    assert "replaced by block 'stop1'" in talk_end.text
    assert isinstance(cut, SpeechInterrupted)
    (stop_start,) = [f for f in got_second if f.kind == "blockProgress" and f.sync == "start"]
    assert stop_start.global_ns >= talk_end.global_ns


def test_a_gesture_gets_a_warning_and_the_block_still_runs(instance: BusConfig) -> None:
    xml = block("warn1", '<gesture id="g1" lexeme="BEAT"/><faceLexeme id="f1" lexeme="RAISE_BROWS" amount="0.8"/>')
    with AgentClient(instance, agent="ada") as client:
        client.sub.subscribe("stream.ada.rig")
        first = client.wait_for(lambda m: isinstance(m, RigPose), 5.0)  # the face before the block
        client.wait_for(lambda m: isinstance(m, RigPose) and m.frame_ns > first.frame_ns + 300_000_000, 5.0)
        client.wait_applied(client.bml(xml), 10.0)
        feedback = feedback_until_end(client, "warn1")
        frames = [first, *(m for m in client.take_held() if isinstance(m, RigPose))]
    (warning,) = [f for f in feedback if f.kind == "warningFeedback"]
    assert warning.sync == "BEHAVIOR_TYPE_NOT_SUPPORTED" and warning.behaviour == "g1"
    assert "gesture" in warning.text and re.search(r"line \d", warning.text)
    element = ElementTree.fromstring(warning.xml)  # the standard's element, as a BML planner reads it
    assert element.tag == f"{{{BML}}}warningFeedback" and element.get("id") == "warn1:g1"
    assert element.get("type") == "BEHAVIOR_TYPE_NOT_SUPPORTED" and element.text == warning.text
    peak = sync_time(feedback, "f1", "attackPeak")
    relax = sync_time(feedback, "f1", "relax")
    held = [f for f in frames if peak <= f.frame_ns <= relax]
    rest = [f for f in frames if f.frame_ns < sync_time(feedback, "f1", "start")]
    brow = ARKIT_INDEX["BrowOuterUpLeft"]
    assert held and rest
    assert np.mean([f.arkit[brow] for f in held]) > np.mean([f.arkit[brow] for f in rest]) + 0.2


@pytest.mark.parametrize("xml, kind", [
    ("<bml id='x'><speech id='s'><text>unclosed</speech></bml>", "PARSING_FAILURE"),
    ("<!DOCTYPE b [<!ENTITY a 'aaaa'>]><bml id='x'>&a;</bml>", "PARSING_FAILURE"),
    (block("x", '<head id="h" lexeme="NOD" start="nobody:start"/>'), ""),
    (block("x", '<head id="h" lexeme="NOD" start="f:end"/><faceLexeme id="f" lexeme="RAISE_BROWS" start="h:end"/>'),
     "IMPOSSIBLE_TO_SCHEDULE"),
    (block("x", '<head id="h" lexeme="NOD" repetition="1000"/>'), ""),
    ("<bml>" * 40 + "</bml>" * 40, "PARSING_FAILURE"),
])
def test_bad_blocks_are_refused_with_a_warning_and_an_error_and_nothing_runs(instance: BusConfig, xml: str,
                                                                             kind: str) -> None:
    with AgentClient(instance, agent="ada") as client:
        with pytest.raises(CommandRejected) as refused:
            client.wait_applied(client.bml(xml), 10.0)
        warning = client.wait_for(lambda m: isinstance(m, BmlFeedback) and m.kind == "warningFeedback", 5.0)
        assert isinstance(warning, BmlFeedback)
        assert not kind or warning.sync == kind
        assert warning.text and str(refused.value)
        assert re.search(r":\d+:", warning.text), warning.text  # the line
        # nothing of it ran, and the realizer is alive: the next good block runs
        client.wait_applied(client.bml(block("ok", '<head id="h" lexeme="SHAKE"/>')), 10.0)
        feedback = feedback_until_end(client, "ok")
    assert [f.block for f in feedback if f.kind == "blockProgress"] == ["ok", "ok"]


def test_a_block_sent_again_with_its_request_id_is_acknowledged_and_runs_once(instance: BusConfig) -> None:
    with AgentClient(instance, agent="ada") as client:
        sent = client.bml(block("once", '<head id="h" lexeme="NOD"/>'), request_id="bml-once-1")
        client.wait_applied(sent, 10.0)
        client.send(sent)
        client.wait_applied(sent, 10.0)
        feedback = feedback_until_end(client, "once")
        nothing_more(client, lambda m: isinstance(m, BmlFeedback) and m.block == "once", 1.0)  # it ran once
    assert [f.sync for f in feedback if f.kind == "blockProgress"] == ["start", "end"]


def test_eca_play_sends_a_file_and_prints_its_feedback_to_the_end(instance: BusConfig) -> None:
    argv = eca_command("play", "--config", str(instance.config_path), "--instance", instance.instance,
                       str(REPO_ROOT / "examples" / "bml" / "nod_on_a_word.bml"))
    done = subprocess.run(argv, capture_output=True, text=True, timeout=60, cwd=REPO_ROOT)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert any('syncPointProgress' in line and 'id="nod1:h1:stroke"' in line for line in lines), done.stdout
    assert "blockProgress" in lines[-2] and 'id="nod1:end"' in lines[-2] and lines[-1] == "done"


def test_fuzzed_blocks_are_each_answered_and_never_take_the_realizer_down(instance: BusConfig) -> None:
    """Mutations of the examples (slices cut, repeated or moved, markup characters thrown in): each block is
    acknowledged or refused, and afterwards the realizer runs a good block as before."""
    rng = random.Random(11)
    sources = [path.read_text() for path in sorted((REPO_ROOT / "examples" / "bml").glob("*.bml"))]
    answered = {"ack": 0, "refused": 0}
    with AgentClient(instance, agent="ada") as client:
        for k in range(40):
            text = rng.choice(sources)
            for _ in range(rng.randint(1, 3)):
                i, j = sorted(rng.randrange(len(text) + 1) for _ in range(2))
                op = rng.randrange(4)
                if op == 0:
                    text = text[:i] + text[j:]
                elif op == 1:
                    text = text[:j] + text[i:j] + text[j:]
                elif op == 2:
                    text = text[:i] + "".join(rng.choice('<>"&:+-/= x9') for _ in range(rng.randint(1, 8))) + text[i:]
                else:
                    text = text[:i]
            text = text.replace('id="', f'id="z{k}', 1)  # each its own block id
            try:
                client.wait_applied(client.bml(text[:65_536]), 15.0)
                answered["ack"] += 1
            except CommandRejected:
                answered["refused"] += 1
        client.wait_applied(client.bml(block("after", '<head id="h" lexeme="NOD"/>')), 10.0)
        feedback = feedback_until_end(client, "after")
    assert answered["ack"] + answered["refused"] == 40 and answered["refused"] > 0, answered
    assert [f.sync for f in feedback if f.kind == "blockProgress"] == ["start", "end"]


def test_a_barge_in_ends_the_speaking_block_once_with_its_reason(instance: BusConfig) -> None:
    text = "Here is a long explanation that the user will not let me finish, because they start to speak. " * 2
    xml = block("barge1", f'<speech id="s1"><text>{text}</text></speech>'
                          '<head id="h1" lexeme="SHAKE" start="s1:end"/>')
    with AgentClient(instance, agent="ada") as client:
        client.wait_applied(client.bml(xml), 15.0)
        client.wait_for(lambda m: isinstance(m, SpeechStarted), 10.0)
        client.wait_applied(client.user_speaking(True), 5.0)
        feedback = feedback_until_end(client, "barge1")
        nothing_more(client, lambda m: isinstance(m, BmlFeedback) and m.block == "barge1", 1.0)
        client.wait_applied(client.user_speaking(False), 5.0)
    (end,) = [f for f in feedback if f.kind == "blockProgress" and f.sync == "end"]
    assert "user started speaking" in end.text, end.text
    assert not [f for f in feedback if f.behaviour == "h1"]  # the shake after the speech never came


def test_a_gaze_cut_short_by_replace_gives_the_gaze_back_at_once(instance: BusConfig) -> None:
    with AgentClient(instance, agent="ada") as client:
        before = client.expect_state(GazeTargetState, timeout_s=5.0)
        client.wait_applied(client.bml(block("gazecut", '<gaze id="g1" target="bob" start="0" end="8"/>')), 10.0)
        client.expect_state(GazeTargetState, lambda m: m.target == "bob", timeout_s=5.0)
        client.wait_applied(client.bml(block("gazecut2", '<head id="h" lexeme="NOD"/>', "REPLACE")), 10.0)
        back = client.expect_state(GazeTargetState, lambda m: m.target != "bob", timeout_s=3.0)
    assert (back.target, back.yaw_deg) == (before.target, before.yaw_deg)
