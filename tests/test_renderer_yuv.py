"""The face as yuv420p from the GPU (renderer/yuv.py) up to the picture's edges: a uniform picture's planes
are uniform to their first and last rows and columns (no chroma fetched from outside the texture, no
half-pixel shift, no row flipped or plane misplaced), at sizes that are and are not multiples of 16, and the
drawn face's background reaches all four edges of every plane."""

from __future__ import annotations

from collections.abc import Iterator

import moderngl
import numpy as np
import pytest

from eca.services.processes.renderer.config import load_render_config
from eca.services.processes.renderer.yuv import YuvTarget

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def ctx() -> Iterator[moderngl.Context]:
    from eca.services.processes.renderer import create_headless_context

    try:
        context = create_headless_context()
    except Exception as exc:  # pragma: no cover - depends on the machine
        pytest.skip(f"no headless OpenGL here: {exc}")
    yield context
    context.release()


def planes(yuv: np.ndarray, width: int, height: int) -> dict[str, np.ndarray]:
    """The Y, U and V planes of a (height * 3 / 2, width) yuv420p array, each as (rows, columns)."""
    flat = yuv.reshape(-1)
    y_end, c_size = width * height, width * height // 4
    return {"Y": flat[:y_end].reshape(height, width),
            "U": flat[y_end:y_end + c_size].reshape(height // 2, width // 2),
            "V": flat[y_end + c_size:].reshape(height // 2, width // 2)}


def bt601(rgb: tuple[float, float, float]) -> tuple[int, int, int]:
    """Y, U, V of an RGB colour in [0, 1]: ITU-R BT.601, limited range."""
    r, g, b = (255 * c for c in rgb)
    return (round(16 + (65.481 * r + 128.553 * g + 24.966 * b) / 255),
            round(128 + (-37.797 * r - 74.203 * g + 112.0 * b) / 255),
            round(128 + (112.0 * r - 93.786 * g - 18.214 * b) / 255))


def edges(plane: np.ndarray) -> dict[str, np.ndarray]:
    return {"first row": plane[0], "last row": plane[-1], "first column": plane[:, 0], "last column": plane[:, -1]}


BACKGROUND = load_render_config().colors["background"]


@pytest.mark.parametrize("size", [(640, 480), (160, 120), (200, 150), (322, 242)])
@pytest.mark.parametrize("colour", [BACKGROUND, (1.0, 0.0, 0.0), (0.1, 0.8, 0.3)])
def test_a_uniform_picture_is_uniform_to_the_edges_of_every_plane(ctx: moderngl.Context, size: tuple[int, int],
                                                                    colour: tuple[float, float, float]) -> None:
    width, height = size
    target = YuvTarget(ctx, size)
    try:
        target.fbo.use()
        target.fbo.clear(*colour, 1.0)
        got = planes(target.read(), width, height)
    finally:
        target.release()
    for (name, plane), want in zip(got.items(), bt601(colour), strict=True):
        interior = int(plane[plane.shape[0] // 2, plane.shape[1] // 2])
        assert abs(interior - want) <= 1, (name, interior, want)
        for where, line in edges(plane).items():
            assert (line == interior).all(), f"{name}'s {where}: {np.unique(line).tolist()}, interior {interior}"


def test_the_drawn_face_has_its_background_along_every_edge_of_every_plane(ctx: moderngl.Context) -> None:
    from eca.agent.face.model import FaceModel
    from eca.services.processes.renderer.renderer import Renderer

    width, height = 640, 480
    target = YuvTarget(ctx, (width, height))
    try:
        Renderer(ctx, (width, height)).render(FaceModel(seed=3).frame_at(0).values, target=target.fbo)
        got = planes(target.read(), width, height)
    finally:
        target.release()
    for (name, plane), want in zip(got.items(), bt601(BACKGROUND), strict=True):
        assert plane.std() > 10, name  # a face in the middle
        for where, line in edges(plane).items():
            assert (np.abs(line.astype(int) - want) <= 1).all(), \
                f"{name}'s {where}: {np.unique(line).tolist()}, not {want}"
