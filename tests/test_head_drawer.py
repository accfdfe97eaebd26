"""The 3D face drawer (eca/services/processes/renderer/head/): a face drawn on an avatar, whose pupils follow the
commanded gaze, whose lids close in a blink and whose jaw opens and closes; on the procedural sample head and, once
it is baked, on the default head (eca/assets/default_head.glb). Pictures are read back and measured; nothing here
compares against stored images."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator

import moderngl
import numpy as np
import pytest

from eca.agent.face.composed import ComposedFace
from eca.agent.face.settings import load_flexor_units
from eca.services.processes.avatar.loader import load_avatar
from eca.services.processes.avatar.model import AlphaMode, Avatar, Texture
from eca.services.processes.renderer import HeadlessContextError, create_headless_context, read_rgb
from eca.services.processes.renderer.head import DEFAULT_HEAD, HeadDrawer, sample_avatar
from tests.support.faces import composed_face as face

pytestmark = pytest.mark.gl

SIZE = (320, 240)
UNITS = load_flexor_units()
AVATARS = ["sample", pytest.param("default", marks=pytest.mark.skipif(not DEFAULT_HEAD.exists(),
                                                                         reason="the default head is not baked yet"))]




@pytest.fixture(scope="module")
def ctx() -> Iterator[moderngl.Context]:
    try:
        context = create_headless_context()
    except HeadlessContextError as exc:
        pytest.skip(f"no headless OpenGL context: {exc}")
    yield context
    context.release()


@pytest.fixture(scope="module", params=AVATARS)
def drawer(request: pytest.FixtureRequest, ctx: moderngl.Context) -> Iterator[HeadDrawer]:
    avatar = sample_avatar() if request.param == "sample" else load_avatar(DEFAULT_HEAD)
    d = HeadDrawer(ctx, SIZE, green_pupils(avatar), samples=0)
    yield d
    d.release()


def picture(drawer: HeadDrawer, f: ComposedFace, view: str = "full") -> np.ndarray:
    return read_rgb(drawer.draw(f, view=view)).astype(np.int32)


def background(drawer: HeadDrawer) -> np.ndarray:
    return np.round(np.asarray(drawer.config.colors["background"]) * 255).astype(np.int32)


def eye_boxes(drawer: HeadDrawer, view: str, above: float = 1.0) -> list[tuple[slice, slice]]:
    """A box about each eye's rest centre in pixels (rows, columns), left eye first: an eyeball's radius to the
    sides and below, `above` radii up (the upper lid's lashes sit about 0.4 radii above the centre)."""
    drawer.draw(face(), view=view)
    eyes = drawer.camera.measure.eyes
    centres = drawer.to_pixels(eyes)
    r = abs(drawer.to_pixels(eyes[:1] + (drawer.eye_radius, 0.0, 0.0))[0, 0] - centres[0, 0])
    return [(slice(int(y - above * r), int(y + r) + 1), slice(int(x - r), int(x + r) + 1)) for x, y in centres]


def green_pupils(avatar: Avatar) -> Avatar:
    """The avatar with its pupils pure green, so the pictures show where they are (lashes and lid lines are as
    dark as a pupil): in the textures of what moves with the eye joints, the darkest texels (an iris's dark rim
    is a little lighter); and the corneas
    over them matte, so no catchlight whitens part of a pupil (it stays where the light is, not with the eye)."""
    eyes = {avatar.skeleton.humanoid[b] for b in ("leftEye", "rightEye")}
    materials = list(avatar.materials)
    for prim in avatar.primitives:
        m = materials[prim.material]
        if prim.node in eyes and m.texture is not None and m.alpha_mode is AlphaMode.OPAQUE:
            rgba = m.texture.rgba.copy()
            value = rgba[..., :3].astype(np.int32).sum(axis=2)
            rgba[value <= value.min() + 12] = (0, 255, 0, 255)
            materials[prim.material] = dataclasses.replace(m, texture=Texture(rgba))
        elif prim.node in eyes and m.alpha_mode is AlphaMode.BLEND:
            materials[prim.material] = dataclasses.replace(m, roughness=1.0)
    return dataclasses.replace(avatar, materials=tuple(materials))


def pupil_centre(img: np.ndarray, box: tuple[slice, slice]) -> tuple[float, float, int]:
    """(x, y, count) of the (green) pupil in a box; count 0 when none shows."""
    part = img[box]
    green = (part[..., 1] > part[..., 0] + 60) & (part[..., 1] > part[..., 2] + 60)
    ys, xs = np.nonzero(green)
    if len(xs) == 0:
        return (float("nan"), float("nan"), 0)
    return (float(xs.mean()) + box[1].start, float(ys.mean()) + box[0].start, int(len(xs)))


def sclera(img: np.ndarray, box: tuple[slice, slice]) -> int:
    """How many pixels of the box are the white of an eye (bright in every channel; lit skin is not in blue)."""
    return int((img[box].min(axis=2) > 200).sum())


def test_it_draws_a_face_where_the_head_is(drawer: HeadDrawer) -> None:
    img = picture(drawer, face())
    bg = background(drawer)
    off = np.abs(img - bg).sum(axis=2) > 12
    assert off[0:4, 0:4].sum() == 0 and off[-4:, -4:].sum() == 0  # the corners are background
    assert 0.2 < off.mean() < 0.85  # the head fills much of the picture, as the 2D face does
    for x, y in drawer.to_pixels(drawer.camera.measure.eyes):
        assert 0 < x < SIZE[0] and 0 < y < SIZE[1] and off[int(y), int(x)]
    left, right = drawer.to_pixels(drawer.camera.measure.eyes)
    assert left[0] > right[0]  # the agent's left eye is on the viewer's right
    rows, cols = np.nonzero(off)
    assert abs(cols.mean() - SIZE[0] / 2) < SIZE[0] * 0.08  # centred


def test_the_upper_view_frames_the_eyes_larger(drawer: HeadDrawer) -> None:
    drawer.draw(face(), view="full")
    full = drawer.to_pixels(drawer.camera.measure.eyes)
    drawer.draw(face(), view="upper")
    upper = drawer.to_pixels(drawer.camera.measure.eyes)
    assert (upper[0, 0] - upper[1, 0]) > 2.5 * (full[0, 0] - full[1, 0])
    assert np.all((upper > 0) & (upper < SIZE)) and upper[:, 1].mean() > SIZE[1] / 2  # brows above, in frame
    # The upper view follows the eyes when the head turns and nods; the full view's camera stays put.
    drawer.draw(face(turn=0.6, nod=0.5), view="upper")
    moved = drawer.to_pixels(drawer.pupils())
    assert np.all((moved > 0) & (moved < SIZE))
    assert abs(moved[:, 1].mean() - upper[:, 1].mean()) < SIZE[1] * 0.1


@pytest.mark.parametrize("axis", ["yaw", "pitch"])
def test_the_pupils_follow_the_commanded_gaze(drawer: HeadDrawer, axis: str) -> None:
    angles = [-20.0, -10.0, 0.0, 10.0, 20.0] if axis == "yaw" else [-20.0, -10.0, 0.0, 8.0, 15.0]
    boxes = eye_boxes(drawer, "upper")
    found = []
    for a in angles:
        eyes = (a, 0.0) if axis == "yaw" else (0.0, a)
        img = picture(drawer, face(eyes), "upper")
        centres = [pupil_centre(img, box) for box in boxes]
        assert all(count > 5 for _, _, count in centres), f"no pupil found at {axis} {a}"
        found.append([c[:2] for c in centres])
        if a == 0.0:  # looking ahead, the picture's pupils are where the posed eyes put them
            assert np.abs(np.array(found[-1]) - drawer.to_pixels(drawer.pupils())).max() < 3.0
    xy = np.array(found)  # (angles, eyes, (x, y))
    if axis == "yaw":
        # + yaw is toward the agent's right: the viewer's left, smaller x; the height stays
        assert np.all(np.diff(xy[:, :, 0], axis=0) < -1.0)
        assert np.ptp(xy[:, :, 1]) < 4.0
    else:
        assert np.all(np.diff(xy[:, :, 1], axis=0) < -1.0)  # + pitch is up: smaller y
        assert np.ptp(xy[:, :, 0], axis=0).max() < 4.0


def test_a_blink_closes_the_lids_over_the_eyes(drawer: HeadDrawer) -> None:
    boxes = eye_boxes(drawer, "upper")
    open_img = picture(drawer, face(), "upper")
    shut = picture(drawer, face(blink_l=1.0, blink_r=1.0), "upper")
    for box in boxes:
        assert sclera(open_img, box) > 0.01 * open_img[box].shape[0] * open_img[box].shape[1]
        assert sclera(shut, box) < 0.02 * sclera(open_img, box)  # nothing of the eye shows
        assert np.abs(shut[box] - open_img[box]).sum(axis=2).mean() > 30
    # One lid: the agent's left eye is the one on the viewer's right; the other stays open.
    wink = picture(drawer, face(blink_l=1.0), "upper")
    assert sclera(wink, boxes[0]) < 0.02 * sclera(open_img, boxes[0])
    assert sclera(wink, boxes[1]) > 0.8 * sclera(open_img, boxes[1])
    again = picture(drawer, face(), "upper")
    assert np.array_equal(again, open_img)


def test_the_jaw_opens_and_closes(drawer: HeadDrawer) -> None:
    closed = picture(drawer, face())
    opened = picture(drawer, face(say_ah=1.0))
    assert drawer.last_frame is not None and drawer.last_frame.arkit_weight("JawOpen") == 1.0
    changed = np.abs(opened - closed).sum(axis=2) > 30
    eyes_y = drawer.to_pixels(drawer.camera.measure.eyes)[:, 1].mean()
    rows = np.nonzero(changed)[0]
    assert changed.sum() > 0.01 * changed.size and np.median(rows) > eyes_y + 0.1 * SIZE[1]  # below the eyes
    # Opening shows the dark inside of the mouth.
    dark = (opened.sum(axis=2) < 3 * 90).sum() - (closed.sum(axis=2) < 3 * 90).sum()
    assert dark > 0.002 * changed.size
    half = picture(drawer, face(say_ah=0.5))
    assert 0 < (np.abs(half - closed).sum(axis=2) > 30).sum() < changed.sum()
    assert np.array_equal(picture(drawer, face()), closed)  # and closes again


def test_the_head_turns_toward_the_agents_right(drawer: HeadDrawer) -> None:
    drawer.draw(face())
    still = drawer.to_pixels(drawer.camera.measure.eyes).mean(axis=0)
    drawer.draw(face(turn=0.5))
    turned = drawer.to_pixels(drawer.pupils()).mean(axis=0)
    assert turned[0] < still[0] - 5  # the viewer's left


def test_stills_can_ask_for_multisampling(ctx: moderngl.Context) -> None:
    plain = HeadDrawer(ctx, SIZE, sample_avatar(), samples=0)
    smooth = HeadDrawer(ctx, SIZE, sample_avatar(), samples=4)
    try:
        a = read_rgb(plain.draw(face())).astype(np.int32)
        b = read_rgb(smooth.draw(face())).astype(np.int32)
        diff = np.abs(a - b).sum(axis=2)
        assert smooth.samples == 4 and plain.samples == 0
        # the same picture but along the edges, where the multisampled one has in-between colours
        assert (diff > 30).mean() < 0.03 and (diff > 0).sum() > 50
        assert len(np.unique(b.reshape(-1, 3), axis=0)) > len(np.unique(a.reshape(-1, 3), axis=0))
    finally:
        plain.release()
        smooth.release()
