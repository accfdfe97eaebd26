"""The default head's jaw follows the voice: a loud vowel block through eca's own lip-sync (eca/agent/lipsync, the
audio service's estimator) opens the head's mouth, the silence after it closes it again, through the same path
the live face takes (mouth weights -> flexors -> ComposedFace -> rig frame -> the head's JawOpen)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from eca.agent.face.composed import ComposedFace
from eca.agent.lipsync import mouth_track
from eca.services.processes.renderer import HeadlessContextError, create_headless_context, make_drawer, read_rgb
from eca.services.processes.renderer.drawer import FaceDrawer
from tests.support.faces import composed_face

pytestmark = pytest.mark.gl

RATE = 16_000
SIZE = (320, 240)


def vowel(seconds: float) -> np.ndarray:
    """A loud voiced vowel: harmonics of 140 Hz shaped like an /a/ (formants near 700 and 1200 Hz)."""
    t = np.arange(round(seconds * RATE)) / RATE
    wave = sum(np.sin(2 * np.pi * 140 * k * t) / k * (1.5 if 4 <= k <= 9 else 1.0) for k in range(1, 30))
    return (0.5 * wave / np.abs(wave).max()).astype(np.float32)


@pytest.fixture(scope="module")
def head() -> Iterator[FaceDrawer]:
    try:
        ctx = create_headless_context()
    except HeadlessContextError as exc:
        pytest.skip(str(exc))
    drawer = make_drawer(ctx, SIZE, "head")
    yield drawer
    drawer.release()
    ctx.release()


def face_at(weights: dict[str, float]) -> ComposedFace:
    return composed_face(**weights)


def dark_pixels(drawer: FaceDrawer, face: ComposedFace) -> int:
    """The dark inside of an open mouth (and nothing else of the face is that dark)."""
    rgb = read_rgb(drawer.draw(face)).astype(int)
    return int((rgb.sum(axis=2) < 3 * 90).sum())


def test_a_loud_block_opens_the_jaw_and_the_silence_after_it_closes_it(head: FaceDrawer) -> None:
    sound = np.concatenate([np.zeros(RATE // 2, np.float32), vowel(0.5), np.zeros(RATE // 2, np.float32)])
    track = mouth_track(sound, RATE)
    before = face_at(track.weights_at(0.25 * RATE))  # in the silence before
    during = face_at(track.weights_at(0.75 * RATE))  # in the middle of the vowel
    after = face_at(track.weights_at(1.45 * RATE))  # well into the silence after
    assert during.frame.get("say_ah") > 0.3 and before.frame.get("say_ah") < 0.05 and after.frame.get("say_ah") < 0.05
    shut, opened, closed = (dark_pixels(head, f) for f in (before, during, after))
    assert opened > shut + 200, (shut, opened)  # the inside of the mouth shows
    assert closed <= shut + 20, (shut, closed)  # and is gone again
