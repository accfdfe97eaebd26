"""The rig vocabularies: ARKit's canonical order (the Live Link packet's), every spelling, visemes, VRM 1.0 and 0.x."""

from __future__ import annotations

import pytest

from eca.agent.rig import (
    ARKIT_NAMES,
    VISEME_NAMES,
    VRM0_NAMES,
    VRM_NAMES,
    arkit_index,
    arkit_names,
    canonical_arkit_name,
    viseme_index,
    viseme_names,
    vrm_index,
    vrm_names,
)
from eca.agent.rig.names import VRM0_TO_VRM1, ArkitSpelling, mirror_name


def test_arkit_order_is_unreals_ear_face_blend_shape() -> None:
    # Indices as JimWest/PyLiveLinkFace's FaceBlendShape and Epic's EARFaceBlendShape number them.
    assert len(ARKIT_NAMES) == len(set(ARKIT_NAMES)) == 52
    expected = {"EyeBlinkLeft": 0, "EyeWideLeft": 6, "EyeBlinkRight": 7, "EyeWideRight": 13, "JawForward": 14,
                "JawOpen": 17, "MouthClose": 18, "MouthSmileLeft": 23, "MouthRollLower": 31, "MouthPressLeft": 35,
                "MouthUpperUpRight": 40, "BrowDownLeft": 41, "BrowInnerUp": 43, "CheekPuff": 46,
                "NoseSneerRight": 50, "TongueOut": 51}
    assert {name: ARKIT_NAMES.index(name) for name in expected} == expected


def test_arkit_spellings() -> None:
    camel, raw = arkit_names("camel"), arkit_names("raw")
    assert arkit_names() == arkit_names("pascal") == ARKIT_NAMES
    assert camel[0] == "eyeBlinkLeft" and raw[0] == "eyeBlink_L"
    assert raw[ARKIT_NAMES.index("MouthSmileRight")] == "mouthSmile_R"
    # Whole-jaw and whole-mouth movements are no sides: ARKit spells them in full.
    assert raw[ARKIT_NAMES.index("JawLeft")] == "jawLeft" and raw[ARKIT_NAMES.index("MouthRight")] == "mouthRight"
    assert raw[ARKIT_NAMES.index("BrowInnerUp")] == "browInnerUp"
    spellings: tuple[ArkitSpelling, ...] = ("pascal", "camel", "raw")
    for spelling in spellings:
        names = arkit_names(spelling)
        assert [arkit_index(n) for n in names] == list(range(52))
    with pytest.raises(ValueError, match="spelling"):
        arkit_names("snake")  # type: ignore[arg-type]


@pytest.mark.parametrize("name", ["eyeBlinkLeft", "EyeBlinkLeft", "eyeBlink_L", "EYEBLINK_L", "eye_blink_left",
                                  " eyeblinkleft ", "eyeBlink.L"])
def test_any_spelling_finds_the_same_shape(name: str) -> None:
    assert arkit_index(name) == 0
    assert canonical_arkit_name(name) == "EyeBlinkLeft"


def test_an_unknown_name_lists_close_matches() -> None:
    with pytest.raises(ValueError, match="EyeBlinkLeft"):
        arkit_index("eyeBlinkLft")
    with pytest.raises(ValueError, match="unknown ARKit blendshape name 'frobnicate'"):
        arkit_index("frobnicate")
    with pytest.raises(ValueError, match="string"):
        arkit_index(3)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="viseme"):
        viseme_index("zz")
    with pytest.raises(ValueError, match="blinkLeft"):
        vrm_index("blinkLef")


def test_visemes() -> None:
    assert VISEME_NAMES == ("sil", "PP", "FF", "TH", "DD", "kk", "CH", "SS", "nn", "RR", "aa", "E", "ih", "oh", "ou")
    gltf = viseme_names("gltf")
    assert gltf[0] == "viseme_sil" and gltf[-4:] == ("viseme_E", "viseme_I", "viseme_O", "viseme_U")
    assert [viseme_index(n) for n in gltf] == list(range(15))
    assert viseme_index("AA") == viseme_index("viseme_aa") == VISEME_NAMES.index("aa")
    assert viseme_index("I") == VISEME_NAMES.index("ih")
    with pytest.raises(ValueError, match="spelling"):
        viseme_names("ovr")  # type: ignore[arg-type]


def test_vrm_names_in_both_versions() -> None:
    assert vrm_names() == VRM_NAMES and len(VRM_NAMES) == 18
    assert vrm_names(0) == VRM0_NAMES and len(VRM0_NAMES) == 17
    assert "surprised" not in {VRM0_TO_VRM1[n] for n in VRM0_NAMES}
    for v0, v1 in VRM0_TO_VRM1.items():
        assert vrm_index(v0) == vrm_index(v1) == VRM_NAMES.index(v1)
    assert vrm_index("Joy") == VRM_NAMES.index("happy") and vrm_index("fun") == VRM_NAMES.index("relaxed")
    assert vrm_index("A") == VRM_NAMES.index("aa") and vrm_index("E") == VRM_NAMES.index("ee")
    assert vrm_index("BLINK_R") == VRM_NAMES.index("blinkRight")
    with pytest.raises(ValueError, match="version"):
        vrm_names(2)


def test_mirror_names() -> None:
    assert mirror_name("EyeLookInLeft") == "EyeLookInRight"
    assert mirror_name("lookRight") == "lookLeft"
    assert mirror_name("JawOpen") == "JawOpen"
