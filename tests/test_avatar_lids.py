"""The lids follow the gaze on a head whose eyes turn by their joints: the default head's eyeLook shapes move the
lids and the skin around the eyes (not the eyeballs, which ride the eye joints), so they are driven with the
joints; a shape that moves the eyeballs themselves is not (the eye would turn twice)."""

from __future__ import annotations

import numpy as np

from eca.agent.face.composed import ComposedFace, EyeAngles
from eca.agent.face.frame import FlexorFrame
from eca.agent.face.settings import load_flexor_units
from eca.agent.rig import Retargeter
from eca.services.processes.avatar.drive import AvatarDriver, moves_the_eyeballs
from eca.services.processes.avatar.loader import load_avatar
from eca.services.processes.avatar.model import MorphTarget, Primitive
from eca.services.processes.renderer.head.drawer import DEFAULT_HEAD


def test_looking_down_lowers_the_lids_while_the_eye_joints_turn() -> None:
    avatar = load_avatar(DEFAULT_HEAD)
    driver = AvatarDriver(avatar)
    assert avatar.capabilities.eyes == "bones"
    down = ComposedFace.from_frame(FlexorFrame.neutral(), load_flexor_units(), EyeAngles(0.0, -20.0))
    pose = driver.drive(Retargeter.load().retarget(down))
    skin = next(p for p, prim in enumerate(avatar.primitives) if prim.joints is not None and prim.targets)
    names = avatar.shapes
    looks = [t for p, t in names["EyeLookDownLeft"] + names["EyeLookDownRight"] if p == skin]
    assert looks and all(pose.weights[skin][t] > 0.5 for t in looks)  # 20 of the 30 degrees: about 0.67
    assert set(driver.eyes) <= set(pose.turns) and -1 not in driver.eyes  # ... and the eyes turn by their joints


def test_a_shape_that_moves_the_eyeball_is_told_from_one_that_moves_the_lids() -> None:
    positions = np.zeros((4, 3), np.float32)
    lids = np.array([[0, 0.01, 0], [0, 0.01, 0], [0, 0, 0], [0, 0, 0]], np.float32)  # the vertices on the head
    ball = np.array([[0, 0, 0], [0, 0, 0], [0.01, 0, 0], [0.01, 0, 0]], np.float32)  # the ones on the eye joint
    prim = Primitive(positions, positions.copy(), np.array([0, 1, 2], np.uint32), 0,
                     joints=np.array([[1, 0, 0, 0], [1, 0, 0, 0], [3, 0, 0, 0], [3, 0, 0, 0]], np.uint16),
                     weights=np.array([[1, 0, 0, 0]] * 4, np.float32),
                     targets=(MorphTarget("EyeLookDownLeft", lids), MorphTarget("EyeLookInLeft", ball)))
    assert not moves_the_eyeballs(prim, 0, {3}) and moves_the_eyeballs(prim, 1, {3})
    rigid = Primitive(positions, positions.copy(), np.array([0, 1, 2], np.uint32), 0, node=3,
                      targets=(MorphTarget("EyeLookInLeft", ball),))
    assert moves_the_eyeballs(rigid, 0, {3}) and not moves_the_eyeballs(rigid, 0, {4})
