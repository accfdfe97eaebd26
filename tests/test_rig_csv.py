"""The rig frames of an offline render as a Live Link Face CSV (services/tools/rig_csv.py): the app's layout word
for word, its timecode, a line per frame, weights in 0..1, blinks where the flexor CSV closes the lids, the
script's emotions in their shapes, and the angles in the app's units and signs. No GL: the frames are animated
and written without drawing."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from eca.agent.rig.names import ARKIT_NAMES
from eca.agent.script import build_timeline, load_scripts
from eca.services.tools.offline import RenderSettings, animate, write_flexor_csv, write_rig_csv
from eca.services.tools.offline_conversation import animate_conversation, write_conversation_rig_csvs
from eca.services.tools.rig_csv import (
    BLEND_SHAPE_COUNT,
    LIVE_LINK_FACE_SHAPES,
    RIG_CSV_COLUMNS,
    live_link_timecode,
    rig_csv_path,
)

# The header line of a take recorded by the Live Link Face app (as the CSVs in
# alexdjulin/LiveLinkFace-CSV-Retarget-For-Motionbuilder anim/ and nmfisher/blender_livelinkface have it).
APP_HEADER = (
    "Timecode,BlendShapeCount,EyeBlinkLeft,EyeLookDownLeft,EyeLookInLeft,EyeLookOutLeft,EyeLookUpLeft,"
    "EyeSquintLeft,EyeWideLeft,EyeBlinkRight,EyeLookDownRight,EyeLookInRight,EyeLookOutRight,EyeLookUpRight,"
    "EyeSquintRight,EyeWideRight,JawForward,JawRight,JawLeft,JawOpen,MouthClose,MouthFunnel,MouthPucker,MouthRight,"
    "MouthLeft,MouthSmileLeft,MouthSmileRight,MouthFrownLeft,MouthFrownRight,MouthDimpleLeft,MouthDimpleRight,"
    "MouthStretchLeft,MouthStretchRight,MouthRollLower,MouthRollUpper,MouthShrugLower,MouthShrugUpper,"
    "MouthPressLeft,MouthPressRight,MouthLowerDownLeft,MouthLowerDownRight,MouthUpperUpLeft,MouthUpperUpRight,"
    "BrowDownLeft,BrowDownRight,BrowInnerUp,BrowOuterUpLeft,BrowOuterUpRight,CheekPuff,CheekSquintLeft,"
    "CheekSquintRight,NoseSneerLeft,NoseSneerRight,TongueOut,HeadYaw,HeadPitch,HeadRoll,LeftEyeYaw,LeftEyePitch,"
    "LeftEyeRoll,RightEyeYaw,RightEyePitch,RightEyeRoll"
)
FPS = 30.0
DIALOGUE = """<?xml version="1.0" encoding="UTF-8"?>
<dialogue agent="ada" partner="user">
  <turn speaker="ada" emotion="happy" duration="3">Hello there.<head turn="0.5" nod="-0.4" duration="1"/></turn>
  <turn speaker="user" emotion="angry" duration="3">No.<head turn="-0.5" tilt="0.5" duration="1"/></turn>
  <turn speaker="ada" emotion="surprised" duration="3">Oh!</turn>
</dialogue>
"""


def _read(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def rendered(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[dict[str, str]], list[dict[str, str]], Path]:
    """A nine-second render of one agent (blinks on): its flexor CSV's rows, its rig CSV's rows and the rig file."""
    folder = tmp_path_factory.mktemp("rig")
    script = folder / "ada.xml"
    script.write_text(DIALOGUE)
    result = animate(build_timeline([str(script)]), "ada", RenderSettings(fps=FPS, eyes="saccade+noise+blink",
                                                                          seed=0), voices=None)
    flexors, rig = folder / "ada.csv", rig_csv_path(folder / "ada.csv", "ada")
    write_flexor_csv(flexors, result)
    write_rig_csv(rig, result, FPS)
    return _read(flexors), _read(rig), rig


def _column(rows: list[dict[str, str]], name: str) -> np.ndarray:
    values: np.ndarray = np.array([float(r[name]) for r in rows], dtype=np.float64)
    return values


def test_the_header_is_the_live_link_face_apps_word_for_word(rendered) -> None:  # type: ignore[no-untyped-def]
    _, _, path = rendered
    assert path.name == "ada_rig_ada.csv"
    lines = path.read_text().split("\n")
    assert lines[0] == APP_HEADER == ",".join(RIG_CSV_COLUMNS)
    assert sorted(LIVE_LINK_FACE_SHAPES) == sorted(ARKIT_NAMES)
    assert lines[-1] == "" and all(len(line.split(",")) == len(RIG_CSV_COLUMNS) for line in lines[1:-1])
    assert {line.split(",")[1] for line in lines[1:-1]} == {str(BLEND_SHAPE_COUNT)} == {"61"}


def test_one_line_per_frame_with_the_apps_timecode(rendered) -> None:  # type: ignore[no-untyped-def]
    flexors, rig, _ = rendered
    assert len(rig) == len(flexors) > 9 * FPS
    for k, (f, r) in enumerate(zip(flexors, rig, strict=True)):
        h, m, s, frames = r["Timecode"].split(":")
        # as Unreal's LiveLinkFaceImporter reads it: seconds + frames / 60
        assert int(h) * 3600 + int(m) * 60 + int(s) + float(frames) / 60 == pytest.approx(float(f["t_s"]), abs=1e-6)
        assert r["Timecode"] == live_link_timecode(k, FPS)


def test_the_timecode_counts_sixtieths_of_a_second_at_any_frame_rate() -> None:
    assert [live_link_timecode(k, 30.0) for k in (0, 1, 29, 30, 31)] == [
        "00:00:00:00.000", "00:00:00:02.000", "00:00:00:58.000", "00:00:01:00.000", "00:00:01:02.000"]
    assert live_link_timecode(1, 60.0) == "00:00:00:01.000"
    assert live_link_timecode(1, 25.0) == "00:00:00:02.400"
    assert live_link_timecode(1, 24.0) == "00:00:00:02.500"
    assert live_link_timecode(1, 29.97) == "00:00:00:02.002"
    assert live_link_timecode(30 * 3661, 30.0) == "01:01:01:00.000"


def test_every_weight_lies_in_0_1(rendered) -> None:  # type: ignore[no-untyped-def]
    _, rig, _ = rendered
    weights = np.array([[float(r[name]) for name in LIVE_LINK_FACE_SHAPES] for r in rig])
    assert np.all((weights >= 0.0) & (weights <= 1.0))
    assert weights.max() > 0.5  # the file is not empty of motion


def test_a_blink_closes_both_eyes_where_the_flexor_csv_closes_the_lids(rendered) -> None:  # type: ignore[no-untyped-def]
    flexors, rig, _ = rendered
    lid = _column(flexors, "lid")
    # a blink lasts a few frames at 30 fps: its closed frames are those with the lids 0.9 or more closed
    closed = (_column(flexors, "blink_l") >= 0.9) & (_column(flexors, "blink_r") >= 0.9)
    assert closed.sum() >= 3, "the seed gives no blink to check"
    assert np.array_equal(closed, lid >= 0.9)
    left, right = _column(rig, "EyeBlinkLeft"), _column(rig, "EyeBlinkRight")
    assert left[closed].min() >= 0.9 and right[closed].min() >= 0.9
    assert np.all(left >= _column(flexors, "blink_l") - 1e-6) and np.all(right >= _column(flexors, "blink_r") - 1e-6)
    assert max(left[lid < 0.05].max(), right[lid < 0.05].max()) < 0.3  # open lids: at most the emotions' droop


def _settled(flexors: list[dict[str, str]], emotion: str) -> np.ndarray:
    """Frames where `emotion` is in force and its 0.5 s blend is over."""
    t = _column(flexors, "t_s")
    names = np.array([r["emotion"] for r in flexors])
    start = t[names == emotion].min()
    return (names == emotion) & (t > start + 0.6)


def test_the_scripts_emotions_show_in_their_shapes(rendered) -> None:  # type: ignore[no-untyped-def]
    flexors, rig, _ = rendered

    def mean(emotion: str, *shapes: str) -> float:
        frames = _settled(flexors, emotion)
        return float(np.mean([_column(rig, shape)[frames] for shape in shapes]))

    assert mean("happy", "MouthSmileLeft", "MouthSmileRight") > 0.7
    assert mean("happy", "BrowDownLeft", "MouthFrownLeft") == 0.0
    assert mean("angry", "BrowDownLeft", "BrowDownRight") > 0.9
    assert mean("angry", "MouthSmileLeft") == 0.0
    assert mean("surprised", "EyeWideLeft", "EyeWideRight") > 0.7
    assert mean("surprised", "BrowOuterUpLeft", "BrowOuterUpRight") > 0.8
    assert mean("surprised", "JawOpen") > 0.4


def test_angles_are_radians_in_the_apps_signs(rendered) -> None:  # type: ignore[no-untyped-def]
    flexors, rig, _ = rendered
    rad = math.radians
    assert np.allclose(_column(rig, "HeadYaw"), rad(40.0) * _column(flexors, "turn"), atol=2e-6)
    assert np.allclose(_column(rig, "HeadPitch"), -rad(25.0) * _column(flexors, "nod"), atol=2e-6)  # + = down
    assert np.allclose(_column(rig, "HeadRoll"), -rad(20.0) * _column(flexors, "tilt"), atol=2e-6)
    for eye in ("Left", "Right"):
        assert np.allclose(_column(rig, f"{eye}EyeYaw"), np.radians(_column(flexors, "eye_yaw_deg")), atol=2e-6)
        assert np.allclose(_column(rig, f"{eye}EyePitch"), -np.radians(_column(flexors, "eye_pitch_deg")), atol=2e-6)
        assert not _column(rig, f"{eye}EyeRoll").any()
    # the script's head moves arrive: turned right (+) while ada says hello, chin down (+), then left and tilted
    t = _column(flexors, "t_s")
    assert _column(rig, "HeadYaw")[(t > 1.5) & (t < 3.0)].min() > 0.3
    assert _column(rig, "HeadPitch")[(t > 1.5) & (t < 3.0)].min() > 0.1
    assert _column(rig, "HeadYaw")[(t > 4.5) & (t < 6.0)].max() < -0.3
    assert _column(rig, "HeadRoll")[(t > 4.5) & (t < 6.0)].max() < -0.1


def test_angles_move_with_the_eyelook_weights_as_in_recorded_takes(rendered) -> None:  # type: ignore[no-untyped-def]
    """In the app's takes LeftEyeYaw grows with EyeLookInLeft (and RightEyeYaw with EyeLookOutRight), and pitch with
    EyeLookDown: the same relations hold in eca's file."""
    _, rig, _ = rendered
    for eye, toward_right in (("Left", "EyeLookInLeft"), ("Right", "EyeLookOutRight")):
        away = "EyeLookOutLeft" if eye == "Left" else "EyeLookInRight"
        horizontal = _column(rig, toward_right) - _column(rig, away)
        vertical = _column(rig, f"EyeLookDown{eye}") - _column(rig, f"EyeLookUp{eye}")
        assert np.ptp(horizontal) > 0.05 and np.ptp(vertical) > 0.05  # the eyes moved both ways
        assert np.corrcoef(horizontal, _column(rig, f"{eye}EyeYaw"))[0, 1] > 0.99
        assert np.corrcoef(vertical, _column(rig, f"{eye}EyePitch"))[0, 1] > 0.99


def test_a_conversation_writes_one_file_per_agent(tmp_path: Path) -> None:
    script = tmp_path / "two.xml"
    script.write_text('<dialogue agents="ada bob">\n'
                      '  <turn speaker="ada" emotion="happy" duration="2">Hi.</turn>\n'
                      '  <turn speaker="bob" emotion="angry" duration="2">No.</turn>\n</dialogue>\n')
    run = load_scripts([script])
    result = animate_conversation(run.timeline, run.agents, RenderSettings(fps=10.0, seed=1), voices=None)
    paths = write_conversation_rig_csvs(tmp_path / "two.csv", result, 10.0)
    assert [p.name for p in paths] == ["two_rig_ada.csv", "two_rig_bob.csv"]
    ada, bob = (_read(p) for p in paths)
    assert len(ada) == len(bob) == result.t_s.size
    late = result.t_s > 3.2
    assert _column(bob, "BrowDownLeft")[late].min() > 0.9 and _column(ada, "BrowDownLeft")[late].max() == 0.0
    assert _column(ada, "MouthSmileLeft")[late].min() > 0.7
    # each file holds its own agent's head: the two turn toward each other
    for agent, rows, face in zip(result.agents, (ada, bob), result.faces, strict=True):
        assert np.allclose(_column(rows, "HeadYaw"), np.radians(face.head_deg[:, 0]), atol=2e-6), agent
