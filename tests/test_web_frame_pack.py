"""The face frames of many agents packed at once (BrowserFace.pack_many, AvatarDriver.drive_many) are the frames
packed one by one (pack, drive): the web service packs a tick's frames in one batch per avatar."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from eca.agent.rig.frame import RigBatch
from eca.services.processes.avatar.drive import AvatarDriver
from eca.services.processes.avatar.loader import DEFAULT_HEAD, load_avatar
from eca.services.processes.avatar.model import Avatar
from eca.services.processes.web.browser_face import BrowserFace, FrameLayout, unpack
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
def test_drive_many_is_drive_row_by_row(name: str, tmp_path: Path) -> None:
    driver = AvatarDriver(avatar(name, tmp_path))
    batch = random_batch(24, seed=len(name))
    rows = [5, 0, 17, 3, 3, 23]  # any rows, in any order, repeated
    many = driver.drive_many(batch, rows)
    assert many.flat.shape == (len(rows), driver.n_targets)
    for k, row in enumerate(rows):
        one = driver.drive(batch.frame(row))
        np.testing.assert_allclose(many.flat[k], one.flat, rtol=0, atol=1e-6)
        assert set(many.local) == set(one.local)
        for joint, local in one.local.items():
            np.testing.assert_allclose(many.local[joint][k], local[:3, :3], rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ["default head", "VRM 0.x", "VRM 1.0, bone lookAt"])
def test_pack_many_gives_the_frames_pack_gives(name: str, tmp_path: Path) -> None:
    face = BrowserFace(avatar(name, tmp_path), (640, 480))
    batch = random_batch(40, seed=7)
    rows = list(range(0, 40, 3))
    slots = [100 + r for r in rows]
    voiced = [r % 2 == 0 for r in rows]
    packed = face.pack_many(batch, rows, slots, seq=9, time_ms=3.9e12 + 0.25, voiced=voiced, mark=True)
    layout = FrameLayout(face.layout.n_weights, face.layout.n_joints)
    for k, row in enumerate(rows):
        one = face.pack(batch.frame(row), slots[k], 9, 3.9e12 + 0.25, voiced[k], mark=True)
        assert len(packed[k]) == len(one) == layout.size
        header = len(one) - layout.n_weights - 8 * layout.n_joints
        assert packed[k][:header] == one[:header]  # slot, kind, flags, seq, time: exactly
        # weights and quaternions: the same numbers summed in another order may round a step apart at a half
        got, want = unpack(packed[k], layout), unpack(one, layout)
        assert got[:4] == want[:4]
        assert np.abs(got[4] - want[4]).max() <= 1 / 255 + 1e-12
        assert np.abs(got[5] - want[5]).max() <= 1 / 32767 + 1e-12
        differing = np.frombuffer(packed[k], np.uint8) != np.frombuffer(one, np.uint8)
        assert differing.sum() <= 2  # the rare half-way rounding, not a different frame
