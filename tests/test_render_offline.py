"""`eca render`: deterministic offline renders of scripts, with audio, CSV and MP4."""

from __future__ import annotations

import csv
from pathlib import Path

import av
import numpy as np
import pytest

from eca.agent.face.flexors import FLEXOR_NAMES
from eca.agent.script import build_timeline
from eca.services.tools.cli import main as eca
from eca.services.tools.offline import CSV_COLUMNS, RenderSettings, animate

pytestmark = pytest.mark.gl
DATA = Path(__file__).parent / "data" / "scripts"
EYE_FLEXORS = {"look_x", "look_y", "blink_l", "blink_r", "lids_l", "lids_r"}


@pytest.fixture
def scripts(tmp_path: Path) -> list[str]:
    status = tmp_path / "status.txt"
    status.write_text(
        "header\nelement transition 3\nproperty double duration\nproperty string role\nend_header\n"
        "1.0;talking\n1.0;listening\n1.0;silence\n"
    )
    emotion = tmp_path / "emotion.txt"
    emotion.write_text(
        "header\nelement transition 2\nproperty double duration\nproperty string emotion\n"
        "property double intensity\nend_header\n1.5;surprised;1\n1.5;angry;0.8\n"
    )
    return [str(status), str(emotion), str(DATA / "paper_head.txt")]


def render(scripts: list[str], out: Path, seed: int) -> Path:
    code = eca(
        ["render", *scripts, "-o", str(out), "--seed", str(seed), "--size", "160x120", "--fps", "15", "--no-voice"]
    )
    assert code == 0
    return out.with_suffix(".csv")


TEXT_COLUMNS = ("role", "emotion")


def read_csv(path: Path) -> dict[str, np.ndarray]:
    with open(path) as fh:
        rows = list(csv.DictReader(fh))
    return {k: np.array([r[k] if k in TEXT_COLUMNS else float(r[k]) for r in rows]) for k in rows[0]}


def test_same_seed_gives_identical_csv_and_another_seed_changes_only_eyes_and_blinks(
    scripts: list[str], tmp_path: Path
) -> None:
    a = render(scripts, tmp_path / "a.mp4", seed=1)
    b = render(scripts, tmp_path / "b.mp4", seed=1)
    c = render(scripts, tmp_path / "c.mp4", seed=2)
    assert a.read_bytes() == b.read_bytes()
    one, other = read_csv(a), read_csv(c)
    changed = {name for name in FLEXOR_NAMES if not np.array_equal(one[name], other[name])}
    assert changed and changed <= EYE_FLEXORS, changed
    assert "look_x" in changed or "look_y" in changed


def test_the_video_has_every_frame_and_an_audio_track(scripts: list[str], tmp_path: Path) -> None:
    out = tmp_path / "v.mp4"
    table = read_csv(render(scripts, out, seed=0))
    with av.open(str(out)) as container:
        kinds = sorted(s.type for s in container.streams)
        frames = sum(1 for _ in container.decode(video=0))
    assert kinds == ["audio", "video"]
    assert frames == table["t_s"].size
    assert table["t_s"][1] == pytest.approx(1 / 15, abs=1e-6)


def test_emotions_and_head_follow_the_script_times(scripts: list[str]) -> None:
    timeline = build_timeline(scripts, agent="agent")
    result = animate(timeline, "agent", RenderSettings(fps=30.0, eyes="saccade"), voices=None)
    idx = {n: i for i, n in enumerate(FLEXOR_NAMES)}
    t = result.t_s
    brows = result.flexors[:, idx["brow_l"]]
    knit = result.flexors[:, idx["brows_knit"]]
    turn = result.flexors[:, idx["turn"]]
    assert brows[(t > 1.2) & (t < 1.5)].mean() > 0.3  # surprised raises the brows
    assert knit[(t > 2.6) & (t < 3.0)].mean() > 0.3  # angry knits them
    # the paper's head file: turn to 1 over 2 s, then to -1 over 3 s
    assert turn[np.searchsorted(t, 2.0)] == pytest.approx(1.0, abs=0.05)
    assert turn[np.searchsorted(t, 5.0)] == pytest.approx(-1.0, abs=0.05)
    assert turn[np.searchsorted(t, 0.1)] < turn[np.searchsorted(t, 1.0)] < turn[np.searchsorted(t, 1.9)]


def test_bad_arguments_are_refused_with_a_clear_message(scripts: list[str], tmp_path: Path, capsys) -> None:
    assert eca(["render", *scripts, "-o", str(tmp_path / "x.avi")]) == 1
    assert "must be an .mp4" in capsys.readouterr().err
    assert eca(["render", *scripts, "-o", str(tmp_path / "x.mp4"), "--size", "161x120"]) == 1
    assert "even" in capsys.readouterr().err
    bad = tmp_path / "bad.txt"
    bad.write_text("header\nend_header\n")
    assert eca(["render", str(bad), "-o", str(tmp_path / "y.mp4")]) == 1
    assert "bad.txt" in capsys.readouterr().err
    assert not (tmp_path / "y.mp4").exists()
    assert eca(["render", *scripts, "-o", str(tmp_path / "z.mp4"), "--csv", str(bad / "z.csv"), "--no-voice"]) == 1
    assert capsys.readouterr().err.strip() == f"eca render: {bad}: is a file, not a folder to write into"
    assert not (tmp_path / "z.mp4").exists()


BOB_DIALOGUE = """<?xml version="1.0" encoding="UTF-8"?>
<dialogue agent="bob" partner="user">
  <turn speaker="bob" emotion="happy" duration="1">Hello.</turn>
  <turn speaker="user" emotion="angry" intensity="0.5" duration="1">Go away.</turn>
</dialogue>
"""


def fast_render(args: list[str]) -> int:
    return eca(["render", *args, "--size", "32x24", "--fps", "10", "--no-voice"])


def test_a_dialogue_rendered_without_agent_animates_its_own_agent(tmp_path: Path) -> None:
    script = tmp_path / "bob.xml"
    script.write_text(BOB_DIALOGUE)
    assert fast_render([str(script), "-o", str(tmp_path / "bob.mp4")]) == 0
    table = read_csv(tmp_path / "bob.csv")
    t = table["t_s"]
    speaking, listening = t < 1.0, t >= 1.3  # the default gap of 0.3 s lies between the turns
    assert set(table["role"][speaking]) == {"talking"}
    assert set(table["emotion"][speaking]) == {"happy"}
    assert set(table["emotion_intensity"][speaking]) == {1.0}
    assert set(table["role"][listening]) == {"listening"}
    assert set(table["emotion"][listening]) == {"angry"}
    assert set(table["emotion_intensity"][listening]) == {0.5}
    smile = table["smile_l"]
    assert smile[(t > 0.6) & (t < 1.0)].mean() > smile[t > 1.9].mean() + 0.2  # the face follows too


def test_an_agent_option_that_disagrees_with_the_dialogue_is_refused(tmp_path: Path, capsys) -> None:
    script = tmp_path / "bob.xml"
    script.write_text(BOB_DIALOGUE)
    out = tmp_path / "ada.mp4"
    assert fast_render([str(script), "-o", str(out), "--agent", "ada"]) == 1
    err = capsys.readouterr().err
    assert f"{script}:2:1: the dialogue animates 'bob' but --agent is 'ada'" in err
    assert "nothing rendered" in err
    assert not out.exists() and not out.with_suffix(".csv").exists()
    assert fast_render([str(script), "-o", str(out), "--agent", "bob"]) == 0  # agreeing is fine


def test_the_csv_header_and_rows_read_back_in_the_documented_units(tmp_path: Path) -> None:
    script = tmp_path / "bob.xml"
    script.write_text(BOB_DIALOGUE)
    out = tmp_path / "bob.mp4"
    assert fast_render([str(script), "-o", str(out), "--eyes", "saccade+noise+blink", "--seed", "3"]) == 0
    lines = out.with_suffix(".csv").read_text().splitlines()
    assert lines[0].split(",") == ["t_s", "role", "emotion", "emotion_intensity", "eye_yaw_deg", "eye_pitch_deg",
                                   "lid", *FLEXOR_NAMES]
    assert tuple(lines[0].split(",")) == CSV_COLUMNS
    row = dict(zip(CSV_COLUMNS, lines[4].split(","), strict=True))
    assert row["t_s"] == "0.300000"  # seconds, frame 3 at 10 fps, six decimals
    assert (row["role"], row["emotion"], row["emotion_intensity"]) == ("talking", "happy", "1.000000")
    table = read_csv(out.with_suffix(".csv"))
    assert np.allclose(np.diff(table["t_s"]), 0.1)
    # the eyes in degrees: the look flexors are the same angles over the 30-degree eye range
    assert np.abs(table["eye_yaw_deg"]).max() > 0.5  # the saccades (scans over the partner's face) moved them
    assert np.all(np.abs(table["eye_yaw_deg"]) <= 30.0) and np.all(np.abs(table["eye_pitch_deg"]) <= 30.0)
    assert np.allclose(table["eye_yaw_deg"] / 30.0, table["look_x"], atol=1e-5)
    assert np.allclose(table["eye_pitch_deg"] / 30.0, table["look_y"], atol=1e-5)
    assert np.all((table["lid"] >= 0.0) & (table["lid"] <= 1.0))
    for name in FLEXOR_NAMES:
        assert np.all(np.abs(table[name]) <= 1.0), name
    assert all(len(v.split(".")[1]) == 6 for v in lines[1].split(",") if v[-1].isdigit())


def test_the_rig_frames_are_written_beside_the_csv_unless_turned_off(tmp_path: Path, capsys) -> None:
    script = tmp_path / "bob.xml"
    script.write_text(BOB_DIALOGUE)
    out = tmp_path / "bob.mp4"
    assert fast_render([str(script), "-o", str(out)]) == 0
    rig = tmp_path / "bob_rig_bob.csv"
    assert str(rig) in capsys.readouterr().out
    flexor_lines, rig_lines = out.with_suffix(".csv").read_text().splitlines(), rig.read_text().splitlines()
    assert rig_lines[0].startswith("Timecode,BlendShapeCount,EyeBlinkLeft,EyeLookDownLeft,")
    assert len(rig_lines) == len(flexor_lines) and rig_lines[2].startswith("00:00:00:06.000,61,")  # 10 fps
    elsewhere = tmp_path / "tables" / "flexors.csv"  # the rig frames follow --csv
    assert fast_render([str(script), "-o", str(tmp_path / "c.mp4"), "--csv", str(elsewhere)]) == 0
    assert (tmp_path / "tables" / "flexors_rig_bob.csv").exists()
    capsys.readouterr()
    assert fast_render([str(script), "-o", str(tmp_path / "n.mp4"), "--no-rig-csv"]) == 0
    assert (tmp_path / "n.csv").exists() and not list(tmp_path.glob("n_rig_*.csv"))
    assert "rig frames" not in capsys.readouterr().out


def test_a_single_listener_nods_at_its_partner_s_pauses_in_the_recommended_mode(tmp_path: Path) -> None:
    import dataclasses
    import wave

    from eca.agent.animator import TimelineAnimator
    from eca.agent.face.flexors import FLEXOR_INDEX
    from eca.agent.gaze.backchannel import BackchannelParams
    from eca.services.tools.offline import AUDIO_RATE, _lines, speech_events

    t = np.arange(AUDIO_RATE) / AUDIO_RATE
    buzz = sum(np.sin(2 * np.pi * 120 * h * t) / h for h in range(1, 30)) * 0.3 * (0.6 + 0.4 * np.sin(np.pi * t))
    voice = np.concatenate([np.concatenate([buzz, np.zeros(int(0.6 * AUDIO_RATE))]) for _ in range(4)])
    with wave.open(str(tmp_path / "user.wav"), "wb") as fh:
        fh.setnchannels(1)
        fh.setsampwidth(2)
        fh.setframerate(AUDIO_RATE)
        fh.writeframes((voice * 32767).astype(np.int16).tobytes())
    script = tmp_path / "listen.xml"
    script.write_text('<dialogue agent="ada"><turn speaker="user" audio="user.wav">Hm.</turn></dialogue>\n')
    timeline = build_timeline([script])
    lines = _lines(timeline, "ada", None)
    params = BackchannelParams.load()
    speech = speech_events(lines, params.min_pause_s)
    assert sum(1 for _, who, on in speech if who == "user" and not on) == 4
    nod = FLEXOR_INDEX["nod"]

    def nods(eyes: str, probability: float) -> np.ndarray:
        animator = TimelineAnimator(timeline, "ada", seed=2, eyes=eyes, utterances=[u for u, _ in lines],
                                    sample_rate=AUDIO_RATE, speech=speech,
                                    backchannel=dataclasses.replace(params, nod_probability=probability))
        return np.array([animator.frame_at(k / 30).flexors[nod] for k in range(30 * 7)])

    dips = nods("saccade+noise+blink", 0.0) - nods("saccade+noise+blink", 1.0)
    down = np.flatnonzero(dips > 0.05) / 30
    stops = [s for s, _, on in speech if not on]
    assert down.size and all(any(0 < x - s < 1.4 for s in stops) for x in down)
    assert np.array_equal(nods("saccade+blink", 0.0), nods("saccade+blink", 1.0))
