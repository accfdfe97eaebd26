"""`eca gaze-trace` and `eca gaze-plot`."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
import pytest

from agent.gaze.params import GazeParams
from services.cli import main
from services.commands.gaze_plot import PANELS, simulate_panels, trajectory_figure
from services.commands.gaze_trace import COLUMNS


def _trace(capsys: pytest.CaptureFixture[str], *args: str) -> list[dict[str, str]]:
    assert main(["gaze-trace", *args]) == 0
    return list(csv.DictReader(io.StringIO(capsys.readouterr().out)))


def test_trace_writes_saccades_as_csv(capsys: pytest.CaptureFixture[str]) -> None:
    rows = _trace(capsys, "--eyes", "saccade", "--role", "talking", "--seconds", "120", "--seed", "5")
    assert rows and tuple(rows[0]) == COLUMNS
    onsets = [float(r["onset_s"]) for r in rows]
    assert onsets == sorted(onsets) and onsets[-1] < 120.0
    assert {r["kind"] for r in rows} == {"mutual", "away"}
    for r in rows:
        assert float(r["duration_s"]) == pytest.approx(
            0.025 + 0.0024 * float(r["amplitude_deg"]), abs=2e-7
        )  # amplitude printed to 1e-4
        assert float(r["hold_s"]) > 0.0
    # Each next onset is the previous onset plus its duration plus its hold.
    for before, after in zip(rows, rows[1:], strict=False):
        expected = float(before["onset_s"]) + float(before["duration_s"]) + float(before["hold_s"])
        assert float(after["onset_s"]) == pytest.approx(expected, abs=3e-9)
    assert rows == _trace(capsys, "--eyes", "saccade", "--role", "talking", "--seconds", "120", "--seed", "5")
    assert rows != _trace(capsys, "--eyes", "saccade", "--role", "talking", "--seconds", "120", "--seed", "6")


def test_listening_holds_mutual_gaze_longer(capsys: pytest.CaptureFixture[str]) -> None:
    def mutual_share(role: str) -> float:
        rows = _trace(capsys, "--role", role, "--seconds", "600", "--seed", "1")
        return sum(r["kind"] == "mutual" for r in rows) / len(rows)

    assert mutual_share("listening") > mutual_share("talking") + 0.2


def test_trace_to_file_and_static_eyes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "trace.csv"
    assert main(["gaze-trace", "--eyes", "static", "--seconds", "30", "-o", str(out)]) == 0
    assert out.read_text().strip() == ",".join(COLUMNS)  # static eyes never move
    assert "wrote 0 saccades" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--seconds", "-1"], "--seconds must be in"),
        (["--emotion", "bored"], "unknown emotion 'bored'; valid: natural"),
        (["--intensity", "2"], "intensity must be in [0, 1]"),
        (["-o", "/nonexistent-dir/x.csv"], "cannot write /nonexistent-dir/x.csv"),
    ],
)
def test_trace_rejects_bad_arguments(capsys: pytest.CaptureFixture[str], args: list[str], message: str) -> None:
    assert main(["gaze-trace", "--seconds", "1", *args]) != 0
    assert message in capsys.readouterr().err


def test_trace_rejects_unknown_mode() -> None:
    with pytest.raises(SystemExit):
        main(["gaze-trace", "--eyes", "blinky"])


def test_plot_writes_both_pictures(tmp_path: Path) -> None:
    assert main(["gaze-plot", "-o", str(tmp_path), "--frames", "300", "--draws", "2000"]) == 0
    for name in ("gaze_trajectory.png", "gaze_statistics.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_trajectory_figure_draws_yaw_and_pitch_of_every_panel() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    params = GazeParams.load()
    yaw, pitch, lid = simulate_panels(params, 600, seed=0)
    noise = [title for title, _, _ in PANELS].index("(b) Perlin noise")
    assert np.ptp(pitch[:, noise]) > 1.0 and not np.array_equal(pitch, yaw)  # the eyes move up and down too
    fig = trajectory_figure(params, yaw, pitch, lid)
    try:
        rows = (fig.axes[: len(PANELS)], fig.axes[len(PANELS):])
        assert len(fig.axes) == 2 * len(PANELS)
        for (angles, word, limit), axes in zip(
            ((yaw, "yaw", params.eye_yaw_limit_deg), (pitch, "pitch", params.eye_pitch_limit_deg)), rows, strict=True
        ):
            for k, ax in enumerate(axes):
                trace = ax.get_lines()[0]
                assert np.array_equal(trace.get_xdata(), angles[:, k])  # the angle across ...
                assert np.array_equal(trace.get_ydata(), np.arange(600))  # ... time (frames) going up
                assert word in ax.get_xlabel() and "deg" in ax.get_xlabel()
                assert ax.get_xlim() == (-limit, limit)
    finally:
        plt.close(fig)
