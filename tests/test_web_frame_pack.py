"""The face frames of many agents posed and packed at once (AvatarDriver.drive_many, BrowserFace.pack_many): each
row is what that agent's frame alone gives, and a packed frame reads back (browser_face.unpack) as the pose: its
weights to the byte, its joints' quaternions as their rotations."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from eca.agent.rig.frame import RigBatch
from eca.services.processes.avatar.drive import AvatarDriver
from eca.services.processes.avatar.loader import DEFAULT_HEAD, load_avatar
from eca.services.processes.avatar.model import Avatar
from eca.services.processes.web.browser_face import MARK, VOICED, BrowserFace, FrameLayout, unpack
from tests.test_avatar_drive import gltf_face, vrm0, vrm1


def random_batch(n: int, seed: int) -> RigBatch:
    """`n` frames over the ranges a face reaches, some with no roll (a case of its own) and eyes either side."""
    rng = np.random.default_rng(seed)
    head = rng.uniform(-40.0, 40.0, (n, 3))
    head[::3, 2] = 0.0
    visemes = rng.dirichlet(np.ones(15), n)
    return RigBatch(t_ns=0, arkit=rng.uniform(0.0, 1.0, (n, 52)), head_deg=head,
                    eyes_deg=rng.uniform(-30.0, 30.0, (n, 4)), visemes=visemes, vrm=rng.uniform(0.0, 1.0, (n, 18)))


AVATARS = {
    "default head": lambda tmp: load_avatar(DEFAULT_HEAD),
    "glTF face": gltf_face,
    "VRM 1.0, bone lookAt": lambda tmp: vrm1(tmp, "bone"),
    "VRM 1.0, expression lookAt": lambda tmp: vrm1(tmp, "expression"),
    "VRM 0.x": lambda tmp: vrm0(tmp),
}


def avatar(name: str, tmp_path: Path) -> Avatar:
    return AVATARS[name](tmp_path)  # type: ignore[no-untyped-call]


@pytest.mark.parametrize("name", sorted(AVATARS))
def test_each_row_of_a_batch_is_its_frame_driven_alone(name: str, tmp_path: Path) -> None:
    driver = AvatarDriver(avatar(name, tmp_path))
    batch = random_batch(24, seed=len(name))
    rows = [5, 0, 17, 3, 3, 23]  # any rows, in any order, repeated: no row reaches another
    many = driver.drive_many(batch, rows)
    assert many.flat.shape == (len(rows), driver.n_targets)
    for k, row in enumerate(rows):
        one = driver.drive(batch.frame(row))
        np.testing.assert_allclose(many.flat[k], one.flat, rtol=0, atol=1e-6)
        assert set(many.local) == set(one.local)
        for joint, local in one.local.items():
            np.testing.assert_allclose(many.local[joint][k], local[:3, :3], rtol=0, atol=1e-12)


def rotation_of(q: np.ndarray) -> np.ndarray:
    """The rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


@pytest.mark.parametrize("name", ["default head", "VRM 0.x", "VRM 1.0, bone lookAt"])
def test_packed_frames_read_back_as_the_pose(name: str, tmp_path: Path) -> None:
    face = BrowserFace(avatar(name, tmp_path), (640, 480))
    batch = random_batch(40, seed=7)
    rows = list(range(0, 40, 3))
    slots = [100 + r for r in rows]
    voiced = [r % 2 == 0 for r in rows]
    packed = face.pack_many(batch, rows, slots, seq=9, time_ms=3.9e12 + 0.25, voiced=voiced, mark=True)
    layout = FrameLayout(face.layout.n_weights, face.layout.n_joints)
    turn = np.diag([-1.0, 1.0, -1.0]) if face.avatar.format == "vrm0" else np.eye(3)  # a VRM 0.x file's own frame
    for k, row in enumerate(rows):
        slot, flags, seq, time_ms, weights, quats = unpack(packed[k], layout)
        assert (slot, flags, seq, time_ms) == (slots[k], VOICED * voiced[k] | MARK, 9, 3.9e12 + 0.25)
        pose = face.driver.drive(batch.frame(row))
        assert np.abs(weights - pose.flat).max() <= 0.5 / 255 + 1e-6  # each weight to the nearest byte
        assert (quats[:, 3] >= 0).all()  # one sign for one rotation
        for j, joint in enumerate(face.joints):
            local = pose.local.get(joint, face.avatar.skeleton.rest[joint])[:3, :3]
            want = turn @ (local / np.linalg.norm(local, axis=0)) @ turn
            np.testing.assert_allclose(rotation_of(quats[j]), want, atol=2e-4)
