"""AvatarDriver: rig frames as morph weights and joint turns on the test faces (tests/test_avatar_files.py).

A blink sets the blink shapes (ARKit and VRM); ARKit names in three spellings reach the same target; a look left
turns the eye joints the right way by the right angle through the VRM range maps (bone type, VRM 1.0 and the
turned VRM 0.x) or as it is (plain glTF), and weighs the look expressions (expression type); an emotion blocks or
fades blink and mouth by VRM 1.0's override rules (block, blend, binary); the head turns in eca's signs, split
over neck and head; a jaw joint opens by JawOpen; and a frame costs well under a millisecond.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from eca.agent.face.composed import EyeAngles
from eca.agent.rig.frame import RigFrame
from eca.agent.rig.names import ARKIT_INDEX, ARKIT_NAMES, VRM_INDEX, viseme_index
from eca.services.processes.avatar.drive import AvatarDriver, agent_rotation
from eca.services.processes.avatar.loader import load_avatar
from eca.services.processes.avatar.model import Avatar
from tests.test_avatar_files import face, glb_bytes, vrm0_document, vrm1_document, write

FORWARD = np.array([0.0, 0.0, 1.0])  # where a model facing +Z looks
UP = np.array([0.0, 1.0, 0.0])


def frame(arkit: dict[str, float] | None = None, vrm: dict[str, float] | None = None, head: tuple = (0.0, 0.0, 0.0),
          eyes: tuple[float, float] = (0.0, 0.0), right_eye: tuple[float, float] | None = None,
          visemes: dict[str, float] | None = None) -> RigFrame:
    a = np.zeros(52)
    for name, w in (arkit or {}).items():
        a[ARKIT_INDEX[name]] = w
    v = np.zeros(18)
    for name, w in (vrm or {}).items():
        v[VRM_INDEX[name]] = w
    s = np.zeros(15)
    s[0] = 1.0
    for name, w in (visemes or {}).items():
        s[0], s[viseme_index(name)] = 0.0, w
    r = right_eye if right_eye is not None else eyes
    return RigFrame(0, a, head[0], head[1], head[2], EyeAngles(*eyes), EyeAngles(*r), s, v)


def face_weights(driver: AvatarDriver, rig: RigFrame) -> np.ndarray:
    """The skinned face quad's six morph weights."""
    pose = driver.drive(rig)
    p = next(p for p, prim in enumerate(driver.avatar.primitives) if prim.joints is not None)
    return pose.weights[p]


def gltf_face(tmp_path: Path, spelling: str = "camel", **kwargs: object) -> Avatar:
    return load_avatar(write(tmp_path, f"{spelling}.glb", face(spelling, **kwargs).builder.glb()))  # type: ignore[arg-type]


def vrm1(tmp_path: Path, look_at: str = "bone") -> Avatar:
    f = face(None)
    return load_avatar(write(tmp_path, f"v1{look_at}.vrm", glb_bytes(vrm1_document(f, look_at), bytes(f.builder.blob))))


def vrm0(tmp_path: Path, look_at: str = "Bone") -> Avatar:
    f = face(None, vrm0=True)
    return load_avatar(write(tmp_path, f"v0{look_at}.vrm", glb_bytes(vrm0_document(f, look_at), bytes(f.builder.blob))))


def degrees_between(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0))))


# --- morph weights ---------------------------------------------------------------------------------------------------

def test_an_arkit_blink_sets_the_blink_shapes(tmp_path: Path) -> None:
    driver = AvatarDriver(gltf_face(tmp_path))
    w = face_weights(driver, frame({"EyeBlinkLeft": 1.0, "EyeBlinkRight": 0.25}))
    assert w.dtype == np.float32 and w.tolist() == pytest.approx([1.0, 0.25, 0.0, 0.0, 0.0, 0.0])


def test_arkit_names_in_three_spellings_reach_the_same_targets(tmp_path: Path) -> None:
    rig = frame({"EyeBlinkLeft": 0.9, "EyeBlinkRight": 0.8, "JawOpen": 0.7, "MouthSmileLeft": 0.6,
                 "BrowInnerUp": 0.4})
    spellings = ("camel", "pascal", "raw")
    results = [face_weights(AvatarDriver(gltf_face(tmp_path, spelling)), rig) for spelling in spellings]
    assert results[0].tolist() == pytest.approx([0.9, 0.8, 0.7, 0.6, 0.0, 0.4])  # eyeLookIn: eyes turn by bones
    assert all(np.array_equal(r, results[0]) for r in results[1:])


def test_eyelook_shapes_follow_the_eyes_when_there_are_no_eye_joints(tmp_path: Path) -> None:
    names = ["eyeLookInLeft", "eyeLookOutLeft", "eyeLookInRight", "eyeLookOutRight", "eyeBlinkLeft", "eyeBlinkRight"]
    avatar = load_avatar(write(tmp_path, "f.glb", face(names=names, eyes=False).builder.glb()))
    w = face_weights(AvatarDriver(avatar), frame({"EyeLookInLeft": 0.5, "EyeLookOutRight": 0.5}))
    assert w.tolist() == pytest.approx([0.5, 0.0, 0.0, 0.5, 0.0, 0.0])


def test_visemes_drive_the_mouth_without_jawopen(tmp_path: Path) -> None:
    names = ["eyeBlinkLeft", "eyeBlinkRight", "viseme_aa", "viseme_U", "viseme_I", "viseme_PP"]
    avatar = load_avatar(write(tmp_path, "rpm.glb", face(names=names, jaw=False).builder.glb()))
    w = face_weights(AvatarDriver(avatar), frame(visemes={"aa": 0.7, "ou": 0.3}))
    assert w.tolist() == pytest.approx([0.0, 0.0, 0.7, 0.3, 0.0, 0.0])


def test_a_vrm_blink_sets_the_blink_expressions_binds(tmp_path: Path) -> None:
    for avatar in (vrm1(tmp_path), vrm0(tmp_path)):
        w = face_weights(AvatarDriver(avatar), frame(vrm={"blink": 0.6}))
        assert w[:2].tolist() == pytest.approx([0.6, 0.6]) and w[2:].tolist() == [0.0] * 4


def test_happy_blocks_the_blink_and_blends_the_mouth(tmp_path: Path) -> None:
    driver = AvatarDriver(vrm1(tmp_path))
    assert face_weights(driver, frame(vrm={"blink": 1.0, "aa": 0.8})).tolist() == pytest.approx(
        [1.0, 1.0, 0.8, 0.0, 0.0, 0.0])
    # happy (overrideBlink block, overrideMouth blend) at 0.25: the blink is gone, the mouth at 1 - 0.25
    w = face_weights(driver, frame(vrm={"happy": 0.25, "blink": 1.0, "aa": 0.8}))
    assert w.tolist() == pytest.approx([0.0, 0.0, 0.8 * 0.75, 0.25, 0.0, 0.0])
    weights = driver.expression_weights(frame(vrm={"happy": 0.25, "blink": 1.0}))
    assert weights[list(driver.avatar.expressions).index("blink")] == 0.0


def test_angry_fades_the_blink_and_a_binary_sad_snaps_and_blocks_the_mouth(tmp_path: Path) -> None:
    driver = AvatarDriver(vrm1(tmp_path))
    w = face_weights(driver, frame(vrm={"angry": 0.4, "blink": 1.0}))  # blend: blink x (1 - 0.4)
    assert w[:2].tolist() == pytest.approx([0.6, 0.6]) and w[5] == pytest.approx(0.4)
    w = face_weights(driver, frame(vrm={"sad": 0.4, "aa": 1.0}))  # binary sad below 0.5: off, no override
    assert w[2] == pytest.approx(1.0) and w[5] == 0.0
    w = face_weights(driver, frame(vrm={"sad": 0.6, "aa": 1.0}))  # over 0.5: fully on (bind 0.5), mouth blocked
    assert w[2] == 0.0 and w[5] == pytest.approx(0.5)
    w = face_weights(driver, frame(vrm={"happy": 0.3, "angry": 0.3, "blink": 1.0}))  # block and blend together
    assert w[:2].tolist() == [0.0, 0.0]


def test_custom_expressions_are_not_driven(tmp_path: Path) -> None:
    driver = AvatarDriver(vrm1(tmp_path))
    assert "smirk" in driver.avatar.expressions
    assert face_weights(driver, frame()).tolist() == [0.0] * 6


def test_a_perfect_sync_vrm_drives_its_arkit_expressions_with_their_bind_weights(tmp_path: Path) -> None:
    f = face(None)
    doc = vrm1_document(f)
    node = f.nodes["face"]
    doc["extensions"]["VRMC_vrm"]["expressions"]["custom"] = {
        "eyeBlinkLeft": {"morphTargetBinds": [{"node": node, "index": 0, "weight": 0.8}]},
        "EyeBlinkRight": {"morphTargetBinds": [{"node": node, "index": 1, "weight": 1.0}]},
        "jawOpen": {"morphTargetBinds": [{"node": node, "index": 2, "weight": 1.0}]},
        "mouthSmile_L": {"morphTargetBinds": [{"node": node, "index": 3, "weight": 1.0}]}}
    for name in ("browInnerUp", "cheekPuff", "mouthFunnel", "mouthPucker", "noseSneer_L", "noseSneer_R", "mouthClose"):
        # a "Perfect Sync" set: enough ARKit emotion shapes that ARKit, not VRM's presets, shows the emotions
        doc["extensions"]["VRMC_vrm"]["expressions"]["custom"][name] = {
            "morphTargetBinds": [{"node": node, "index": 4, "weight": 0.5}]}
    avatar = load_avatar(write(tmp_path, "ps.vrm", glb_bytes(doc, bytes(f.builder.blob))))
    driver = AvatarDriver(avatar)
    w = face_weights(driver, frame({"EyeBlinkLeft": 1.0, "JawOpen": 0.5, "MouthSmileLeft": 0.2},
                                   vrm={"happy": 1.0, "blink": 1.0, "aa": 1.0}))
    # ARKit drives; the VRM presets do not (the face has ARKit emotion shapes, ARKit blink and jawOpen)
    assert w.tolist() == pytest.approx([0.8, 0.0, 0.5, 0.2, 0.0, 0.0])
    assert driver.jaw == -1  # a JawOpen shape opens the mouth: the jaw joint stays


def test_expression_lookat_weighs_the_look_expressions_through_the_outer_map(tmp_path: Path) -> None:
    driver = AvatarDriver(vrm1(tmp_path, "expression"))
    assert driver.eyes == (-1, -1)  # no eye joint turns with an expression lookAt
    w = face_weights(driver, frame(eyes=(-20.0, 0.0)))  # to the agent's left: lookLeft, 20 / 40 x 1
    assert w[4] == pytest.approx(0.5) and w[5] == 0.0
    w = face_weights(driver, frame(eyes=(60.0, 0.0)))  # right, beyond the map: lookRight (on t5) at 1
    assert w[5] == pytest.approx(1.0) and w[4] == 0.0
    w = face_weights(driver, frame(eyes=(-20.0, 0.0), vrm={"happy": 1.0}))
    assert w[4] == pytest.approx(0.5)  # happy overrides blink and mouth, not the look


def test_vrm0_blendshape_lookat_weighs_look_expressions(tmp_path: Path) -> None:
    w = face_weights(AvatarDriver(vrm0(tmp_path, "BlendShape")), frame(eyes=(-25.0, 0.0)))
    assert w[4] == pytest.approx(0.5)  # LookLeft: 25 / 50 x 1


# --- joints ----------------------------------------------------------------------------------------------------------

def eye_directions(driver: AvatarDriver, rig: RigFrame) -> tuple[np.ndarray, np.ndarray]:
    pose = driver.drive(rig)
    return pose.turns[driver.eyes[0]] @ FORWARD, pose.turns[driver.eyes[1]] @ FORWARD


@pytest.mark.parametrize("make", [vrm1, vrm0], ids=["vrm1", "vrm0"])
def test_a_look_left_turns_the_eyes_to_the_models_left_through_the_bone_range_maps(tmp_path: Path,
                                                                                   make: object) -> None:
    avatar = make(tmp_path)  # type: ignore[operator]
    driver = AvatarDriver(avatar)
    look = avatar.look_at
    assert driver.eyes == (avatar.skeleton.humanoid["leftEye"], avatar.skeleton.humanoid["rightEye"])
    left, right = eye_directions(driver, frame(eyes=(-20.0, 0.0)))
    assert left[0] > 0 and right[0] > 0  # toward +X: the model's (and agent's) left
    outer, inner = look.horizontal_outer, look.horizontal_inner
    # the left eye turns outward (outer map), the right one inward (inner map)
    assert degrees_between(left, FORWARD) == pytest.approx(20.0 / outer.input_max_deg * outer.output_scale)
    assert degrees_between(right, FORWARD) == pytest.approx(20.0 / inner.input_max_deg * inner.output_scale)
    up, _ = eye_directions(driver, frame(eyes=(0.0, 12.0)))
    assert up[1] > 0 and degrees_between(up, FORWARD) == pytest.approx(12.0 / look.vertical_up.input_max_deg
                                                                       * look.vertical_up.output_scale)
    down, _ = eye_directions(driver, frame(eyes=(0.0, -12.0)))
    assert down[1] < 0 and degrees_between(down, FORWARD) == pytest.approx(
        12.0 / look.vertical_down.input_max_deg * look.vertical_down.output_scale)


def test_plain_gltf_eyes_turn_by_their_own_angles_with_vergence(tmp_path: Path) -> None:
    driver = AvatarDriver(gltf_face(tmp_path))
    left, right = eye_directions(driver, frame(eyes=(10.0, 0.0), right_eye=(4.0, 0.0)))
    assert left[0] < 0 and degrees_between(left, FORWARD) == pytest.approx(10.0)  # the agent's right is -X
    assert degrees_between(right, FORWARD) == pytest.approx(4.0)


def test_the_head_turns_in_ecas_signs_split_over_neck_and_head(tmp_path: Path) -> None:
    driver = AvatarDriver(gltf_face(tmp_path))
    pose = driver.drive(frame(head=(20.0, 0.0, 0.0)))
    neck, head = driver.neck, driver.head
    assert (pose.turns[neck] @ FORWARD)[0] < 0  # yaw + : toward the agent's right, -X
    assert degrees_between(pose.turns[neck] @ FORWARD, FORWARD) == pytest.approx(6.0)
    assert degrees_between(pose.turns[head] @ FORWARD, FORWARD) == pytest.approx(14.0)
    pose = driver.drive(frame(head=(0.0, 10.0, 0.0)))
    assert (pose.turns[head] @ FORWARD)[1] > 0  # pitch + : chin up
    pose = driver.drive(frame(head=(0.0, 0.0, 10.0)))
    assert (pose.turns[head] @ UP)[0] < 0  # roll + : toward the right shoulder, -X
    # yaw after pitch after roll: the look direction of a yaw and pitch is that yaw of that pitch
    direction = agent_rotation(30.0, 20.0, 10.0) @ FORWARD
    assert direction[1] == pytest.approx(np.sin(np.radians(20.0)))
    assert np.degrees(np.arctan2(-direction[0], direction[2])) == pytest.approx(30.0)


def test_local_transforms_turn_a_joint_with_a_rest_rotation_in_model_axes(tmp_path: Path) -> None:
    s = np.sqrt(0.5)  # the head bone rests turned a quarter about +X (as a Blender bone does)
    avatar = gltf_face(tmp_path, head_rotation=[s, 0.0, 0.0, s])
    driver = AvatarDriver(avatar)
    pose = driver.drive(frame(head=(30.0, 0.0, 0.0)))
    local = driver.local_transforms(pose)
    world = np.empty_like(local)
    for j, p in enumerate(avatar.skeleton.parents.tolist()):
        world[j] = local[j] if p < 0 else world[p] @ local[j]
    rest_world = np.empty_like(local)
    for j, p in enumerate(avatar.skeleton.parents.tolist()):
        rest_world[j] = avatar.skeleton.rest[j] if p < 0 else rest_world[p] @ avatar.skeleton.rest[j]
    head = driver.head
    # the head's frame is its rest frame turned by the neck's and its own model-axes turns
    expected = pose.turns[driver.neck] @ pose.turns[head] @ rest_world[head][:3, :3]
    assert np.allclose(world[head][:3, :3], expected, atol=1e-9)
    assert degrees_between(world[head][:3, :3] @ np.linalg.inv(rest_world[head][:3, :3]) @ FORWARD,
                           FORWARD) == pytest.approx(30.0)


def test_a_jaw_joint_opens_by_jawopen_when_no_shape_does(tmp_path: Path) -> None:
    names = ["eyeBlinkLeft", "eyeBlinkRight", "mouthSmileLeft", "browInnerUp", "x", "y"]
    avatar = load_avatar(write(tmp_path, "jaw.glb", face(names=names).builder.glb()))
    assert avatar.capabilities.mouth == "jaw bone"
    driver = AvatarDriver(avatar, jaw_open_deg=20.0)
    pose = driver.drive(frame({"JawOpen": 0.5}))
    chin = pose.turns[driver.jaw] @ FORWARD
    assert chin[1] < 0 and degrees_between(chin, FORWARD) == pytest.approx(10.0)
    assert AvatarDriver(gltf_face(tmp_path)).jaw == -1  # a JawOpen shape: the jaw joint stays


def test_driver_options_are_checked(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="neck_share"):
        AvatarDriver(gltf_face(tmp_path), neck_share=1.5)


def test_all_52_arkit_shapes_reach_their_targets(tmp_path: Path) -> None:
    """Every ARKit shape of a Perfect Sync face takes its weight from the rig frame (its cost per frame is part of
    the head's frame in bench/render.py --head)."""
    avatar = load_avatar(write(tmp_path, "arkit52.glb", face(names=list(ARKIT_NAMES)).builder.glb()))
    weights = np.linspace(0.01, 0.52, 52)
    rig = frame(dict(zip(ARKIT_NAMES, weights, strict=True)), head=(10.0, 5.0, 2.0), eyes=(8.0, -3.0))
    got = face_weights(AvatarDriver(avatar), rig)
    looks = [i for i, name in enumerate(ARKIT_NAMES) if name.startswith("EyeLook")]
    expected = weights.copy()
    expected[looks] = got[looks]  # the eyeLooks follow the eye angles, not the frame's weights
    assert got == pytest.approx(expected, abs=1e-6)
