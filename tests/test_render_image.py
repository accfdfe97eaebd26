"""Driver-independent properties of rendered images (headless EGL): where things are, what changes."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator

import moderngl
import numpy as np
import pytest

from eca.agent.face.flexors import N_FLEXORS
from eca.agent.face.frame import FlexorFrame
from eca.services.processes.renderer import (
    HeadlessContextError,
    Renderer,
    RenderToggles,
    create_headless_context,
    create_offscreen_target,
    load_render_config,
    read_rgb,
)
from eca.services.processes.renderer.curves import CURVE_POINTS, TUBE_POINTS, shader_template
from eca.services.processes.renderer.geometry import EYE_RADIUS, N_BONES, eye_centre
from eca.services.processes.renderer.poser import FacePoser
from eca.services.processes.renderer.renderer import SURFACE, VERTEX_FORMAT
from eca.services.processes.renderer.shaders import FACE_VERTEX

SURFACE_FACE = (SURFACE, "face")

pytestmark = pytest.mark.gl

SIZE = (320, 240)
GREEN = (0.0, 1.0, 0.0)
MAGENTA = (1.0, 0.0, 1.0)


def flexors(**values: float) -> np.ndarray:
    return FlexorFrame.from_dict(values).values


@pytest.fixture(scope="module")
def ctx() -> Iterator[object]:
    try:
        context = create_headless_context()
    except HeadlessContextError as exc:
        pytest.skip(f"no headless OpenGL context: {exc}")
    yield context
    context.release()


@pytest.fixture(scope="module")
def renderer(ctx) -> Renderer:
    """A renderer whose pupils are pure green and mouth cavity magenta, so they are easy to find."""
    config = load_render_config()
    colors = dict(config.colors, pupil=GREEN, mouth=MAGENTA)
    return Renderer(ctx, SIZE, dataclasses.replace(config, colors=colors))


def image(renderer: Renderer, f: np.ndarray, **kw: object) -> np.ndarray:
    renderer.render(f, **kw)
    return read_rgb(renderer.fbo).astype(np.int32)


def mask_of(img: np.ndarray, color: tuple[float, float, float], tol: int = 60) -> np.ndarray:
    """Pixels of a colour in any of the cel bands (which scale it by 0.7-1.0)."""
    target = np.array(color) * 255
    lit = np.array([level * target for level in (0.72, 0.88, 1.0)])
    return (np.abs(img[None] - lit[:, None, None, :]).max(-1) < tol).any(0)


def dilated(mask: np.ndarray, steps: int) -> np.ndarray:
    """The mask grown by `steps` pixels in every direction (diagonals included)."""
    grown = mask.copy()
    for _ in range(steps):
        before = grown.copy()
        grown[1:] |= before[:-1]
        grown[:-1] |= before[1:]
        before = grown.copy()
        grown[:, 1:] |= before[:, :-1]
        grown[:, :-1] |= before[:, 1:]
    return grown


def centroid(mask: np.ndarray) -> np.ndarray:
    ys, xs = np.nonzero(mask)
    assert xs.size > 5, "colour not found in the image"
    return np.array([xs.mean(), ys.mean()])


def test_read_rgb_is_top_row_first(renderer: Renderer) -> None:
    img = image(renderer, flexors())
    assert img.shape == (SIZE[1], SIZE[0], 3)
    hair = np.array(renderer.config.colors["hair"]) * 255
    top, bottom = img[: SIZE[1] // 4], img[3 * SIZE[1] // 4 :]
    near = lambda part: (np.abs(part - hair).max(-1) < 60).mean()  # noqa: E731
    assert near(top) > 5 * near(bottom)  # the hair is at the top of the picture


def test_pupils_move_to_the_viewers_left_for_the_agents_right_and_up_for_up(renderer: Renderer) -> None:
    rest = centroid(mask_of(image(renderer, flexors()), GREEN))
    right = centroid(mask_of(image(renderer, flexors(look_x=0.6)), GREEN))
    left = centroid(mask_of(image(renderer, flexors(look_x=-0.6)), GREEN))
    up = centroid(mask_of(image(renderer, flexors(look_y=0.5)), GREEN))
    down = centroid(mask_of(image(renderer, flexors(look_y=-0.5)), GREEN))
    assert right[0] < rest[0] - 3 < left[0] - 6
    assert up[1] < rest[1] - 2  # image y grows downward
    assert down[1] > rest[1] + 2
    assert abs(right[1] - rest[1]) < 3 and abs(up[0] - rest[0]) < 3


def test_pupil_centroid_matches_the_projected_pupil_centres(renderer: Renderer) -> None:
    f = flexors(look_x=-0.3, look_y=0.2)
    img = image(renderer, f)
    expected = renderer.to_pixels(renderer.last_pose.pupils).mean(0)
    assert np.abs(centroid(mask_of(img, GREEN)) - expected).max() < 3.0


def eyeball_discs(renderer: Renderer) -> np.ndarray:
    """A mask of the two eyeballs' projected discs in the relaxed pose."""
    renderer.render(flexors())
    centres = np.array([eye_centre(1), eye_centre(-1)])
    px = renderer.to_pixels(centres)
    radius = np.abs(renderer.to_pixels(centres + [0.0, EYE_RADIUS, 0.0])[:, 1] - px[:, 1])
    ys, xs = np.mgrid[0 : SIZE[1], 0 : SIZE[0]]
    mask = np.zeros((SIZE[1], SIZE[0]), dtype=bool)
    for (cx, cy), r in zip(px, radius, strict=True):
        mask |= (xs - cx) ** 2 + (ys - cy) ** 2 < (0.85 * r) ** 2
    return mask


def test_eye_region_darkens_as_the_lids_close(ctx, renderer: Renderer) -> None:
    disc = eyeball_discs(renderer)
    plain = Renderer(ctx, SIZE)  # the real colours: a dark pupil, as the face is meant to look
    shots = [image(plain, flexors(blink_l=b, blink_r=b)) for b in (0.0, 0.5, 1.0)]
    white = [(img[disc].min(-1) > 235).sum() for img in shots]  # the sclera
    assert white[0] > 1.5 * white[1] > 0 and white[2] < 0.1 * white[0]
    brightness = [img[disc].mean() for img in shots]
    assert brightness[0] > max(brightness[1], brightness[2]) + 3
    assert not mask_of(image(renderer, flexors(blink_l=1.0, blink_r=1.0)), GREEN).any()  # pupil hidden


def test_one_sided_blink_closes_the_agents_left_eye_on_the_viewers_right(renderer: Renderer) -> None:
    img = image(renderer, flexors(blink_l=1.0))
    xs = np.nonzero(mask_of(img, GREEN))[1]
    assert xs.size > 5 and xs.max() < SIZE[0] / 2  # only the viewer's-left pupil remains


def test_mouth_opens_for_say_ah(renderer: Renderer) -> None:
    closed = image(renderer, flexors())
    opened = image(renderer, flexors(say_ah=1.0))
    assert mask_of(closed, MAGENTA).sum() < 20
    cavity = mask_of(opened, MAGENTA)
    assert cavity.sum() > 300
    assert centroid(cavity)[1] > SIZE[1] * 0.6  # in the lower face
    assert np.abs(closed - opened).max(-1).astype(bool)[: SIZE[1] // 2].mean() < 0.01


def test_upper_view_shows_no_mouth(renderer: Renderer) -> None:
    rest = image(renderer, flexors(), view="upper")
    for mouth in ("say_ah", "say_oo", "say_ee", "smile_l"):
        other = image(renderer, flexors(**{mouth: 1.0}), view="upper")
        assert not mask_of(other, MAGENTA).any()
        assert (np.abs(other - rest).max(-1) > 0).mean() < 0.002, mouth
    # and it frames the eyes larger than the full view does
    full = mask_of(image(renderer, flexors()), GREEN).sum()
    upper = mask_of(rest, GREEN).sum()
    assert upper > 3 * full


def test_toggles_change_what_is_drawn(renderer: Renderer) -> None:
    f = flexors(brow_l=0.5, brow_r=0.5)
    base = image(renderer, f)

    def changed(**toggle: bool) -> float:
        return float((np.abs(image(renderer, f, toggles=RenderToggles(**toggle)) - base).max(-1) > 30).mean())

    assert changed(eyebrows=False) > 0.002
    assert changed(eye_cover=False) > 0.002
    assert changed(wireframe=True) > 0.02
    assert changed(surface_3d=True) > 0.05
    marked = image(renderer, f, toggles=RenderToggles(eye_centre=True))
    red = np.array(renderer.config.colors["eye_centre"]) * 255
    assert (np.abs(marked - red).max(-1) < 10).sum() > 20


def test_trajectory_overlay_draws_the_gaze_path(renderer: Renderer) -> None:
    f = flexors()
    path = np.stack([np.linspace(-0.8, 0.8, 40), 0.3 * np.sin(np.linspace(0, 6, 40))], 1)
    drawn = image(renderer, f, overlay_points=path)
    hidden = image(renderer, f, overlay_points=path, toggles=RenderToggles(trajectory=False))
    green = np.array(renderer.config.colors["trajectory"]) * 255
    line = np.abs(drawn - green).max(-1) < 10
    assert line.sum() > 60
    assert not (np.abs(hidden - green).max(-1) < 10).any()
    xs = np.nonzero(line[:, : SIZE[0] // 2])[1]  # the viewer's-left eye's path spans the gaze range
    assert xs.max() - xs.min() > 8
    with pytest.raises(ValueError, match="overlay_points"):
        renderer.render(f, overlay_points=np.zeros((4, 3)))


def test_nan_flexors_render_as_relaxed(renderer: Renderer) -> None:
    relaxed = image(renderer, flexors())
    nan = np.full(N_FLEXORS, np.nan)
    assert np.array_equal(image(renderer, nan), relaxed)


def test_renders_into_any_target_with_its_own_aspect(ctx, renderer: Renderer) -> None:
    target = create_offscreen_target(ctx, (200, 300))
    try:
        renderer.render(flexors(look_x=0.4), target=target)
        img = read_rgb(target)
        assert img.shape == (300, 200, 3)
        pupils = renderer.to_pixels(renderer.last_pose.pupils, size=(200, 300))
        assert np.abs(centroid(mask_of(img.astype(np.int32), GREEN)) - pupils.mean(0)).max() < 3
    finally:
        target.release()
    with pytest.raises(ValueError, match="view"):
        renderer.render(flexors(), view="side")


class CountingContext:
    """Wraps a moderngl context and counts every GL object it is asked to create."""

    FACTORIES = (
        "buffer",
        "program",
        "vertex_array",
        "simple_vertex_array",
        "texture",
        "texture_array",
        "texture3d",
        "framebuffer",
        "renderbuffer",
        "depth_renderbuffer",
        "depth_texture",
        "sampler",
        "query",
        "scope",
    )

    def __init__(self, ctx: object) -> None:
        object.__setattr__(self, "_ctx", ctx)
        object.__setattr__(self, "created", 0)

    def __getattr__(self, name: str) -> object:
        attr = getattr(self._ctx, name)
        if name in self.FACTORIES:

            def counted(*args: object, **kwargs: object) -> object:
                object.__setattr__(self, "created", self.created + 1)
                return attr(*args, **kwargs)

            return counted
        return attr

    def __setattr__(self, name: str, value: object) -> None:
        setattr(self._ctx, name, value)


def test_gl_objects_are_made_once_not_per_frame(ctx) -> None:
    counting = CountingContext(ctx)
    r = Renderer(counting, (64, 48))  # type: ignore[arg-type]
    after_init = counting.created
    assert after_init > 0
    rng = np.random.default_rng(3)
    for i in range(8):
        toggles = RenderToggles(wireframe=i % 2 == 0, surface_3d=i % 3 == 0, eye_centre=True)
        r.render(
            rng.uniform(-1, 1, N_FLEXORS),
            view=("full", "upper")[i % 2],
            toggles=toggles,
            overlay_points=rng.uniform(-1, 1, (50, 2)),
        )
    assert counting.created == after_init


def test_the_head_outline_lies_only_along_the_background(ctx, monkeypatch) -> None:
    """The head's outline is its contour against what lies behind it: where the head folds away (the
    hair's ledge, the chin's blend into the jaw), an edge between a front and a back face runs across the
    visible surface, and no line may be drawn along it."""
    import eca.services.processes.renderer.renderer as module

    config = load_render_config()
    r = Renderer(ctx, (640, 480), dataclasses.replace(config, colors=dict(config.colors, outline=MAGENTA)))
    draw = r._draw

    def head_outline_only(mesh: str, prog: str, groups: list[str], kind: str = module.SURFACE) -> None:
        if kind == module.OUTLINE:
            groups = [g for g in groups if mesh == "static" and g == "face"]
        return draw(mesh, prog, groups, kind)

    monkeypatch.setattr(r, "_draw", head_outline_only)
    background = np.array(r.config.colors["background"]) * 255
    outline = np.array(MAGENTA) * 255
    reach = int(np.ceil(r.config.outline_px)) + 1
    poses = [flexors(turn=-0.5, tilt=0.5), flexors(turn=0.9, nod=-0.4), flexors(turn=-0.9, nod=0.5, tilt=-0.6)]
    poses += [flexors(turn=t, nod=n, tilt=-t) for t in (-1.0, 1.0) for n in (-1.0, 1.0)]
    for f in poses:
        img = image(r, f)
        lines = np.abs(img - outline).max(-1) < 30
        near_background = np.abs(img - background).max(-1) < 3
        grown = dilated(near_background, reach)
        assert lines.sum() > 500
        assert not (lines & ~grown).any(), f"an outline crosses the head at {np.argwhere(lines & ~grown)[:3]}"
    r.release()


def test_outline_quads_match_an_inverted_hull(ctx, monkeypatch) -> None:
    """The silhouette quads draw the line an inverted hull of the static parts would (the old way)."""
    import eca.services.processes.renderer.renderer as module

    r = Renderer(ctx, SIZE)
    hull = np.concatenate([r.static.indices, r.static.indices + np.uint32(r.static.vertices.shape[0])])
    hull_ibo = ctx.buffer(hull.astype(np.uint32).tobytes())
    hull_vao = ctx.vertex_array(
        r.flat_progs[0],
        [(r.static_vbo, *module.VERTEX_FORMAT)],
        index_buffer=hull_ibo,
        index_element_size=4,
        skip_errors=True,
    )
    draw = r._draw

    def draw_hull(mesh: str, prog: str, groups: list[str], kind: str = module.SURFACE) -> None:
        if mesh != "static" or kind != module.OUTLINE:
            return draw(mesh, prog, groups, kind)
        ctx.enable(moderngl.CULL_FACE)
        ctx.cull_face = "front"
        base = r.static.indices.size
        for group in groups:
            first, count = r.static.ranges[group]
            hull_vao.render(moderngl.TRIANGLES, vertices=count, first=base + first)
        ctx.cull_face = "back"
        ctx.disable(moderngl.CULL_FACE)

    poses = [(flexors(), "full"), (flexors(say_ah=1.0, turn=0.4, tilt=-0.5), "full"), (flexors(lids_l=1.0), "upper")]
    quads = [image(r, f, view=view) for f, view in poses]
    monkeypatch.setattr(r, "_draw", draw_hull)
    for (f, view), expected in zip(poses, quads, strict=True):
        hulled = image(r, f, view=view)
        outline = np.array(r.config.colors["outline"]) * 255
        dark_q = np.abs(expected - outline).max(-1) < 40
        dark_h = np.abs(hulled - outline).max(-1) < 40
        # The same lines: nearly every outline pixel of one lies within a pixel of the other's.
        near_h = dilated(dark_h, 1)
        assert dark_q.sum() > 100 and (dark_q & ~near_h).sum() < 0.1 * dark_q.sum(), view
    hull_vao.release()
    hull_ibo.release()
    r.release()


def test_leaving_out_the_triangles_that_face_away_changes_no_pixel(ctx) -> None:
    """The surface pass is given only the static triangles that may face the camera: every pose and
    view draws the same picture as with all of them (GL would cull the rest)."""
    r = Renderer(ctx, SIZE)
    static = r.meshes["static"]
    rng = np.random.default_rng(11)
    names = ("turn", "nod", "tilt", "look_x", "look_y", "lids_l", "lids_r", "say_ah", "say_oo")
    poses = [flexors(**{n: float(rng.choice([-1.0, 1.0])) if rng.random() < 0.4 else float(rng.uniform(-1, 1))
                        for n in names}) for _ in range(24)]  # fmt: skip
    poses += [flexors(blink_l=1.0, turn=1.0, nod=-1.0), flexors(turn=-1.0, nod=1.0, tilt=1.0, say_ah=1.0)]
    toggles = [RenderToggles(), RenderToggles(eye_cover=False, wireframe=True)]
    drawn = []
    for i, f in enumerate(poses):
        kw = {"view": ("full", "upper")[i % 2], "toggles": toggles[(i // 2) % 2]}
        subset = image(r, f, **kw)
        assert static.ranges[SURFACE_FACE][1] < r.static.ranges["face"][1]  # some were left out
        static.EDGE_ON_SLACK = np.inf  # every triangle
        everything = image(r, f, **kw)
        del static.EDGE_ON_SLACK
        drawn.append(np.count_nonzero(subset != everything))
    assert drawn == [0] * len(poses)
    r.release()


def test_the_compiled_facing_pass_selects_what_the_numpy_reference_does(ctx) -> None:
    """FrameIndices.update_for (compiled) uploads the same triangles and outline quads, in the same groups,
    as update() given RigidFacing.distances, over random poses, the jaw (blended triangles) included."""
    r = Renderer(ctx, SIZE)
    static = r.meshes["static"]
    rng = np.random.default_rng(5)
    for i in range(40):
        f = rng.uniform(-1, 1, N_FLEXORS) * (1.0 if i % 2 else 0.4)
        pose = r.poser.pose(f, dynamic=False)
        view_m, _ = r.camera(("full", "upper")[i % 2], 4 / 3, pose.model)
        modelview = view_m @ pose.model
        eye = -modelview[:3, :3].T @ modelview[:3, 3]
        static.update_for(pose.bones, eye)
        ranges, buffers = dict(static.ranges), {kind: ibo.read() for kind, ibo in static.ibos.items()}
        static.update(r.static_facing.distances(pose.bones, eye))
        expected_ranges, expected_buffers = static.ranges, {kind: ibo.read() for kind, ibo in static.ibos.items()}
        assert ranges == expected_ranges
        for kind in (SURFACE, "outline"):
            used = sum(count for (k, _), (_, count) in ranges.items() if k == kind) * 4
            assert used > 0 and buffers[kind][:used] == expected_buffers[kind][:used], kind
    r.release()


def test_the_warm_up_compiles_what_a_frame_runs(ctx) -> None:
    """kernels.warm_up (which setup runs) compiles each compiled function for the very argument types a
    renderer's frame passes it, so that no frame compiles anything."""
    from eca.services.processes.renderer import curves, kernels, poser

    compiled = [kernels.static_frame_indices, curves.brow_curves, curves._mouth_shape, curves._curve_rows,
                curves.curve_block, poser._pose_bones]  # fmt: skip
    kernels.warm_up()
    before = [list(fn.signatures) for fn in compiled]
    r = Renderer(ctx, SIZE)
    for view in ("full", "upper"):
        image(r, flexors(say_ah=0.5, turn=0.3, blink_l=1.0), view=view)
    assert [list(fn.signatures) for fn in compiled] == before
    assert all(len(signatures) >= 1 for signatures in before)
    r.release()


def test_the_vertex_shader_builds_the_brows_and_mouth_where_numpy_does(ctx) -> None:
    """The real FACE_VERTEX, by transform feedback, over the dynamic vertices built from the uploaded
    curve block: positions and normals where build_dynamic puts them, and the jaw weights, read through
    a jaw bone that only lifts by 1 in z."""
    poser = FacePoser()
    template = shader_template(poser.layout).astype(np.float32)
    n = template.shape[0]
    prog = ctx.program(vertex_shader=FACE_VERTEX, varyings=["gl_Position", "v_normal"])
    frame = np.tile(np.eye(4, dtype=np.float32), (N_BONES + 1, 1, 1))
    frame[1, 3, 2] = 1.0  # the jaw bone (column-major: column 3 is the translation)
    frames = ctx.buffer(frame.tobytes())
    block = np.zeros((CURVE_POINTS + TUBE_POINTS, 4), dtype=np.float32)
    curves = ctx.buffer(reserve=block.nbytes)
    prog["Frame"].binding, prog["Curves"].binding = 0, 1
    vbo = ctx.buffer(template.tobytes())
    vao = ctx.vertex_array(prog, [(vbo, *VERTEX_FORMAT)], skip_errors=True)
    out = ctx.buffer(reserve=n * 7 * 4)
    target = create_offscreen_target(ctx, (4, 4))  # Mesa runs transform feedback only with a framebuffer bound
    target.use()
    rng = np.random.default_rng(8)
    for f in [flexors(), flexors(say_ah=1.0, say_oo=0.4, smile_r=1.0, brows_knit=0.8)] + [
        rng.uniform(-1, 1, N_FLEXORS) for _ in range(4)
    ]:
        full = poser.pose(f).dynamic
        poser.build_dynamic(poser.pose(f, dynamic=False), block)
        curves.write(block)
        frames.bind_to_uniform_block(0)
        curves.bind_to_uniform_block(1)
        vao.transform(out, mode=moderngl.POINTS, vertices=n)
        got = np.frombuffer(out.read(), dtype=np.float32).reshape(n, 7)
        expected = full[:, 0:3] + np.outer(full[:, 12], [0.0, 0.0, 1.0])
        np.testing.assert_allclose(got[:, 0:3], expected, atol=2e-5)
        np.testing.assert_allclose(got[:, 4:7], full[:, 3:6], atol=2e-4)
    for obj in (vao, vbo, out, curves, frames, prog, target):
        obj.release()


def test_upper_view_keeps_the_eyes_in_frame_when_the_head_moves(renderer: Renderer) -> None:
    for pose in (flexors(nod=-1.0), flexors(nod=1.0), flexors(turn=0.8, tilt=-1.0)):
        img = image(renderer, pose, view="upper")
        xs, ys = np.nonzero(mask_of(img, GREEN))[::-1]
        assert xs.size > 20
        assert SIZE[1] * 0.3 < ys.mean() < SIZE[1] * 0.9, pose  # the camera followed the eyes
    fixed = image(renderer, flexors(nod=-1.0))  # the full view does not follow: the eyes go down
    assert centroid(mask_of(fixed, GREEN))[1] > centroid(mask_of(image(renderer, flexors()), GREEN))[1] + 5


def test_release_frees_the_renderers_objects(ctx) -> None:
    r = Renderer(ctx, (32, 24))
    r.render(flexors())
    r.release()
    other = Renderer(ctx, (32, 24))  # the context is still usable
    other.render(flexors(look_x=0.5))
    assert read_rgb(other.fbo).shape == (24, 32, 3)
    other.release()
