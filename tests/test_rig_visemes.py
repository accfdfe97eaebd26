"""Visemes and VRM vowels from the five mouth weights, and the rig config's errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from eca.agent.config import ConfigError, load_toml
from eca.agent.lipsync import MOUTH_FLEXORS, VISEMES, LipSyncConfig
from eca.agent.rig import VISEME_NAMES, load_rig_config
from eca.agent.rig.config import parse_rig_config
from eca.agent.rig.names import VRM_VOWELS
from eca.agent.rig.visemes import MOUTH_SHAPES

TABLE = load_rig_config().visemes
LIPSYNC_VISEME = {"open": "aa", "rounded": "ou", "spread": "ih", "closed": "PP", "fricative": "FF"}
LIPSYNC_VOWEL = {"open": "aa", "rounded": "ou", "spread": "ih"}


def test_the_mouth_shapes_are_the_lip_syncs() -> None:
    assert MOUTH_SHAPES == MOUTH_FLEXORS


@pytest.mark.parametrize("jaw", [1.0, 0.6, 0.3])
@pytest.mark.parametrize("shape", VISEMES)
def test_each_lip_sync_shape_reads_as_its_viseme(shape: str, jaw: float) -> None:
    # The lip-sync's mouth for each of its visemes, with say_ah scaled by the jaw opening as the estimator does.
    row = np.array(LipSyncConfig.load().viseme_table[VISEMES.index(shape)])
    row[0] *= jaw
    visemes, vowels = TABLE.weights(row[None, :])
    expected = LIPSYNC_VISEME[shape]
    assert VISEME_NAMES[int(np.argmax(visemes[0]))] == expected
    assert visemes[0, VISEME_NAMES.index(expected)] >= 0.5
    if shape in LIPSYNC_VOWEL:
        assert VRM_VOWELS[int(np.argmax(vowels[0]))] == LIPSYNC_VOWEL[shape]
    else:  # a closed or fricative mouth is no vowel
        assert vowels[0].sum() == 0.0


def test_each_prototype_is_its_own_best_match() -> None:
    visemes, _ = TABLE.weights(TABLE.prototypes)
    assert [VISEME_NAMES[i] for i in np.argmax(visemes, axis=1)] == list(VISEME_NAMES[1:])


def test_a_mouth_at_rest_is_silence() -> None:
    visemes, vowels = TABLE.weights(np.zeros((1, 5)))
    assert visemes[0, 0] == 1.0 and visemes[0, 1:].sum() == 0.0 and vowels.sum() == 0.0
    quiet, _ = TABLE.weights(np.array([[0.5 * TABLE.rest_span, 0, 0, 0, 0]]))
    assert quiet[0, 0] == pytest.approx(0.5)  # half way to fully active


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0, allow_nan=False), min_size=5, max_size=5))
def test_weights_are_bounded_and_sum_to_one(mouth: list[float]) -> None:
    visemes, vowels = TABLE.weights(np.array([mouth]))
    assert np.all((visemes >= 0.0) & (visemes <= 1.0)) and visemes.sum() == pytest.approx(1.0)
    opening = max(0.0, *mouth[:3]) * (1.0 - max(0.0, *mouth[3:]))
    assert np.all(vowels >= 0.0) and vowels.sum() == pytest.approx(opening)


# -- config errors name the file and the key ---------------------------------------------------------------------


def _document() -> dict:  # type: ignore[type-arg]
    return load_toml("rig")


def _fails(document: dict, match: str) -> None:  # type: ignore[type-arg]
    with pytest.raises(ConfigError, match=match):
        parse_rig_config(document, "rig.toml")


def test_config_errors() -> None:
    doc = _document()
    del doc["arkit"]["JawOpen"]
    _fails(doc, r"rig.toml: \[arkit\]: missing row\(s\) JawOpen")
    doc = _document()
    doc["arkit"]["JawOpne"] = {}
    _fails(doc, r"unknown row 'JawOpne'; did you mean JawOpen")
    doc = _document()
    doc["arkit"]["JawOpen"] = {"say_ah": 1.0}
    _fails(doc, r"\[arkit\] JawOpen: 'say_ah': write 'say_ah\+' or 'say_ah-'")
    doc = _document()
    doc["arkit"]["JawOpen"] = {"say_uh+": 1.0}
    _fails(doc, r"unknown flexor 'say_uh'")
    doc = _document()
    doc["arkit"]["JawOpen"] = {"say_ah+": "1"}
    _fails(doc, r"'say_ah\+' must be a finite number")
    doc = _document()
    doc["arkit"]["EyeLookInLeft"] = {}
    _fails(doc, r"EyeLookInLeft: the eyeLook shapes come from the eye angles")
    doc = _document()
    doc["eye_look"]["in_deg"] = 0.0
    _fails(doc, r"\[eye_look\]: 'in_deg' must be a finite number > 0")
    doc = _document()
    del doc["vrm_look_at"]["vertical_up"]["output_scale"]
    _fails(doc, r"\[vrm_look_at\] vertical_up: missing key 'output_scale'")
    doc = _document()
    doc["visemes"]["prototypes"]["PP"] = {"say_mm": 2.0}
    _fails(doc, r"\[visemes\].prototypes PP: 'say_mm' must lie in \[0, 1\]")
    doc = _document()
    doc["visemes"]["sharpness"] = 1000.0
    _fails(doc, r"'sharpness' must be at most 300")
    doc = _document()
    doc["vrm_vowels"]["ee"] = "sil"
    _fails(doc, r"\[vrm_vowels\] ee: unknown viseme 'sil'")
    doc = _document()
    doc["vrm_emotions"]["relaxed"] = []
    _fails(doc, r"\[vrm_emotions\] relaxed: must be")


def test_a_user_config_replaces_the_shipped_one(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    text = (Path(load_rig_config().source)).read_text().replace('JawOpen = { "say_ah+" = 1.0 }',
                                                               'JawOpen = { "say_ah+" = 0.5 }')
    (tmp_path / "rig.toml").write_text(text)
    monkeypatch.setenv("ECA_CONFIG_DIR", str(tmp_path))
    config = load_rig_config()
    assert config.source == str(tmp_path / "rig.toml")
    assert config.arkit.row("JawOpen") == [{"say_ah+": 0.5}]
    assert config.vrm_emotions.row("relaxed")[2] == {"smile_l+": -1.0, "smile_r+": -1.0, "bias": 1.6}
