"""`eca render`: deterministic offline renders of scripts, with audio, CSV and MP4."""

from __future__ import annotations

import csv
from pathlib import Path

import av
import numpy as np
import pytest

from agent.face.flexors import FLEXOR_NAMES
from agent.script import build_timeline
from services.cli import main as eca
from services.offline import RenderSettings, animate

pytestmark = pytest.mark.gl
DATA = Path(__file__).parent / "data" / "scripts"
EYE_FLEXORS = {"look_x", "look_y", "blink_l", "blink_r", "lids_l", "lids_r"}


@pytest.fixture
def scripts(tmp_path: Path) -> list[str]:
    status = tmp_path / "status.txt"
    status.write_text(
        "header\nelement transition 3\nproperty double duration\nproperty string role\nend_header\n"
        "1.0;talking\n1.0;listening\n1.0;silence\n"
    )
    emotion = tmp_path / "emotion.txt"
    emotion.write_text(
        "header\nelement transition 2\nproperty double duration\nproperty string emotion\n"
        "property double intensity\nend_header\n1.5;surprised;1\n1.5;angry;0.8\n"
    )
    return [str(status), str(emotion), str(DATA / "paper_head.txt")]


def render(scripts: list[str], out: Path, seed: int) -> Path:
    code = eca(
        ["render", *scripts, "-o", str(out), "--seed", str(seed), "--size", "160x120", "--fps", "15", "--no-voice"]
    )
    assert code == 0
    return out.with_suffix(".csv")


def read_csv(path: Path) -> dict[str, np.ndarray]:
    with open(path) as fh:
        rows = list(csv.DictReader(fh))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


def test_same_seed_gives_identical_csv_and_another_seed_changes_only_eyes_and_blinks(
    scripts: list[str], tmp_path: Path
) -> None:
    a = render(scripts, tmp_path / "a.mp4", seed=1)
    b = render(scripts, tmp_path / "b.mp4", seed=1)
    c = render(scripts, tmp_path / "c.mp4", seed=2)
    assert a.read_bytes() == b.read_bytes()
    one, other = read_csv(a), read_csv(c)
    changed = {name for name in FLEXOR_NAMES if not np.array_equal(one[name], other[name])}
    assert changed and changed <= EYE_FLEXORS, changed
    assert "look_x" in changed or "look_y" in changed


def test_the_video_has_every_frame_and_an_audio_track(scripts: list[str], tmp_path: Path) -> None:
    out = tmp_path / "v.mp4"
    table = read_csv(render(scripts, out, seed=0))
    with av.open(str(out)) as container:
        kinds = sorted(s.type for s in container.streams)
        frames = sum(1 for _ in container.decode(video=0))
    assert kinds == ["audio", "video"]
    assert frames == table["t_s"].size
    assert table["t_s"][1] == pytest.approx(1 / 15, abs=1e-6)


def test_emotions_and_head_follow_the_script_times(scripts: list[str]) -> None:
    timeline = build_timeline(scripts, agent="agent")
    result = animate(timeline, "agent", RenderSettings(fps=30.0, eyes="saccade"), voices=None)
    idx = {n: i for i, n in enumerate(FLEXOR_NAMES)}
    t = result.t_s
    brows = result.flexors[:, idx["brow_l"]]
    knit = result.flexors[:, idx["brows_knit"]]
    turn = result.flexors[:, idx["turn"]]
    assert brows[(t > 1.2) & (t < 1.5)].mean() > 0.3  # surprised raises the brows
    assert knit[(t > 2.6) & (t < 3.0)].mean() > 0.3  # angry knits them
    # the paper's head file: turn to 1 over 2 s, then to -1 over 3 s
    assert turn[np.searchsorted(t, 2.0)] == pytest.approx(1.0, abs=0.05)
    assert turn[np.searchsorted(t, 5.0)] == pytest.approx(-1.0, abs=0.05)
    assert turn[np.searchsorted(t, 0.1)] < turn[np.searchsorted(t, 1.0)] < turn[np.searchsorted(t, 1.9)]


def test_bad_arguments_are_refused_with_a_clear_message(scripts: list[str], tmp_path: Path, capsys) -> None:
    assert eca(["render", *scripts, "-o", str(tmp_path / "x.avi")]) == 1
    assert "must be an .mp4" in capsys.readouterr().err
    assert eca(["render", *scripts, "-o", str(tmp_path / "x.mp4"), "--size", "161x120"]) == 1
    assert "even" in capsys.readouterr().err
    bad = tmp_path / "bad.txt"
    bad.write_text("header\nend_header\n")
    assert eca(["render", str(bad), "-o", str(tmp_path / "y.mp4")]) == 1
    assert "bad.txt" in capsys.readouterr().err
    assert not (tmp_path / "y.mp4").exists()
