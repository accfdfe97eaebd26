"""Golden images of the face, compared with a tolerance (RMS and fraction of changed pixels).

Regenerate after an intended change of the look with:  ECA_REGEN_GOLDEN=1 pytest tests/test_render_golden.py
and look at the new files in tests/golden/ before committing them.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from eca.agent.face.emotions import load_emotion_table
from eca.agent.face.flexors import FLEXOR_INDEX, N_FLEXORS
from eca.services.processes.renderer import (
    HeadlessContextError,
    Renderer,
    RenderToggles,
    create_headless_context,
    read_rgb,
)
from tests.support.golden import check_golden, compare

pytestmark = pytest.mark.gl

SIZE = (160, 120)
MAX_RMS = 6.0  # of 255: rasterisers may differ in edge pixels, not in what is drawn
MAX_CHANGED = 0.02  # fraction of pixels differing by more than CHANGED_LEVEL in any channel


def _f(**values: float) -> np.ndarray:
    f = np.zeros(N_FLEXORS)
    for name, value in values.items():
        f[FLEXOR_INDEX[name]] = value
    return f


def _emotion(name: str, **extra: float) -> np.ndarray:
    f = np.nan_to_num(load_emotion_table().pose(name), nan=0.0)
    for key, value in extra.items():
        f[FLEXOR_INDEX[key]] = value
    return f


CASES: dict[str, tuple[callable, str, RenderToggles]] = {
    "face_neutral_full": (lambda: _f(), "full", RenderToggles()),
    "face_happy_full": (lambda: _emotion("happy"), "full", RenderToggles()),
    "face_angry_upper": (lambda: _emotion("angry"), "upper", RenderToggles()),
    "face_look_turn_ah": (
        lambda: _f(look_x=0.6, look_y=-0.3, turn=0.4, nod=-0.2, tilt=0.3, say_ah=0.8),
        "full",
        RenderToggles(),
    ),
    "face_blink_wire_3d": (lambda: _f(blink_l=1.0, say_oo=1.0), "full", RenderToggles(wireframe=True, surface_3d=True)),
}


@pytest.fixture(scope="module")
def renderer() -> Iterator[Renderer]:
    try:
        ctx = create_headless_context()
    except HeadlessContextError as exc:
        pytest.skip(f"no headless OpenGL context: {exc}")
    yield Renderer(ctx, SIZE)
    ctx.release()




@pytest.mark.parametrize("name", sorted(CASES))
def test_matches_golden_image(renderer: Renderer, name: str) -> None:
    flexors, view, toggles = CASES[name]
    renderer.render(flexors(), view=view, toggles=toggles)
    actual = read_rgb(renderer.fbo)
    check_golden(actual, name, MAX_RMS, MAX_CHANGED)


def test_the_comparison_catches_a_real_change(renderer: Renderer) -> None:
    renderer.render(_f())
    neutral = read_rgb(renderer.fbo)
    renderer.render(_f(say_ah=1.0, brow_l=1.0, brow_r=1.0))
    rms, changed = compare(read_rgb(renderer.fbo), neutral)
    assert changed > MAX_CHANGED or rms > MAX_RMS
    assert compare(neutral, neutral) == (0.0, 0.0)
