"""`eca snapshot`: argument checking, one still, the contact sheet."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from eca.agent.face.emotions import PAPER_EMOTIONS, load_emotion_table
from eca.agent.face.flexors import FLEXOR_INDEX
from eca.services.processes.renderer import HeadlessContextError, create_headless_context
from eca.services.processes.renderer.config import load_render_config
from eca.services.tools.commands import snapshot
from eca.services.tools.commands.snapshot import SnapshotError, parse_size, pose_flexors


def _gl_available() -> bool:
    try:
        create_headless_context().release()
    except HeadlessContextError:
        return False
    return True


needs_gl = pytest.mark.skipif(not _gl_available(), reason="no headless OpenGL (EGL) context")


def main(argv: list[str]) -> int:
    """Run `eca snapshot` through its own subparser (the CLI adds it the same way)."""
    parser = argparse.ArgumentParser(prog="eca")
    snapshot.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return int(args.func(args))


def test_parse_size() -> None:
    assert parse_size("640x480") == (640, 480)
    assert parse_size("32X24") == (32, 24)
    for bad in ("640", "x480", "640x", "-5x10", "axb", "8x8", "10000x10"):
        with pytest.raises(SnapshotError, match="--size"):
            parse_size(bad)


def test_pose_flexors_layers_gaze_head_and_mouth_over_the_emotion() -> None:
    table, config = load_emotion_table(), load_render_config()
    f = pose_flexors(table, config, "surprised", 0.5, yaw=15.0, pitch=-6.0, turn=0.2, mouth="oo")
    assert f[FLEXOR_INDEX["look_x"]] == pytest.approx(15.0 / config.units.look_x_deg)
    assert f[FLEXOR_INDEX["look_y"]] == pytest.approx(-6.0 / config.units.look_y_deg)
    assert f[FLEXOR_INDEX["turn"]] == 0.2
    assert f[FLEXOR_INDEX["say_oo"]] == 1.0 and f[FLEXOR_INDEX["say_ah"]] == 0.0  # --mouth wins
    full = pose_flexors(table, config, "surprised", 1.0)
    half = pose_flexors(table, config, "surprised", 0.5)
    brow = FLEXOR_INDEX["brow_l"]
    assert 0 < half[brow] < full[brow] and half[brow] == pytest.approx(full[brow] / 2)
    assert not np.isnan(pose_flexors(table, config, "natural")).any()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--emotion", "gleeful"], "unknown emotion 'gleeful'"),
        (["--intensity", "1.5"], "--intensity must lie in"),
        (["--yaw", "45"], "--yaw must lie in"),
        (["--pitch", "nan"], "--pitch must lie in"),
        (["--turn", "2"], "--turn must lie in"),
        (["--size", "big"], "--size must look like"),
        (["--supersample", "9"], "--supersample must lie in"),
    ],
)
def test_bad_arguments_are_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    out = tmp_path / "x.png"
    assert main(["snapshot", "-o", str(out), *argv]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_bad_output_paths_are_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["snapshot", "-o", str(tmp_path / "x.jpg")]) == 2
    assert ".png" in capsys.readouterr().err
    assert main(["snapshot", "-o", str(tmp_path / "missing" / "x.png")]) == 2
    assert "does not exist" in capsys.readouterr().err


@pytest.mark.gl
@needs_gl
def test_writes_a_still_of_the_requested_size(tmp_path: Path) -> None:
    out = tmp_path / "angry.png"
    argv = [
        "snapshot",
        "--emotion",
        "angry",
        "--intensity",
        "0.5",
        "--view",
        "upper",
        "--size",
        "96x72",
        "--supersample",
        "1",
        "--yaw",
        "-10",
        "--eye-centre",
        "-o",
        str(out),
    ]
    assert main(argv) == 0
    img = Image.open(out)
    assert img.size == (96, 72) and img.mode == "RGB"
    assert np.asarray(img).std() > 10  # a picture, not a blank


@pytest.mark.gl
@needs_gl
def test_sheet_lays_out_the_nine_emotions_with_labels(tmp_path: Path) -> None:
    out = tmp_path / "sheet.png"
    assert main(["snapshot", "--sheet", "--size", "64x48", "--supersample", "1", "-o", str(out)]) == 0
    img = np.asarray(Image.open(out)).astype(int)
    label_h = 18  # max(18, 48 // 8)
    assert img.shape == (3 * (48 + label_h), 3 * 64, 3)
    cells = [
        img[r * (48 + label_h) : r * (48 + label_h) + 48, c * 64 : (c + 1) * 64] for r in range(3) for c in range(3)
    ]
    assert len(cells) == len(PAPER_EMOTIONS)
    # every emotion looks different from every other (half-angry vs angry included)
    for i in range(len(cells)):
        for j in range(i + 1, len(cells)):
            assert np.abs(cells[i] - cells[j]).max(-1).astype(bool).mean() > 0.005, (
                PAPER_EMOTIONS[i],
                PAPER_EMOTIONS[j],
            )
    labels = img[48 : 48 + label_h]
    assert (labels.min(-1) < 100).any()  # dark label text under the first row
