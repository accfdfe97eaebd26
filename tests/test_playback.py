"""Script replay over the bus, bus recordings, and their errors."""

from __future__ import annotations

import time
from pathlib import Path

import msgpack
import pytest
import zmq

from eca.agent.script import EmotionCue, GazeCue, HeadCue, RoleCue, SayCue
from eca.protocol.bus import Publisher, Subscriber
from eca.protocol.codec import encode
from eca.protocol.messages import EmotionState, MoveHead, RoleState, Say, SetEmotion, SetGazeTarget
from eca.services.processes.dialogue import DialogueService
from eca.services.tools.cli import main as eca
from eca.services.tools.playback import CueTranslator
from eca.services.tools.recording import RecordingError, RecordingWriter, read_recording
from tests.support.bus import ServiceThread


def test_head_cue_leaves_unnamed_axes_where_they_were() -> None:
    tr = CueTranslator("ada")
    first = tr.commands(HeadCue(0.0, "ada", turn=0.5, nod=0.2, tilt=None, duration_s=1.0))[0]
    second = tr.commands(HeadCue(1.0, "ada", turn=None, nod=-0.3, tilt=0.1, duration_s=0.5))[0]
    assert isinstance(second, MoveHead)
    assert (first.turn, first.nod, first.tilt) == (0.5, 0.2, 0.0)
    assert (second.turn, second.nod, second.tilt) == (0.5, -0.3, 0.1)


def test_cues_become_commands_for_the_agent_only() -> None:
    tr = CueTranslator("ada")
    assert tr.commands(RoleCue(0.0, "user", "talking")) == []
    (emo,) = tr.commands(EmotionCue(0.0, "ada", "happy", 0.5, 0.3))
    assert isinstance(emo, SetEmotion) and (emo.name, emo.intensity, emo.transition_s) == ("happy", 0.5, 0.3)
    gaze = tr.commands(GazeCue(0.0, "ada", mode=None, yaw_deg=10.0, pitch_deg=None))
    assert isinstance(gaze[0], SetGazeTarget) and (gaze[0].yaw_deg, gaze[0].pitch_deg) == (10.0, 0.0)
    (say,) = tr.commands(SayCue(0.0, "ada", "u1", "hi", "/abs/hi.wav", 1.0))
    assert isinstance(say, Say) and say.audio_path == "/abs/hi.wav" and say.request_id == "u1"
    assert tr.commands(SayCue(0.0, "ada", "u2", "no voice", None, 1.0)) == []  # no voice cache given


def test_recording_round_trip_and_replay_republishes_every_frame(bus, tmp_path: Path) -> None:
    path = tmp_path / "rec.eca"
    frames = [(b"state.ada.emotion", encode(EmotionState(agent="ada", name="happy"))), (b"cmd.ada.x", b"\x01\x02")]
    writer = RecordingWriter(path, "test", 5)
    for i, (topic, payload) in enumerate(frames):
        writer.write(1_000_000 * (i + 1), topic, payload)
    writer.close()
    header, records = read_recording(path)
    assert header["instance"] == "test" and [(r.topic, r.payload) for r in records] == frames
    ctx = zmq.Context()
    sub = Subscriber(ctx, bus, ["cmd.ada.", "state.ada."])
    sub.wait_ready()
    try:
        assert eca(["replay", str(path), "--config", str(bus.config_path), "--instance", bus.instance,
                    "--speed", "0"]) == 0
        got = [sub.recv(5.0) for _ in frames]
        assert [g.topic for g in got if g] == ["state.ada.emotion", "cmd.ada.x"]
        assert got[0].message.name == "happy" and got[1].error is not None  # replayed as it was, bad too
    finally:
        sub.close()
        ctx.term()


@pytest.mark.parametrize("content, problem", [
    (b"", "empty file"),
    (msgpack.packb({"magic": "other"}), "no 'eca-recording' header"),
    (msgpack.packb({"magic": "eca-recording", "version": 9}), "format 9"),
    (msgpack.packb({"magic": "eca-recording", "version": 1}) + msgpack.packb([1, "text", b""]),
     "record 0 is not"),
    (msgpack.packb({"magic": "eca-recording", "version": 1}) + msgpack.packb([5, b"a", b""])
     + msgpack.packb([4, b"a", b""]), "record 1 goes back in time"),
])
def test_damaged_recordings_are_refused_before_anything_is_sent(tmp_path: Path, content: bytes, problem: str,
                                                                bus) -> None:
    path = tmp_path / "bad.eca"
    path.write_bytes(content)
    with pytest.raises(RecordingError, match=problem):
        read_recording(path)
    ctx = zmq.Context()
    sub = Subscriber(ctx, bus, [""])
    sub.wait_ready()
    try:
        assert eca(["replay", str(path), "--config", str(bus.config_path), "--instance", bus.instance]) == 1
        pub = Publisher(ctx, bus, "marker")
        pub.wait_ready()
        pub.publish(SetEmotion(agent="zz", name="marker"))
        got = sub.recv(5.0)
        while got is not None and got.topic.startswith("sys."):
            got = sub.recv(5.0)
        assert got is not None and got.topic == "cmd.zz.set_emotion"  # nothing from the bad file came first
        pub.close()
    finally:
        sub.close()
        ctx.term()


def test_play_publishes_the_timeline_at_its_times(bus, tmp_path: Path) -> None:
    status = tmp_path / "status.txt"
    status.write_text("header\nelement transition 3\nproperty double duration\nproperty string role\nend_header\n"
                      "0.3;talking\n0.3;listening\n0.3;silence\n")
    emotion = tmp_path / "emotion.txt"
    emotion.write_text("header\nelement transition 2\nproperty double duration\nproperty string emotion\n"
                       "property double intensity\nend_header\n0.45;happy;1\n0.45;angry;0.5\n")
    ctx = zmq.Context()
    with ServiceThread(DialogueService(bus)):
        sub = Subscriber(ctx, bus, ["state.ada.role", "state.ada.emotion"])
        sub.wait_ready()
        try:
            t0 = time.monotonic()
            assert eca(["play", str(status), str(emotion), "--config", str(bus.config_path), "--instance",
                        bus.instance, "--agent", "ada", "--no-voice"]) == 0
            seen = []
            while (got := sub.recv(0.5)) is not None:
                m = got.message
                if isinstance(m, RoleState):
                    seen.append(("role", m.role, m.t_ns))
                elif isinstance(m, EmotionState) and m.source == "dialogue":
                    seen.append(("emotion", m.name, m.t_ns))
            assert time.monotonic() - t0 >= 0.9  # it ran in real time, not all at once
        finally:
            sub.close()
            ctx.term()
    changes = [(kind, value) for kind, value, _ in seen]
    roles = [v for k, v in changes if k == "role"]
    emotions = [v for k, v in changes if k == "emotion"]
    assert roles[-3:] == ["talking", "listening", "silence"]
    assert emotions[-2:] == ["happy", "angry"]
    times = {(k, v): t for k, v, t in seen}
    gap = lambda a, b: (times[b] - times[a]) / 1e9  # noqa: E731
    assert gap(("role", "talking"), ("role", "listening")) == pytest.approx(0.3, abs=0.1)
    assert gap(("emotion", "happy"), ("emotion", "angry")) == pytest.approx(0.45, abs=0.1)


def test_play_refuses_a_bad_script_and_sends_nothing(bus, tmp_path: Path, capsys) -> None:
    bad = tmp_path / "bad.txt"
    bad.write_text("header\nelement transition 2\nproperty int duration\nend_header\n1\n")
    assert eca(["play", str(bad), "--config", str(bus.config_path), "--instance", bus.instance, "--no-voice"]) == 1
    assert "bad.txt" in capsys.readouterr().err


def test_a_gaze_cue_that_leaves_an_axis_alone_keeps_it_offline_as_live() -> None:
    from eca.agent.animator import TimelineAnimator
    from eca.agent.script import Timeline

    cues = (GazeCue(0.0, "ada", None, 10.0, 5.0), GazeCue(0.5, "ada", None, -10.0, None),
            GazeCue(1.0, "ada", None, None, -3.0))
    live = CueTranslator("ada")
    sent = [m for cue in cues for m in live.commands(cue)]
    assert [(m.yaw_deg, m.pitch_deg) for m in sent] == [(10.0, 5.0), (-10.0, 5.0), (-10.0, -3.0)]
    animator = TimelineAnimator(Timeline((), cues, 1.5, ("ada",)), "ada", seed=0, eyes="saccade+blink",
                                utterances=[], sample_rate=22_050)
    targets: list[tuple[float, float]] = []
    real = animator.gaze.set_target
    animator.gaze.set_target = lambda i, yaw, pitch, t_ns: (targets.append((yaw, pitch)), real(i, yaw, pitch, t_ns))
    animator.frame_at(1.5)
    assert targets == [(m.yaw_deg, m.pitch_deg) for m in sent]


def test_play_refuses_a_cue_the_protocol_would_refuse_before_sending_anything(bus, tmp_path: Path,
                                                                                capsys) -> None:
    import shutil

    shutil.copy(Path(__file__).parent / "data" / "scripts" / "clip.wav", tmp_path / "clip.wav")
    script = tmp_path / "long-id.xml"
    script.write_text('<dialogue agent="ada" partner="user">\n'
                      '  <turn speaker="user" duration="0.5">Hello there.</turn>\n'
                      f'  <turn speaker="ada" audio="clip.wav" id="{"x" * 80}">Hi.</turn>\n'
                      '</dialogue>\n')
    ctx = zmq.Context()
    sub = Subscriber(ctx, bus, ["cmd."])
    try:
        sub.wait_ready()
        assert eca(["play", str(script), "--config", str(bus.config_path), "--instance", bus.instance,
                    "--no-voice"]) == 1
        assert sub.recv(0.3) is None  # not even the cues before the bad one
        err = capsys.readouterr().err
        assert "say cue at 0.80 s" in err and "request_id" in err
    finally:
        sub.close()
        ctx.term()


def test_the_animator_reports_the_role_and_emotion_its_models_are_in() -> None:
    from eca.agent.animator import TimelineAnimator
    from eca.agent.script import Timeline

    cues = (RoleCue(0.5, "bob", "talking"), EmotionCue(1.0, "bob", "happy", 0.7, 0.2),
            RoleCue(1.0, "ada", "listening"), EmotionCue(1.5, "ada", "angry", 1.0, 0.2))
    animator = TimelineAnimator(Timeline((), cues, 2.0, ("bob", "ada")), "bob", seed=0, eyes="static",
                                utterances=[], sample_rate=22_050)
    states = [(f.role, f.emotion, f.emotion_intensity)
              for f in (animator.frame_at(t) for t in (0.0, 0.6, 1.0, 1.9))]
    assert states == [("silence", "natural", 1.0), ("talking", "natural", 1.0), ("talking", "happy", 0.7),
                      ("talking", "happy", 0.7)]  # the other agent's cues change nothing
