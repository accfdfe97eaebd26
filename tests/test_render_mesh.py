"""The face geometry and how flexors move it: pure numpy, no OpenGL."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from eca.agent.face.flexors import N_FLEXORS
from eca.agent.face.frame import FlexorFrame
from eca.services.processes.renderer.config import load_render_config
from eca.services.processes.renderer.curves import (
    CURVE_POINTS,
    RING,
    SEGMENTS,
    STRIP_CODE,
    TUBE_CODE,
    TUBE_POINTS,
    _on_face,
    clean_flexors,
    mouth_shape,
    shader_template,
)
from eca.services.processes.renderer.geometry import (
    BONE_ULID_L,
    EXTRUDED,
    EYE_RADIUS,
    _ellipsoid,
    build_static_mesh,
    eye_centre,
)
from eca.services.processes.renderer.outline import RigidFacing, Silhouette, extruded_copy
from eca.services.processes.renderer.poser import FacePoser, lid_elevations, skin


def flexors(**values: float) -> np.ndarray:
    return FlexorFrame.from_dict(values).values


@pytest.fixture(scope="module")
def poser() -> FacePoser:
    return FacePoser(load_render_config().units)


@pytest.fixture(scope="module")
def static():
    return build_static_mesh()


def test_static_mesh_is_well_formed(static) -> None:
    n = static.vertices.shape[0]
    assert static.vertices.dtype == np.float32 and static.vertices.shape[1] == 13
    assert static.indices.max() < n and static.indices.size % 3 == 0
    assert np.isfinite(static.vertices).all()
    covered = sum(count for _, count in static.ranges.values())
    assert covered == static.indices.size
    assert set(static.ranges) == {"decals", "nose", "face", "eyes", "lids"}


def test_triangles_wind_counter_clockwise_around_their_normals(static) -> None:
    tris = static.indices.reshape(-1, 3)
    p = static.vertices[:, 0:3].astype(np.float64)
    nrm = static.vertices[:, 3:6].astype(np.float64)
    face = np.cross(p[tris[:, 1]] - p[tris[:, 0]], p[tris[:, 2]] - p[tris[:, 0]])
    big = np.linalg.norm(face, axis=1) > 1e-9  # pole triangles have no area and no winding
    agree = np.einsum("ij,ij->i", face, nrm[tris].sum(1))[big]
    assert (agree > 0).all()


def test_dynamic_geometry_is_finite_and_stable_in_size(poser: FacePoser) -> None:
    sizes = set()
    rng = np.random.default_rng(1)
    for _ in range(20):
        pose = poser.pose(rng.uniform(-1, 1, N_FLEXORS))
        assert np.isfinite(pose.dynamic).all()
        sizes.add(pose.dynamic.shape)
    assert sizes == {(poser.layout.n_vertices, 13)}


def shader_dynamic(template: np.ndarray, block: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What FACE_VERTEX does with the vertices of shader_template (shaders.py), in numpy: positions,
    normals and jaw weights from the curve_block."""
    points, sections = block[:CURVE_POINTS], block[CURVE_POINTS:]
    on_face, normal_at = _on_face(points[:, 0], points[:, 1], points[:, 2])
    k = np.rint(template[:, 0]).astype(int)
    pos, normal = on_face[k].copy(), template[:, 3:6].astype(np.float64).copy()
    tube = template[:, 9] >= TUBE_CODE
    tube &= template[:, 9] < STRIP_CODE
    kt = k[tube]
    j = kt % SEGMENTS
    cos, sin = template[tube, 1:2], template[tube, 2:3]
    o, section = normal_at[kt], sections[kt]
    tangent = on_face[np.where(j == SEGMENTS - 1, kt, kt + 1)] - on_face[np.where(j == 0, kt, kt - 1)]
    side = np.cross(o, tangent)
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    pos[tube] = on_face[kt] + cos * section[:, 0:1] * side + sin * section[:, 1:2] * o
    tube_normal = cos * section[:, 2:3] * side + sin * o
    normal[tube] = tube_normal / np.linalg.norm(tube_normal, axis=1, keepdims=True)
    return pos, normal, points[k, 3]


def test_the_shader_builds_from_the_curve_block_what_numpy_builds(poser: FacePoser) -> None:
    """The renderer uploads only the points the brows and mouth are built from; the vertex shader (here
    in numpy; test_render_image runs the real one) must rebuild what build_dynamic builds, jaw weights
    included."""
    lay = poser.layout
    template = shader_template(lay)
    tubes, strips = template[lay.tube_block], template[lay.strip_block]
    assert (tubes[:, 9] >= TUBE_CODE).all() and (tubes[:, 9] < STRIP_CODE).all() and (strips[:, 9] >= STRIP_CODE).all()
    rng = np.random.default_rng(3)
    for f in [flexors(), flexors(say_ah=1.0, smile_l=1.0, brow_r=-1.0)] + [
        rng.uniform(-1, 1, N_FLEXORS) for _ in range(5)
    ]:
        full = poser.pose(f).dynamic.copy()
        block = np.zeros((CURVE_POINTS + TUBE_POINTS, 4), dtype=np.float32)
        untouched = poser.pose(f, dynamic=False)
        before = untouched.dynamic.copy()
        poser.build_dynamic(untouched, block)
        np.testing.assert_array_equal(untouched.dynamic, before)  # only the block is written
        pos, normal, weight = shader_dynamic(template, block.astype(np.float64))
        np.testing.assert_allclose(pos, full[:, 0:3], atol=1e-5)
        np.testing.assert_allclose(normal, full[:, 3:6], atol=1e-4)
        np.testing.assert_allclose(weight, full[:, 12], atol=1e-6)


def test_nan_is_relaxed_and_values_are_clipped() -> None:
    f = np.full(N_FLEXORS, np.nan)
    f[0] = 3.0
    cleaned = clean_flexors(f)
    assert cleaned[0] == 1.0 and (cleaned[1:] == 0).all()
    with pytest.raises(ValueError, match="shape"):
        clean_flexors(np.zeros(5))


def test_gaze_to_the_agents_right_moves_the_pupils_to_the_viewers_left(poser: FacePoser) -> None:
    rest = poser.pose(flexors()).pupils
    right = poser.pose(flexors(look_x=0.5)).pupils
    up = poser.pose(flexors(look_y=0.5)).pupils
    assert (right[:, 0] < rest[:, 0] - 0.03).all()  # -x is the viewer's left
    assert (up[:, 1] > rest[:, 1] + 0.03).all()
    # 30 degrees per unit: half a unit turns the pupil by 15 degrees around the eye centre
    c = eye_centre(1)
    d = right[0] - c
    assert np.degrees(np.arctan2(-d[0], d[2])) == pytest.approx(15.0, abs=1e-6)
    assert np.linalg.norm(d) == pytest.approx(EYE_RADIUS)


def test_head_turn_nod_and_tilt_follow_the_agents_frame(poser: FacePoser) -> None:
    nose = np.array([[0.0, -0.1, 1.0]])

    def moved(**kw: float) -> np.ndarray:
        m = poser.pose(flexors(**kw)).model
        return nose @ m[:3, :3].T + m[:3, 3]

    assert moved(turn=0.5)[0, 0] < -0.2  # toward the agent's right = viewer's left
    assert moved(nod=0.5)[0, 1] > moved()[0, 1] + 0.2  # chin up: the nose rises
    top = np.array([[0.0, 1.0, 0.0]])
    m = poser.pose(flexors(tilt=0.5)).model
    assert (top @ m[:3, :3].T + m[:3, 3])[0, 0] < -0.1  # top of the head toward the right shoulder


def test_lids_close_with_blink_open_with_lids_and_follow_gaze_pitch() -> None:
    uppers = [lid_elevations(b, 0.0, 0.0)[0] for b in np.linspace(0, 1, 6)]
    lowers = [lid_elevations(b, 0.0, 0.0)[1] for b in np.linspace(0, 1, 6)]
    assert all(a > b for a, b in zip(uppers, uppers[1:], strict=False))
    assert all(a < b for a, b in zip(lowers, lowers[1:], strict=False))
    up_closed, low_closed = lid_elevations(1.0, 0.0, 0.0)
    assert up_closed - low_closed <= 3.5  # the rims meet
    assert lid_elevations(0.0, 1.0, 0.0)[0] > lid_elevations(0.0, 0.0, 0.0)[0] > lid_elevations(0.0, -1.0, 0.0)[0]
    assert lid_elevations(0.0, 0.0, -20.0)[0] < lid_elevations(0.0, 0.0, 0.0)[0] - 8.0  # looking down
    for blink in (0.0, 1.0):
        for lids in (-1.0, 1.0):
            for pitch in (-30.0, 30.0):
                up, low = lid_elevations(blink, lids, pitch)
                assert up > low


def test_blink_turns_the_upper_lid_bone_down(poser: FacePoser) -> None:
    point = np.array([0.0, 0.0, 1.0, 0.0])  # direction, so the bone's translation drops out
    open_dir = poser.pose(flexors()).bones[BONE_ULID_L] @ point
    closed_dir = poser.pose(flexors(blink_l=1.0)).bones[BONE_ULID_L] @ point
    assert closed_dir[1] < open_dir[1] - 0.4


def test_mouth_opens_rounds_spreads_presses_and_smiles() -> None:
    rest = mouth_shape(flexors())
    ah = mouth_shape(flexors(say_ah=1.0))
    oo = mouth_shape(flexors(say_oo=1.0))
    ee = mouth_shape(flexors(say_ee=1.0))
    ah_mm = mouth_shape(flexors(say_ah=1.0, say_mm=1.0))
    smile = mouth_shape(flexors(smile_l=1.0))
    assert rest.jaw_deg == 0 and ah.jaw_deg > 10
    assert ah_mm.jaw_deg < 0.2 * ah.jaw_deg  # pressed lips win over an open jaw
    width = lambda s: s.x[-1] - s.x[0]  # noqa: E731
    assert width(oo) < 0.7 * width(rest) < width(rest) < width(ee)
    assert oo.protrude.max() > rest.protrude.max() + 0.05
    # smile_l lifts the +x corner (the agent's left) only
    assert smile.upper[-1] > rest.upper[-1] + 0.08 and smile.upper[0] == pytest.approx(rest.upper[0])
    sneer = mouth_shape(flexors(sneer_r=1.0))
    middle = len(sneer.x) // 2
    assert sneer.upper[: middle - 1].max() > rest.upper.max() + 0.04  # the agent's right is -x
    assert (sneer.upper >= sneer.lower).all()


def test_jaw_moves_the_chin_and_lower_lip_but_not_the_upper_lip(poser: FacePoser, static) -> None:
    closed = poser.pose(flexors())
    opened = poser.pose(flexors(say_ah=1.0))
    chin_before = skin(static.vertices, closed.bones, closed.model)[:, 1].min()
    chin_after = skin(static.vertices, opened.bones, opened.model)[:, 1].min()
    assert chin_after < chin_before - 0.06
    lay = poser.layout
    lower = skin(opened.dynamic[lay.slices["lip_l"]], opened.bones, opened.model)
    lower0 = skin(closed.dynamic[lay.slices["lip_l"]], closed.bones, closed.model)
    upper = skin(opened.dynamic[lay.slices["lip_u"]], opened.bones, opened.model)
    upper0 = skin(closed.dynamic[lay.slices["lip_u"]], closed.bones, closed.model)
    assert lower[:, 1].mean() < lower0[:, 1].mean() - 0.1
    assert abs(upper[:, 1].mean() - upper0[:, 1].mean()) < 0.02


def test_brows_raise_lower_and_knit(poser: FacePoser) -> None:
    lay = poser.layout

    def brow(**kw: float) -> np.ndarray:
        pose = poser.pose(flexors(**kw))
        return pose.dynamic[lay.slices["brow_l"], 0:3].reshape(-1, RING, 3).mean(1)  # centre line, inner first

    rest = brow()
    assert brow(brow_l=1.0)[:, 1].mean() > rest[:, 1].mean() + 0.1
    assert brow(brow_l=-1.0)[:, 1].mean() < rest[:, 1].mean() - 0.05
    assert brow(brow_r=1.0)[:, 1].mean() == pytest.approx(rest[:, 1].mean())  # other side only
    angry = brow(brow_l=-0.8, brows_knit=0.9)
    assert angry[0, 1] - angry[-1, 1] < rest[0, 1] - rest[-1, 1] - 0.1  # inner end down: the V
    worried = brow(brow_l=0.8, brows_knit=0.8)
    assert worried[0, 1] - worried[-1, 1] > rest[0, 1] - rest[-1, 1] + 0.05  # inner end up: oblique
    assert worried[0, 0] < rest[0, 0]  # drawn toward the nose


def test_gaze_points_match_the_pupils_of_the_pose(poser: FacePoser) -> None:
    pose = poser.pose(flexors(look_x=0.3, look_y=-0.4, turn=0.2, nod=0.1))
    points = poser.gaze_points(np.array([[0.3, -0.4]]), pose.model)
    np.testing.assert_allclose(points[:, 0, :], pose.pupils, atol=1e-9)


def _eye_in_head(model: np.ndarray, world_eye: np.ndarray) -> np.ndarray:
    return model[:3, :3].T @ (world_eye - model[:3, 3])


@pytest.mark.parametrize(
    "values",
    [{}, {"turn": 0.8, "look_x": 0.7}, {"nod": -0.6, "blink_l": 1.0, "lids_r": 0.9}, {"tilt": 1.0, "say_ah": 1.0}],
)
def test_rigid_facing_agrees_with_the_posed_geometry(poser: FacePoser, static, values: dict[str, float]) -> None:
    pose = poser.pose(flexors(**values))
    eye = _eye_in_head(pose.model, np.array([0.3, 0.4, 7.0]))
    tris = static.indices.reshape(-1, 3).astype(int)
    posed = skin(static.vertices, pose.bones, np.eye(4))
    p0 = posed[tris[:, 0]]
    normal = np.cross(posed[tris[:, 1]] - p0, posed[tris[:, 2]] - p0)
    cos = np.einsum("ij,ij->i", normal, eye - p0) / np.maximum(
        np.linalg.norm(normal, axis=1) * np.linalg.norm(eye - p0, axis=1), 1e-12
    )
    front = RigidFacing(static.vertices, tris).front(pose.bones, eye)
    clear = np.abs(cos) > 1e-6  # edge-on (or zero-area) triangles may go either way
    np.testing.assert_array_equal(front[clear], cos[clear] > 0)


def test_silhouette_of_an_ellipsoid_is_its_rim_as_closed_loops() -> None:
    part = _ellipsoid(np.zeros(3), np.array([1.0, 0.8, 0.6]), "skin", 16, 9)
    sil = Silhouette(part.vertices[:, 0:3], part.triangles, part.vertices.shape[0])
    n_tri = len(part.triangles)
    facing = RigidFacing(part.vertices, part.triangles)
    for eye in (np.array([0.0, 0.0, 50.0]), np.array([30.0, 10.0, 20.0])):
        front = facing.front(np.tile(np.eye(4), (8, 1, 1)), eye)
        quads = sil.quads_for(front)
        assert 0 < len(quads) < n_tri / 3
        inner = part.vertices[quads[:, :2].reshape(-1), 0:3].astype(np.float64)
        normal = inner / np.array([1.0, 0.8, 0.6]) ** 2  # the ellipsoid's normal direction
        cos = (normal / np.linalg.norm(normal, axis=1, keepdims=True)) @ (eye / np.linalg.norm(eye))
        assert np.abs(cos).max() < 0.45  # every edge lies near where the surface turns edge-on
        # Closed loops: every vertex (welded by position) is the end of an even number of edges.
        _, ends = np.unique(np.round(inner * 1e6), axis=0, return_counts=True)
        assert (ends % 2 == 0).all()
        # The outer corners are the EXTRUDED copies of the inner ones.
        np.testing.assert_array_equal(quads[:, 2], quads[:, 1] + part.vertices.shape[0])
        np.testing.assert_array_equal(quads[:, 5], quads[:, 0] + part.vertices.shape[0])


def test_extruded_copies_keep_everything_but_the_marked_material(static) -> None:
    both = extruded_copy(static.vertices)
    n = static.vertices.shape[0]
    np.testing.assert_array_equal(both[:n], static.vertices)
    np.testing.assert_array_equal(both[n:, 9], static.vertices[:, 9] + EXTRUDED)
    np.testing.assert_array_equal(np.delete(both[n:], 9, axis=1), np.delete(static.vertices, 9, axis=1))


def test_render_config_errors_name_the_file_and_key(tmp_path) -> None:
    from eca.agent.config import ConfigError

    good = (Path(__file__).resolve().parent.parent / "eca" / "configs" / "render.toml").read_text()
    cases = {
        "skin = [0.98, 0.80, 0.66]": ("skin = [0.98, 0.80]", "'skin' must be a list of 3 numbers"),
        "band_edges = [0.05, 0.5]": ("band_edges = [0.5, 0.05]", "'band_edges' must increase"),
        "width_px = 2.2": ("width_px = -1", "'width_px' must lie in"),
    }
    for old, (new, message) in cases.items():
        assert old in good
        bad = tmp_path / "render_bad.toml"
        bad.write_text(good.replace(old, new, 1))
        with pytest.raises(ConfigError, match=message) as err:
            load_render_config(bad)
        assert "render_bad.toml" in str(err.value)
