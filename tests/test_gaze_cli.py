"""`eca gaze-trace` and `eca gaze-plot`."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
import pytest

from eca.agent.gaze.params import FACE_FEATURES, GazeParams
from eca.services.tools.cli import main
from eca.services.tools.commands.gaze_plot import PANELS, ZOOM_DEG, simulate_panels, trajectory_figure
from eca.services.tools.commands.gaze_trace import COLUMNS, EVENT_KINDS

NEW_MODE = "saccade+noise+blink"
EYES_ALIVE = ("mutual", "away")


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


def _fixation_seconds(rows: list[dict[str, str]], seconds: float) -> dict[str, float]:
    """Seconds spent fixating after each kind of Eyes Alive saccade (mutual, away): its hold, the last one cut
    at the end of the run. The trace starts with a decision at 0, so these cover the run but for flights."""
    spent = dict.fromkeys(EYES_ALIVE, 0.0)
    decisions = [r for r in rows if r["kind"] in EYES_ALIVE]
    for r in decisions:
        spent[r["kind"]] += float(r["hold_s"])
    last = decisions[-1]
    spent[last["kind"]] -= float(last["onset_s"]) + float(last["duration_s"]) + float(last["hold_s"]) - seconds
    return spent


def test_the_new_mode_traces_scans_microsaccades_and_blinks_at_their_configured_rates(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Mode saccade+noise+blink, listening, 20 minutes: every kind of event is in the trace, each at the rate
    its constant in configs/gaze.toml sets: microsaccades 1.5 per second of fixation (Martinez-Conde et al.
    2004), scans 0.8 per second of mutual gaze while listening, blinks 26 per minute in conversation
    (Bentivoglio et al. 1997). Each tolerance is about three standard deviations of its count, so a model that
    followed a rate off by a third fails: a microsaccade rate of 1 or 2 per second, the talking scan rate
    (1.2 /s), the blink rate at rest (17 /min), as the asserts on those rates below show."""
    params = GazeParams.load()
    seconds = 1200.0
    rows = _trace(capsys, "--eyes", NEW_MODE, "--role", "listening", "--seconds", "1200", "--seed", "1")
    kinds = [r["kind"] for r in rows]
    assert set(kinds) == {"mutual", "away", "scan", "micro", "blink"}  # no head turns here
    onsets = [float(r["onset_s"]) for r in rows]
    assert onsets == sorted(onsets)
    spent = _fixation_seconds(rows, seconds)
    assert spent["mutual"] + spent["away"] == pytest.approx(seconds, rel=0.01)
    micro_rate = kinds.count("micro") / (spent["mutual"] + spent["away"])
    assert micro_rate == pytest.approx(params.fixation.microsaccade_rate_hz, rel=0.07)
    assert micro_rate != pytest.approx(1.0, rel=0.07) and micro_rate != pytest.approx(2.0, rel=0.07)
    scan_rate = kinds.count("scan") / spent["mutual"]
    assert scan_rate == pytest.approx(params.fixation.scan_rate_hz["listening"], rel=0.12)
    assert scan_rate != pytest.approx(params.fixation.scan_rate_hz["talking"], rel=0.12)
    blinks_per_min = kinds.count("blink") / seconds * 60.0
    assert blinks_per_min == pytest.approx(params.roles["listening"].blink_rate_per_min, rel=0.12)
    assert blinks_per_min != pytest.approx(params.roles["silence"].blink_rate_per_min, rel=0.12)
    # Scans only while the gaze is mutual, each landing on one of the partner's features (the gaze target is
    # at 0, 0); microsaccades are fractions of a degree, at most the configured 1 deg.
    features = {(round(float(y), 4), round(float(p), 4)) for y, p in params.fixation.features_deg}
    assert len(features) == len(FACE_FEATURES)
    current = None
    for r in rows:
        if r["kind"] in EYES_ALIVE:
            current = r["kind"]
        elif r["kind"] == "scan":
            assert current == "mutual"
            assert (float(r["to_yaw_deg"]), float(r["to_pitch_deg"])) in features
    micro = np.array([float(r["amplitude_deg"]) for r in rows if r["kind"] == "micro"])
    assert micro.max() <= params.fixation.microsaccade_max_deg + 1e-4
    assert np.median(micro) == pytest.approx(params.fixation.microsaccade_median_deg, rel=0.15)


@pytest.mark.parametrize(
    ("eyes", "kinds"),
    [
        ("static", set()),
        ("noise", set()),  # Perlin eyes and Perlin's blink pulse: nothing with an onset
        ("saccade", {"mutual", "away"}),
        ("saccade+blink", {"mutual", "away", "blink"}),
    ],
)
def test_the_papers_modes_trace_none_of_the_new_kinds(
    capsys: pytest.CaptureFixture[str], eyes: str, kinds: set[str]
) -> None:
    rows = _trace(capsys, "--eyes", eyes, "--role", "talking", "--seconds", "300", "--seed", "2")
    assert {r["kind"] for r in rows} == kinds


def test_the_new_mode_keeps_the_eyes_alive_decisions(capsys: pytest.CaptureFixture[str]) -> None:
    """The fixational movements ride on the Eyes Alive saccades without shifting their draws: with one seed,
    the paper's mode and the new one make the same decisions (mutual or away) with the same hold times."""
    def decisions(eyes: str) -> list[tuple[str, str]]:
        rows = _trace(capsys, "--eyes", eyes, "--role", "talking", "--seconds", "300", "--seed", "3",
                      "--kinds", "mutual,away")
        return [(r["kind"], r["hold_s"]) for r in rows]

    paper = decisions("saccade")
    assert len(paper) > 50 and paper == decisions(NEW_MODE)


def test_trace_writes_only_the_kinds_asked_for_and_blinks_by_their_lid_curve(
    capsys: pytest.CaptureFixture[str],
) -> None:
    args = ("--eyes", NEW_MODE, "--role", "talking", "--seconds", "120", "--seed", "4")
    every = _trace(capsys, *args)
    chosen = _trace(capsys, *args, "--kinds", "away,blink")
    assert chosen == [r for r in every if r["kind"] in ("away", "blink")]
    assert {r["kind"] for r in chosen} == {"away", "blink"}
    blink_s = GazeParams.load().blink.duration_s
    for r in chosen:
        if r["kind"] == "blink":  # a blink has an onset and a duration (its lid curve's), nothing else
            assert float(r["duration_s"]) == pytest.approx(blink_s)
            assert [k for k, v in r.items() if v] == ["onset_s", "kind", "duration_s"]
    # A gaze-evoked blink starts with the saccade that pulled it, and is written after it.
    onsets = [(float(r["onset_s"]), r["kind"] == "blink") for r in every]
    assert onsets == sorted(onsets)
    assert set(EVENT_KINDS) == {"mutual", "away", "head", "scan", "micro", "blink"}


def test_trace_to_file_and_static_eyes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "trace.csv"
    assert main(["gaze-trace", "--eyes", "static", "--seconds", "30", "-o", str(out)]) == 0
    assert out.read_text().strip() == ",".join(COLUMNS)  # static eyes never move
    assert "wrote 0 saccades and 0 blinks" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--seconds", "-1"], "--seconds must be in"),
        (["--emotion", "bored"], "unknown emotion 'bored'; valid: natural"),
        (["--intensity", "2"], "intensity must be in [0, 1]"),
        (["-o", "/nonexistent-dir/x.csv"], "cannot write /nonexistent-dir/x.csv"),
        (["--kinds", "away,wink"], "--kinds: unknown kind 'wink'; valid: mutual, away, head, scan, micro, blink"),
        (["--kinds", ","], "--kinds names no kind"),
    ],
)
def test_trace_rejects_bad_arguments(capsys: pytest.CaptureFixture[str], args: list[str], message: str) -> None:
    assert main(["gaze-trace", "--seconds", "1", *args]) != 0
    assert message in capsys.readouterr().err


def test_trace_rejects_unknown_mode() -> None:
    with pytest.raises(SystemExit):
        main(["gaze-trace", "--eyes", "blinky"])


def test_plot_writes_both_pictures(tmp_path: Path) -> None:
    from PIL import Image

    assert main(["gaze-plot", "-o", str(tmp_path), "--frames", "300", "--draws", "2000"]) == 0
    for name in ("gaze_trajectory.png", "gaze_statistics.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with Image.open(tmp_path / "gaze_trajectory.png") as image:  # one column per panel and the zoom, two rows
        width, height = image.size
    assert width > 2.55 * len(PANELS) * 100 and height == 1300


def test_the_trajectory_figure_draws_yaw_and_pitch_of_every_mode_with_its_events() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    params = GazeParams.load()
    frames = 900
    traces = simulate_panels(params, frames, seed=0)
    yaw, pitch = traces.yaw, traces.pitch
    assert {mode for _, mode, _ in PANELS} == {"static", "noise", "saccade", "saccade+blink", NEW_MODE}
    noise = [mode for _, mode, _ in PANELS].index("noise")
    assert np.ptp(pitch[:, noise]) > 1.0 and not np.array_equal(pitch, yaw)  # the eyes move up and down too
    fig = trajectory_figure(params, traces)
    try:
        columns = len(PANELS) + 1  # and the zoom into the last panel
        assert len(fig.axes) == 2 * columns
        rows = (fig.axes[:columns], fig.axes[columns:])
        for (angles, word, limit), axes in zip(
            ((yaw, "yaw", params.eye_yaw_limit_deg), (pitch, "pitch", params.eye_pitch_limit_deg)), rows, strict=True
        ):
            for k, ax in enumerate(axes):
                shown = frames if k < len(PANELS) else 600  # the zoom: the first 20 s
                trace = ax.get_lines()[0]
                assert np.array_equal(trace.get_xdata(), angles[:shown, min(k, len(PANELS) - 1)])  # the angle across
                assert np.array_equal(trace.get_ydata(), np.arange(shown))  # ... time (frames) going up
                assert word in ax.get_xlabel() and "deg" in ax.get_xlabel()
                assert ax.get_xlim() == ((-limit, limit) if k < len(PANELS) else (-ZOOM_DEG, ZOOM_DEG))
                # Each kind of event is marked where it happens: scans and microsaccades in the new mode only,
                # the blink model's blinks (lids closed) in every blinking mode.
                marked = {line.get_label() for line in ax.get_lines()[1:]
                          if len(line.get_xdata()) and not line.get_label().startswith("_")}  # not the 0 line
                mode = PANELS[min(k, len(PANELS) - 1)][1]
                if mode == NEW_MODE:
                    assert {"scan", "micro", "mutual", "blink"} <= marked
                else:
                    assert not {"scan", "micro"} & marked
                if mode == "static":
                    assert not marked
                elif mode.startswith("saccade"):
                    assert "mutual" in marked
        labels = [text.get_text() for legend in fig.legends for text in legend.get_texts()]
        assert any("scan" in label for label in labels) and any("blink" in label for label in labels)
    finally:
        plt.close(fig)
