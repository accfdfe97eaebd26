"""The default head as VRM files: a VRM 1.0 and a VRM 0.x written here FROM eca/assets/default_head.glb (its
meshes, skin and ARKit-named morph targets as they are, with a VRM extension added), loaded, and drawn through the
drawing seam (`make_drawer`) at a few faces beside the .glb itself.

- VRM 1.0 (`VRMC_vrm`): humanoid bones from the head's Neck, Head, Jaw, LeftEye and RightEye nodes; preset
  expressions binding its ARKit targets (blink: EyeBlinkLeft/Right, happy: MouthSmileLeft/Right, aa: JawOpen ...);
  lookAt of bone type, with range maps that pass eca's eye range (30 degrees) through unchanged, so the eye joints
  turn as the .glb's do.
- VRM 0.x (`VRM`): the same in 0.x's shape (a humanBones list, blendShapeMaster groups with 0-100 weights,
  firstPerson lookAt of BlendShape type: lookUp/Down/Left/Right binding the EyeLook targets), and the model stored
  facing -Z as 0.x models are (x and z negated in vertices, normals, morph deltas, node translations and inverse
  binds); the loader turns it back to face +Z (avatar/loader.py).

The head's targets keep their ARKit names, so both VRMs are "Perfect Sync" faces: emotions, blink and mouth come
from the ARKit shapes, as on the .glb, and the pictures should match the .glb's but for the rasteriser's edges.
The eyes are where they differ by design: a bone lookAt turns the eye joints (as the .glb's eyes turn), an
expression lookAt moves the EyeLook shapes and leaves the eye joints still (VRM lookAt.md), so the 0.x file's
gaze is checked against its own neutral face, not against the .glb.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import moderngl
import numpy as np
import pytest

from eca.agent.face.composed import ComposedFace
from eca.agent.face.emotions import load_emotion_table
from eca.agent.face.flexors import FLEXOR_INDEX, N_FLEXORS
from eca.agent.face.frame import FlexorFrame
from eca.agent.face.settings import load_flexor_units
from eca.services.processes.avatar.loader import load_avatar
from eca.services.processes.avatar.model import LookAtType
from eca.services.processes.renderer import (
    FaceDrawer,
    HeadlessContextError,
    create_headless_context,
    make_drawer,
    read_rgb,
)
from eca.services.processes.renderer.head import DEFAULT_HEAD
from tests.support.golden import compare
from tests.support.vrm import head_document, vrm0_file, vrm1_file

pytestmark = [pytest.mark.gl, pytest.mark.skipif(not DEFAULT_HEAD.exists(), reason="the default head is not baked")]

SIZE = (320, 240)
UNITS = load_flexor_units()
# Same face, same GL, other file: the pictures come out identical here (negating x and z is exact in floats); the
# tolerance leaves room for a rounding in the loader's turn back, and is test_head_golden.py's, well under what a
# lost emotion changes (happy against neutral: RMS 5.9, 0.57 % of pixels).
MAX_RMS = 3.0  # of 255
MAX_CHANGED = 0.0025  # fraction of pixels differing by more than CHANGED_LEVEL in any channel

# -- drawing them ----------------------------------------------------------------------------------------------


def _flexors(**values: float) -> np.ndarray:
    f = np.zeros(N_FLEXORS)
    for name, value in values.items():
        f[FLEXOR_INDEX[name]] = value
    return f


FACES: dict[str, np.ndarray] = {
    "neutral": _flexors(),
    "happy": np.nan_to_num(load_emotion_table().pose("happy", 1.0), nan=0.0),
    "blink": _flexors(blink_l=1.0, blink_r=1.0),
    "jaw": _flexors(say_ah=1.0),
    "right": _flexors(look_x=0.6),  # eyes 18 degrees toward the agent's right (the viewer's left)
}
KINDS = ("glb", "vrm1", "vrm0")




@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("vrm")
    return {"glb": DEFAULT_HEAD, "vrm1": vrm1_file(tmp), "vrm0": vrm0_file(tmp)}


@pytest.fixture(scope="module")
def ctx() -> Iterator[moderngl.Context]:
    try:
        context = create_headless_context()
    except HeadlessContextError as exc:
        pytest.skip(f"no headless OpenGL context: {exc}")
    yield context
    context.release()


@pytest.fixture(scope="module")
def drawn(ctx: moderngl.Context, files: dict[str, Path]) -> Iterator[dict[str, Any]]:
    """Every kind's picture of every face (kind -> face -> RGB), and each drawer's eye centres and eye radius in
    pixels (kind -> (2, 2) array, float), the drawers kept for the pose checks."""
    pictures: dict[str, dict[str, np.ndarray]] = {}
    drawers: dict[str, FaceDrawer] = {}
    for kind in KINDS:
        drawer = drawers[kind] = make_drawer(ctx, SIZE, str(files[kind]))
        pictures[kind] = {name: read_rgb(drawer.draw(ComposedFace.from_frame(FlexorFrame(f), UNITS))).copy()
                          for name, f in FACES.items()}
    glb = drawers["glb"]
    eyes = glb.camera.measure.eyes
    centres = glb.to_pixels(eyes)
    radius = abs(glb.to_pixels(eyes[:1] + (glb.eye_radius, 0.0, 0.0))[0, 0] - centres[0, 0])
    yield {"pictures": pictures, "drawers": drawers, "eyes": centres, "eye_radius": radius}
    for drawer in drawers.values():
        drawer.release()


def changed_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rows of the pixels that differ clearly between two pictures."""
    return np.nonzero(np.abs(a.astype(np.int32) - b.astype(np.int32)).sum(axis=2) > 30)[0]


def test_both_files_load_as_vrm_of_the_default_head(files: dict[str, Path]) -> None:
    glb, one, zero = (load_avatar(files[k]) for k in KINDS)
    assert (one.format, zero.format) == ("vrm1", "vrm0")
    assert one.look_at is not None and one.look_at.type is LookAtType.BONE
    assert zero.look_at is not None and zero.look_at.type is LookAtType.EXPRESSION
    assert one.capabilities.eyes == "bones" and zero.capabilities.eyes == "vrm lookAt"
    for avatar in (one, zero):
        assert avatar.skeleton.humanoid == glb.skeleton.humanoid  # the same five face joints
        assert (avatar.capabilities.blink, avatar.capabilities.mouth) == ("arkit shapes", "arkit jawOpen")
        assert avatar.capabilities.missing == ()
        assert {"happy", "aa", "blink", "blinkLeft", "blinkRight"} <= set(avatar.expressions)
        assert [b.target for b in avatar.expressions["aa"].binds] == [head_document()[3].index("JawOpen")]
    assert {"lookUp", "lookDown", "lookLeft", "lookRight"} <= set(zero.expressions)
    # The 0.x model, stored facing -Z, is turned back: its vertices and joints are the .glb's.
    for a, b in zip(zero.primitives, glb.primitives, strict=True):
        np.testing.assert_allclose(a.positions, b.positions, atol=1e-6)
        np.testing.assert_allclose(a.normals, b.normals, atol=1e-6)
        for ta, tb in zip(a.targets, b.targets, strict=True):
            np.testing.assert_allclose(ta.positions, tb.positions, atol=1e-6)
    np.testing.assert_allclose(zero.skeleton.rest, glb.skeleton.rest, atol=1e-6)
    np.testing.assert_allclose(zero.skeleton.inverse_bind, glb.skeleton.inverse_bind, atol=1e-6)


@pytest.mark.parametrize("kind, name", [(k, n) for k in ("vrm1", "vrm0") for n in FACES
                                        if (k, n) != ("vrm0", "right")])
def test_a_vrm_draws_each_face_as_the_glb_does(drawn: dict[str, Any], kind: str, name: str) -> None:
    rms, changed = compare(drawn["pictures"][kind][name], drawn["pictures"]["glb"][name])
    assert rms <= MAX_RMS and changed <= MAX_CHANGED, f"{kind} {name}: RMS {rms:.2f}, {changed:.2%} changed"


@pytest.mark.parametrize("kind", KINDS)
def test_each_face_changes_the_picture_where_it_should(drawn: dict[str, Any], kind: str) -> None:
    pictures = drawn["pictures"][kind]
    neutral = pictures["neutral"]
    eyes_y = float(drawn["eyes"][:, 1].mean())
    r = drawn["eye_radius"]
    for name in FACES:
        if name != "neutral":
            assert compare(pictures[name], neutral)[0] > 1.0, f"{kind} {name} looks as the neutral face"
    blink = changed_rows(pictures["blink"], neutral)  # the lids: about the eyes only
    assert blink.size > 100 and np.all(np.abs(blink - eyes_y) < 2.5 * r)
    for name in ("jaw", "happy"):  # the mouth: below the eyes
        rows = changed_rows(pictures[name], neutral)
        assert rows.size > 200 and np.median(rows) > eyes_y + 0.15 * SIZE[1], name
    gaze = changed_rows(pictures["right"], neutral)  # eyes (or, by expression, the skin about them)
    assert gaze.size > 20 and np.all(np.abs(gaze - eyes_y) < 2.5 * r)


def test_an_expression_lookat_moves_the_eyelook_shapes_and_not_the_eyes(drawn: dict[str, Any]) -> None:
    """The 0.x file's gaze is by expressions (VRM lookAt.md): lookRight weighs in through its range map and moves
    the EyeLook targets; the eye joints stay as they are, so its picture is not the .glb's, whose eyes turn."""
    drawer = drawn["drawers"]["vrm0"]
    drawer.draw(ComposedFace.from_frame(FlexorFrame(FACES["right"]), UNITS))
    pose = drawer.last_pose
    names = list(drawer.avatar.expressions)
    weights = drawer.driver.expression_weights(drawer.last_frame)
    assert weights[names.index("lookRight")] == pytest.approx(0.6, abs=0.05)  # 18 of 30 degrees
    assert weights[names.index("lookLeft")] == 0.0
    eyes = {drawer.avatar.skeleton.humanoid[b] for b in ("leftEye", "rightEye")}
    assert not eyes & set(pose.turns)
    target = head_document()[3].index("EyeLookOutRight")
    morphed = [p for p, prim in enumerate(drawer.avatar.primitives) if prim.targets]
    assert morphed and all(pose.weights[p][target] == pytest.approx(0.6, abs=0.05) for p in morphed)
    rms, _ = compare(drawn["pictures"]["vrm0"]["right"], drawn["pictures"]["glb"]["right"])
    assert rms > MAX_RMS
