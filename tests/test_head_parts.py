"""The 3D drawer's parts: the GPU's morphing and skinning against numpy, materials (alpha mask, blending back to
front, two sides, the toon ramp), framing without eye or head joints, the pupil marks, a stage of a 2D face beside
a 3D head, and the kinds `make_drawer` knows (a path to a .glb or .vrm among them)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import moderngl
import numpy as np
import pytest

from eca.agent.face.composed import ComposedFace
from eca.agent.face.flexors import FLEXOR_INDEX
from eca.agent.face.scene import LiveScene
from eca.agent.face.settings import load_flexor_units
from eca.services.processes.avatar.drive import AvatarPose
from eca.services.processes.avatar.errors import AvatarError
from eca.services.processes.avatar.loader import load_avatar
from eca.services.processes.avatar.model import (
    AlphaMode,
    Avatar,
    Capabilities,
    Material,
    Primitive,
    Skeleton,
    Texture,
)
from eca.services.processes.renderer import (
    FlexorFaceDrawer,
    HeadlessContextError,
    RenderToggles,
    Stage,
    create_headless_context,
    create_offscreen_target,
    make_drawer,
    read_rgb,
)
from eca.services.processes.renderer.head import DEFAULT_HEAD, HeadDrawer, sample_avatar
from eca.services.processes.renderer.head.skeleton import Posed, global_transforms
from eca.services.processes.scene.bus_scene import AgentView
from tests.support.faces import composed_face as composed
from tests.test_avatar_files import face as gltf_face
from tests.test_avatar_files import glb_bytes, vrm0_document, vrm1_document, write

UNITS = load_flexor_units()
SIZE = (240, 180)




@pytest.fixture(scope="module")
def ctx() -> Iterator[moderngl.Context]:
    try:
        context = create_headless_context()
    except HeadlessContextError as exc:
        pytest.skip(f"no headless OpenGL context: {exc}")
    yield context
    context.release()


# -- small avatars: quads and spheres on a head joint -------------------------------------------------------------


def _translation(x: float, y: float, z: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def _skeleton(eyes: bool = True, head: bool = True) -> Skeleton:
    """root -> head (at 1.6 m) -> two eyes; humanoid names for what there is."""
    rest = [np.eye(4)]
    parents = [-1]
    humanoid: dict[str, int] = {}
    if head:
        rest.append(_translation(0.0, 1.6, 0.0))
        parents.append(0)
        humanoid["head"] = 1
        if eyes:
            rest += [_translation(0.03, 0.0, 0.08), _translation(-0.03, 0.0, 0.08)]
            parents += [1, 1]
            humanoid.update(leftEye=2, rightEye=3)
    return Skeleton(tuple(f"j{k}" for k in range(len(rest))), np.array(parents, dtype=np.int32), np.stack(rest),
                    np.tile(np.eye(4), (len(rest), 1, 1)), humanoid)


def quad(half: float, z: float, material: int, node: int = 1, facing: float = 1.0) -> Primitive:
    """A square of side 2 * half at depth z in the node's frame, facing +z (facing -1: facing -z)."""
    p = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], dtype=np.float32)
    n = np.tile(np.array([0.0, 0.0, facing], dtype=np.float32), (4, 1))
    idx = np.array([0, 1, 2, 0, 2, 3] if facing > 0 else [0, 2, 1, 0, 3, 2], dtype=np.uint32)
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], dtype=np.float32)
    return Primitive(p, n, idx, material, uvs=uv, node=node)


def sphere(radius: float, material: int, node: int = 1, n: int = 32) -> Primitive:
    th, ph = np.meshgrid(np.linspace(0, math.pi, n + 1), np.linspace(-math.pi, math.pi, 2 * n + 1), indexing="ij")
    normals = np.stack([np.sin(th) * np.sin(ph), np.cos(th), np.sin(th) * np.cos(ph)], -1).reshape(-1, 3)
    r, c = np.meshgrid(np.arange(n), np.arange(2 * n), indexing="ij")
    a = r * (2 * n + 1) + c
    tris = np.stack([a, a + 2 * n + 1, a + 1, a + 1, a + 2 * n + 1, a + 2 * n + 2], -1).reshape(-1)
    return Primitive((normals * radius).astype(np.float32), normals.astype(np.float32), tris.astype(np.uint32),
                     material, node=node)


def avatar(primitives: list[Primitive], materials: list[Material], skeleton: Skeleton | None = None) -> Avatar:
    return Avatar("test", tuple(primitives), tuple(materials), skeleton or _skeleton(), {}, None,
                  Capabilities(eyes="bones", blink="arkit shapes", mouth="jaw bone"))


def draw(ctx: moderngl.Context, a: Avatar, **kwargs: object) -> np.ndarray:
    d = HeadDrawer(ctx, SIZE, a, samples=0)
    try:
        return read_rgb(d.draw(composed(), **kwargs)).astype(np.int32)  # type: ignore[arg-type]
    finally:
        d.release()


def centre(img: np.ndarray) -> np.ndarray:
    h, w = img.shape[:2]
    return img[h // 2 - 3 : h // 2 + 3, w // 2 - 3 : w // 2 + 3].reshape(-1, 3).mean(axis=0)


# -- the GPU's deformation ----------------------------------------------------------------------------------------


@pytest.mark.gl
@pytest.mark.parametrize("which", ["sample", pytest.param("default", marks=pytest.mark.skipif(
    not DEFAULT_HEAD.exists(), reason="the default head is not baked yet"))])
def test_the_gpu_morphs_and_skins_every_vertex_as_numpy_does(ctx: moderngl.Context, which: str) -> None:
    a = sample_avatar() if which == "sample" else load_avatar(DEFAULT_HEAD)
    d = HeadDrawer(ctx, SIZE, a, samples=0)
    try:
        frame = d.retargeter.retarget(composed((12.0, -8.0), turn=0.4, nod=-0.3, tilt=0.2, say_ah=0.7, smile_l=0.8))
        pose = d.driver.drive(frame)
        rng = np.random.default_rng(3)
        # every target of every primitive on at once, at random weights: more than any emotion sets
        weights = tuple(rng.random(len(w)).astype(np.float32) for w in pose.weights)
        d.draw_pose(AvatarPose(weights, pose.turns, pose.local, np.concatenate(weights)))
        palette = d.posed.palette.astype(np.float64)
        checked = 0
        for gp in d.gpu.primitives:
            if gp.deformed is None:
                continue
            prim = a.primitives[gp.index]
            got = np.frombuffer(gp.deformed.read(), dtype=np.float32).reshape(-1, 6)
            pos, nrm = prim.positions.astype(np.float64), prim.normals.astype(np.float64)
            for w, target in zip(weights[gp.index], prim.targets, strict=True):
                pos = pos + float(w) * target.positions
                if target.normals is not None:
                    nrm = nrm + float(w) * target.normals
            if prim.joints is not None and prim.weights is not None:
                m = np.einsum("vk,vkij->vij", prim.weights, palette[prim.joints.astype(np.intp)])
                pos = np.einsum("vij,vj->vi", m[:, :3, :3], pos) + m[:, :3, 3]
                nrm = np.einsum("vij,vj->vi", m[:, :3, :3], nrm)
            assert np.abs(got[:, :3] - pos).max() < 2e-5  # metres: float32 rounding
            # normal deltas are packed in 9 bits an axis: half a step of error a target at most
            assert np.abs(got[:, 3:] - nrm).max() <= 1e-5 + gp.n_targets * gp.normal_scale / 511
            checked += 1
        assert checked >= 4  # the sample: the head, the neck and the lids; the default head: the skin and more
    finally:
        d.release()


def test_posing_a_few_joints_updates_what_hangs_below_them_and_puts_the_rest_back() -> None:
    a = sample_avatar()
    posed = Posed(a.skeleton)
    turn = np.eye(4)
    turn[:3, :3] = [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]
    local = {2: a.skeleton.rest[2] @ turn}  # the head
    g = posed.pose(local).copy()
    full = np.array(a.skeleton.rest)
    full[2] = local[2]
    assert np.allclose(g, global_transforms(np.asarray(a.skeleton.parents), full))
    assert posed.changed == frozenset({2, 3, 4, 5})  # the head and its jaw and eyes
    g = posed.pose({})
    assert np.allclose(g, posed.rest_global) and posed.changed == frozenset({2, 3, 4, 5})
    posed.pose({})
    assert posed.changed == frozenset()


# -- materials ----------------------------------------------------------------------------------------------------


@pytest.mark.gl
def test_an_alpha_mask_cuts_where_the_texture_is_transparent(ctx: moderngl.Context) -> None:
    rgba = np.zeros((8, 8, 4), dtype=np.uint8)
    rgba[..., 0] = 230
    rgba[:, 4:, 3] = 255  # the right half opaque
    masked = Material("card", texture=Texture(rgba), alpha_mode=AlphaMode.MASK, double_sided=True)
    img = draw(ctx, avatar([quad(0.1, 0.0, 0)], [masked]))
    bg = img[0, 0]
    h, w = SIZE[1] // 2, SIZE[0] // 2
    assert np.array_equal(img[h, w - 20], bg)  # cut away: the background
    r, g, b = img[h, w + 20]
    assert r > 150 and g < 60 and b < 60  # kept: red


@pytest.mark.gl
def test_blended_primitives_are_drawn_after_the_opaque_ones_back_to_front(ctx: moderngl.Context) -> None:
    materials = [Material("green", (0.0, 0.6, 0.0, 1.0)), Material("blue glass", (0.0, 0.0, 1.0, 0.5),
                                                                 alpha_mode=AlphaMode.BLEND),
                 Material("red glass", (1.0, 0.0, 0.0, 0.5), alpha_mode=AlphaMode.BLEND)]
    # Listed front first: a drawer that drew in order would let the front glass hide the back one.
    glass = [quad(0.06, 0.02, 2), quad(0.08, 0.01, 1)]
    opaque = quad(0.1, 0.0, 0)
    img = centre(draw(ctx, avatar([*glass, opaque], materials)))
    alone = centre(draw(ctx, avatar([opaque], materials)))
    assert img[0] > 60 and img[2] > 60 and img[1] < alone[1] - 40  # red over blue over green, all showing
    behind = centre(draw(ctx, avatar([opaque, quad(0.08, -0.02, 1)], materials)))
    assert np.allclose(behind, alone, atol=1)  # glass behind an opaque surface is hidden by the depth test


@pytest.mark.gl
def test_a_double_sided_surface_shows_its_back_and_a_single_sided_one_does_not(ctx: moderngl.Context) -> None:
    backward = quad(0.1, 0.0, 0, facing=-1.0)  # its back toward the camera
    one = draw(ctx, avatar([backward], [Material("one", (0.8, 0.2, 0.2, 1.0))]))
    two = draw(ctx, avatar([backward], [Material("two", (0.8, 0.2, 0.2, 1.0), double_sided=True)]))
    assert np.array_equal(centre(one), one[0, 0])
    assert centre(two)[0] > 120 and centre(two)[0] > centre(two)[1] + 60  # the red surface, its back lit


@pytest.mark.gl
def test_a_toon_material_has_two_tones_where_a_lit_one_has_a_gradient(ctx: moderngl.Context) -> None:
    base = (0.5, 0.5, 0.8, 1.0)

    def tones(material: Material) -> tuple[float, int]:
        img = draw(ctx, avatar([sphere(0.1, 0)], [material]))
        on = np.abs(img - img[0, 0]).sum(axis=2) > 10
        lum = img[on].sum(axis=1)
        levels, counts = np.unique(lum // 6, return_counts=True)
        top2 = np.sort(counts)[-2:].sum() / counts.sum()
        return float(top2), len(levels)

    toon_share, _ = tones(Material("toon", base, toon=True, shade_color=(0.3, 0.2, 0.4)))
    lit_share, lit_levels = tones(Material("lit", base))
    assert toon_share > 0.6  # most of the sphere is one of two tones (the rest: the step and the rim)
    assert lit_share < 0.25 and lit_levels > 30


@pytest.mark.gl
def test_light_is_gamma_correct_half_the_light_is_brighter_than_half_the_code(ctx: moderngl.Context) -> None:
    from eca.services.processes.renderer.head.lighting import Lights

    grey = [Material("grey", (0.5, 0.5, 0.5, 1.0))]
    dark = Lights(key=(0.0, 0.0, 0.0), fill=(0.0, 0.0, 0.0), rim=(0.0, 0.0, 0.0), sky=(1.0, 1.0, 1.0),
                  ground=(1.0, 1.0, 1.0))
    d = HeadDrawer(ctx, SIZE, avatar([quad(0.1, 0.0, 0)], grey), samples=0, lights=dark)
    try:
        value = centre(read_rgb(d.draw(composed())).astype(np.int32))
    finally:
        d.release()
    # linear 0.5 under a light of 1 is sRGB 0.735 (188 of 255), not 128
    assert np.all(np.abs(value - 255 * 0.5 ** (1 / 2.2)) < 3)


# -- framing ------------------------------------------------------------------------------------------------------


@pytest.mark.gl
@pytest.mark.parametrize("joints", ["eyes", "head only", "none"])
def test_a_model_is_framed_from_what_joints_it_has(ctx: moderngl.Context, joints: str) -> None:
    skeleton = _skeleton(eyes=joints == "eyes", head=joints != "none")
    node = 1 if joints != "none" else 0
    head = sphere(0.1, 0, node=node)
    if joints == "none":
        head = Primitive(head.positions + np.array([0.0, 1.6, 0.0], dtype=np.float32), head.normals, head.indices, 0)
    img = draw(ctx, avatar([head], [Material("skin", (0.8, 0.6, 0.5, 1.0))], skeleton))
    on = np.abs(img - img[0, 0]).sum(axis=2) > 10
    rows, cols = np.nonzero(on)
    assert 0.55 * SIZE[1] < np.ptp(rows) < 0.95 * SIZE[1]  # the head fills most of the height
    assert abs(cols.mean() - SIZE[0] / 2) < 3


# -- overlays, stage, kinds -----------------------------------------------------------------------------------------


@pytest.mark.gl
def test_the_pupil_marks_and_the_gaze_trail_are_drawn_over_the_eyes(ctx: moderngl.Context) -> None:
    d = HeadDrawer(ctx, SIZE, sample_avatar(), samples=0)
    try:
        plain = read_rgb(d.draw(composed((10.0, 5.0)), view="upper")).astype(np.int32)
        marks = read_rgb(d.draw(composed((10.0, 5.0)), view="upper",
                                toggles=RenderToggles(eye_centre=True))).astype(np.int32)
        red = np.round(np.asarray(d.config.colors["eye_centre"]) * 255)
        for x, y in d.to_pixels(d.pupils()):
            near = marks[int(y) - 3 : int(y) + 4, int(x) - 3 : int(x) + 4]
            assert (np.abs(near - red).sum(axis=2) < 30).sum() >= 5
        trail = np.array([[-0.5, 0.0], [0.0, 0.3], [0.5, 0.0]])
        with_trail = read_rgb(d.draw(composed((10.0, 5.0)), view="upper", toggles=RenderToggles(), trail=trail))
        assert (np.abs(with_trail.astype(np.int32) - plain).sum(axis=2) > 30).sum() > 40
    finally:
        d.release()


@pytest.mark.gl
def test_the_wireframe_toggle_draws_the_mesh_over_the_surface(ctx: moderngl.Context) -> None:
    d = HeadDrawer(ctx, SIZE, sample_avatar(), samples=0)
    try:
        plain = read_rgb(d.draw(composed())).astype(np.int32)
        wired = read_rgb(d.draw(composed(), toggles=RenderToggles(wireframe=True))).astype(np.int32)
        again = read_rgb(d.draw(composed())).astype(np.int32)
        blue = np.round(np.asarray(d.config.colors["wireframe"]) * 255)
        lines = np.abs(wired - blue).sum(axis=2) < 40
        head = np.abs(plain - plain[0, 0]).sum(axis=2) > 10
        assert lines[head].mean() > 0.1 and lines[~head].mean() < 0.01  # on the head, not around it
        assert np.array_equal(again, plain)  # and the state is put back
    finally:
        d.release()


class PerViewDrawer:
    """A FaceDrawer that hands each view of a stage's frame to its own drawer, in the stage's order (a stand-in
    until Stage takes a drawer per view)."""

    def __init__(self, drawers: list[object]) -> None:
        self.drawers = drawers
        self.size = (0, 0)
        self._next = 0

    def draw(self, face: ComposedFace, target: moderngl.Framebuffer | None = None, **kwargs: object) -> object:
        drawer = self.drawers[self._next % len(self.drawers)]
        self._next += 1
        return drawer.draw(face, target, **kwargs)  # type: ignore[attr-defined]

    def release(self) -> None:
        for d in self.drawers:
            d.release()  # type: ignore[attr-defined]


@pytest.mark.gl
@pytest.mark.parametrize("samples", [0, 4])
def test_a_stage_draws_a_2d_face_beside_a_3d_head(ctx: moderngl.Context, samples: int) -> None:
    # multisampled, the head is drawn apart and copied into its panel, which must land in the right place
    half = (SIZE[0], SIZE[1])
    flexor, head = FlexorFaceDrawer(ctx, half), HeadDrawer(ctx, half, sample_avatar(), samples=samples)
    views = [AgentView(name, LiveScene(seed=k, idle_noise=False)) for k, name in enumerate(("ada", "bob"))]
    views[1].scene.set_emotion("happy", 1.0, 0.0, 0)
    stage = Stage(PerViewDrawer([flexor, head]), views, fps=10.0, facing_turn=0.3)  # type: ignore[arg-type]
    target = create_offscreen_target(ctx, (2 * SIZE[0], SIZE[1]))
    try:
        faces = stage.compose(1_000_000_000)
        stage.draw(faces, target)
        both = read_rgb(target).astype(np.int32)
        target.viewport = (0, 0, 2 * SIZE[0], SIZE[1])
        # Each panel is what its drawer draws alone of the face the stage turned toward the other agent.
        turned = [f.with_flexors(_turned(f, side * 0.3), UNITS) for f, side in zip(faces, (-1.0, 1.0), strict=True)]
        alone = [read_rgb(flexor.draw(turned[0])).astype(np.int32), read_rgb(head.draw(turned[1])).astype(np.int32)]
        left, right = both[:, : SIZE[0]], both[:, SIZE[0] :]
        assert np.abs(left - alone[0]).mean() < 0.5 and np.abs(right - alone[1]).mean() < 0.5
        assert left.std() > 10 and right.std() > 10
    finally:
        for a in (*target.color_attachments, target.depth_attachment):
            a.release()
        target.release()
        flexor.release()
        head.release()


def _turned(face: ComposedFace, by: float) -> np.ndarray:
    values = np.array(face.flexors)
    values[FLEXOR_INDEX["turn"]] = float(np.clip(values[FLEXOR_INDEX["turn"]] + by, -1, 1))
    return values


@pytest.mark.gl
def test_make_drawer_knows_the_flexor_face_the_head_and_avatar_files(ctx: moderngl.Context, tmp_path: Path) -> None:
    flexor = make_drawer(ctx, SIZE)
    assert isinstance(flexor, FlexorFaceDrawer)
    flexor.release()
    with pytest.raises(ValueError, match=r"unknown face kind 'nope'.*flexor, head.*\.glb"):
        make_drawer(ctx, SIZE, "nope")
    with pytest.raises(AvatarError, match="missing.vrm"):
        make_drawer(ctx, SIZE, str(tmp_path / "missing.vrm"))
    if DEFAULT_HEAD.exists():
        head = make_drawer(ctx, SIZE, "head")
        assert isinstance(head, HeadDrawer)
        head.release()
    else:
        with pytest.raises(FileNotFoundError, match="default_head.glb"):
            make_drawer(ctx, SIZE, "head")
    glb = write(tmp_path, "face.glb", gltf_face("pascal").builder.glb())
    vrm1 = gltf_face(None)
    vrm1_path = write(tmp_path, "face1.vrm", glb_bytes(vrm1_document(vrm1, "expression"), bytes(vrm1.builder.blob)))
    vrm0 = gltf_face(None, vrm0=True)
    vrm0_path = write(tmp_path, "face0.vrm", glb_bytes(vrm0_document(vrm0), bytes(vrm0.builder.blob)))
    for path in (glb, vrm1_path, vrm0_path):
        d = make_drawer(ctx, SIZE, str(path))
        try:
            assert isinstance(d, HeadDrawer)
            img = read_rgb(d.draw(composed(), view="full")).astype(np.int32)
            assert (np.abs(img - img[0, 0]).sum(axis=2) > 10).mean() > 0.05  # something drawn
        finally:
            d.release()
