"""The emotion table: the paper's nine poses as data, intensity scaling, and config errors."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from eca.agent.config import ConfigError
from eca.agent.face.emotions import PAPER_EMOTIONS, load_emotion_table
from eca.agent.face.flexors import FLEXOR_INDEX, N_FLEXORS

TABLE = load_emotion_table()
EXPRESSIONS = [name for name in PAPER_EMOTIONS if name != "natural"]


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "bad_emotions.toml"
    path.write_text(text)
    return path


def _valid_table_text(**replace: str) -> str:
    """A minimal valid table; `replace` swaps the body of one emotion."""
    bodies = {name: "smile_l = 0.5" for name in PAPER_EMOTIONS}
    bodies["natural"] = "smile_l = 0.0"
    bodies["half-angry"] = 'like = "angry"\nintensity = 0.5'
    bodies.update({name.replace("_", "-"): body for name, body in replace.items()})
    return "\n".join(f"[{name}]\n{body}\n" for name, body in bodies.items())


def test_the_default_table_holds_the_papers_nine_emotions() -> None:
    assert set(PAPER_EMOTIONS) <= set(TABLE.names)
    assert len(PAPER_EMOTIONS) == 9


def test_poses_are_float_vectors_of_every_flexor_within_range() -> None:
    for name in TABLE.names:
        pose = TABLE.pose(name)
        assert pose.shape == (N_FLEXORS,) and pose.dtype == np.float64
        cared = pose[~np.isnan(pose)]
        assert np.all((cared >= -1.0) & (cared <= 1.0)), name


def test_the_natural_face_relaxes_every_expression_flexor_and_leaves_head_and_eyes_alone() -> None:
    natural = TABLE.pose("natural")
    for flexor in ("brow_l", "brows_knit", "lids_r", "smile_l", "sneer_r", "say_ah"):
        assert natural[FLEXOR_INDEX[flexor]] == 0.0
    for flexor in ("turn", "look_x", "look_y", "blink_l"):
        assert np.isnan(natural[FLEXOR_INDEX[flexor]])


def test_the_nine_poses_are_distinct_from_each_other() -> None:
    for a, b in itertools.combinations(PAPER_EMOTIONS, 2):
        pa, pb = np.nan_to_num(TABLE.pose(a)), np.nan_to_num(TABLE.pose(b))
        assert np.max(np.abs(pa - pb)) >= 0.2, (a, b)


@pytest.mark.parametrize(
    ("emotion", "cue", "sign"),
    [
        ("happy", "smile_l", +1),
        ("happy", "lids_l", -1),
        ("surprised", "brow_l", +1),
        ("surprised", "lids_r", +1),
        ("surprised", "say_ah", +1),
        ("angry", "brow_r", -1),
        ("angry", "brows_knit", +1),
        ("angry", "lids_l", -1),
        ("disappointed", "smile_r", -1),
        ("disappointed", "nod", -1),
        ("disappointed", "brows_knit", +1),
        ("frightened", "brow_l", +1),
        ("frightened", "brows_knit", +1),
        ("frightened", "lids_l", +1),
        ("arrogant", "nod", +1),
        ("arrogant", "lids_r", -1),
        ("annoyed", "brows_knit", +1),
        ("annoyed", "sneer_l", +1),
    ],
)
def test_each_emotion_shows_its_classic_cue(emotion: str, cue: str, sign: int) -> None:
    assert sign * TABLE.pose(emotion)[FLEXOR_INDEX[cue]] >= 0.2


def test_arrogant_and_annoyed_are_one_sided() -> None:
    arrogant = TABLE.pose("arrogant")
    assert arrogant[FLEXOR_INDEX["smile_l"]] - arrogant[FLEXOR_INDEX["smile_r"]] > 0.3
    annoyed = TABLE.pose("annoyed")
    assert annoyed[FLEXOR_INDEX["brow_r"]] - annoyed[FLEXOR_INDEX["brow_l"]] > 0.4


def test_half_angry_is_angry_at_half_intensity() -> None:
    np.testing.assert_allclose(TABLE.pose("half-angry"), TABLE.pose("angry", 0.5), equal_nan=True)
    np.testing.assert_allclose(TABLE.pose("half-angry", 0.5), TABLE.pose("angry", 0.25), equal_nan=True)


def test_half_angry_follows_angry_when_the_file_changes_angry(tmp_path: Path) -> None:
    table = load_emotion_table(_write(tmp_path, _valid_table_text(angry="brow_l = -1.0")))
    assert table.pose("half-angry")[FLEXOR_INDEX["brow_l"]] == pytest.approx(-0.5)


def test_underscore_and_case_are_accepted_in_names() -> None:
    np.testing.assert_array_equal(TABLE.pose("Half_Angry"), TABLE.pose("half-angry"))


@pytest.mark.parametrize("emotion", EXPRESSIONS)
def test_intensity_zero_is_natural_and_one_is_the_full_pose(emotion: str) -> None:
    natural = np.nan_to_num(TABLE.pose("natural"))
    zero = TABLE.pose(emotion, 0.0)
    cared = ~np.isnan(zero)
    np.testing.assert_allclose(zero[cared], natural[cared])
    np.testing.assert_array_equal(TABLE.pose(emotion, 1.0), TABLE.pose(emotion))


@given(emotion=st.sampled_from(EXPRESSIONS), intensity=st.floats(0.0, 1.0))
def test_a_blend_lies_between_natural_and_the_full_emotion(emotion: str, intensity: float) -> None:
    natural = np.nan_to_num(TABLE.pose("natural"))
    full = TABLE.pose(emotion)
    blend = TABLE.pose(emotion, intensity)
    cared = ~np.isnan(full)
    assert np.array_equal(np.isnan(blend), np.isnan(full))
    low = np.minimum(natural, full)[cared] - 1e-12
    high = np.maximum(natural, full)[cared] + 1e-12
    assert np.all((blend[cared] >= low) & (blend[cared] <= high))
    # linear in intensity: the distance to natural scales with it
    np.testing.assert_allclose(blend[cared] - natural[cared], intensity * (full - natural)[cared], atol=1e-12)


def test_unknown_emotion_lists_the_known_names() -> None:
    with pytest.raises(ValueError, match=r"unknown emotion 'sad'.*happy.*frightened"):
        TABLE.pose("sad")


@pytest.mark.parametrize("intensity", [-0.1, 1.5, float("nan")])
def test_intensity_outside_zero_one_is_rejected(intensity: float) -> None:
    with pytest.raises(ValueError, match="intensity"):
        TABLE.pose("happy", intensity)


def test_returned_poses_cannot_corrupt_the_table() -> None:
    pose = TABLE.pose("happy")
    pose[:] = 0.0
    assert TABLE.pose("happy")[FLEXOR_INDEX["smile_l"]] > 0.5


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("smile_x = 0.5", r"\[happy\] smile_x: unknown flexor"),
        ("smile_l = 1.5", r"\[happy\] smile_l: 1.5 lies outside"),
        ('smile_l = "lots"', r"\[happy\] smile_l: must be a number"),
        ("smile_l = true", r"\[happy\] smile_l: must be a number"),
    ],
)
def test_a_bad_flexor_value_names_file_emotion_and_key(tmp_path: Path, body: str, message: str) -> None:
    path = _write(tmp_path, _valid_table_text(happy=body))
    with pytest.raises(ConfigError, match=message) as caught:
        load_emotion_table(path)
    assert str(path) in str(caught.value)


def test_a_missing_emotion_is_named(tmp_path: Path) -> None:
    text = _valid_table_text().replace("[frightened]", "[scared]")
    with pytest.raises(ConfigError, match="missing emotion.*frightened"):
        load_emotion_table(_write(tmp_path, text))


def test_a_missing_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="nowhere.toml: config file not found"):
        load_emotion_table(tmp_path / "nowhere.toml")


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ('like = "furious"\nintensity = 0.5', r"\[half-angry\] like: unknown emotion 'furious'"),
        ('like = "angry"\nintensity = 2.0', r"\[half-angry\] intensity"),
        ('like = "angry"\nbrow_l = 0.1', r"\[half-angry\]: a reference .* cannot also set flexors"),
        ('like = "half-angry"', r"circular reference half-angry -> half-angry"),
    ],
)
def test_bad_references_are_named(tmp_path: Path, body: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_emotion_table(_write(tmp_path, _valid_table_text(half_angry=body)))


def test_an_entry_that_is_not_a_table_is_named(tmp_path: Path) -> None:
    text = "happy = 3\n" + _valid_table_text().replace("[happy]\nsmile_l = 0.5\n", "")
    with pytest.raises(ConfigError, match=r"\[happy\] must be a table"):
        load_emotion_table(_write(tmp_path, text))


def test_an_emotion_is_a_constant_action() -> None:
    action = TABLE.action("happy", 0.5)
    np.testing.assert_array_equal(action.values_at(0), TABLE.pose("happy", 0.5))
    np.testing.assert_array_equal(action.values_at(10**12), action.values_at(0))
