"""`eca gaze-plot`: pictures of the gaze model, like the paper's Figure 4, and its statistics."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from agent.config import ConfigError
from agent.gaze.engine import GazeEngine
from agent.gaze.generator import direction_from_uniform, magnitude_from_uniform, min_uniform_p, saccade_duration_s
from agent.gaze.params import GazeParams

if TYPE_CHECKING:  # matplotlib is imported when drawing, after the backend is chosen
    from matplotlib.figure import Figure

NS_PER_S = 1_000_000_000
# (title, eye mode, role) for each panel of the trajectory figure.
PANELS = (
    ("(a) static", "static", "talking"),
    ("(b) Perlin noise", "noise", "talking"),
    ("(c) saccades, talking", "saccade", "talking"),
    ("(c) saccades, listening", "saccade", "listening"),
    ("(d) saccades + blinks, talking", "saccade+blink", "talking"),
)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "gaze-plot",
        help="draw the pupil trajectory per eye mode and the saccade statistics as PNG",
        description="Write gaze_trajectory.png (pupil position across, time going up, like the paper's "
        "Figure 4, one column per eye mode and role: horizontal position (yaw) on top, vertical (pitch) "
        "below) and gaze_statistics.png (histograms of magnitude, "
        "direction, duration and interval over the model's analytic curves).",
    )
    parser.add_argument("-o", "--output", default="docs/img", help="folder for the PNGs (default: docs/img)")
    parser.add_argument("--frames", type=int, default=5000, help="frames at 30 fps in the trajectory figure")
    parser.add_argument("--draws", type=int, default=200_000, help="draws per histogram (default: 200000)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.frames < 10 or args.draws < 100:
        print("eca gaze-plot: need --frames >= 10 and --draws >= 100", file=sys.stderr)
        return 2
    try:
        params = GazeParams.load()
    except ConfigError as exc:
        print(f"eca gaze-plot: {exc}", file=sys.stderr)
        return 2
    out = Path(args.output)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(f"eca gaze-plot: cannot create {out}: {exc.strerror}", file=sys.stderr)
        return 1
    import matplotlib

    matplotlib.use("Agg")
    trajectory = out / "gaze_trajectory.png"
    statistics = out / "gaze_statistics.png"
    plot_trajectories(params, args.frames, args.seed, trajectory)
    plot_statistics(params, args.draws, args.seed, statistics)
    print(f"wrote {trajectory} and {statistics}", file=sys.stderr)
    return 0


def simulate_panels(params: GazeParams, frames: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Yaw, pitch (degrees) and lid (0 open .. 1 closed) per frame (30 fps), one agent per panel."""
    engine = GazeEngine(len(PANELS), seed=seed, params=params)
    for agent, (_, mode, role) in enumerate(PANELS):
        engine.set_mode(agent, mode, 0)
        engine.set_role(agent, role, 0)
    yaw = np.empty((frames, len(PANELS)))
    pitch = np.empty((frames, len(PANELS)))
    lid = np.empty((frames, len(PANELS)))
    for frame in range(frames):
        tick = engine.tick(frame * NS_PER_S // 30)
        yaw[frame], pitch[frame], lid[frame] = tick.yaw_deg, tick.pitch_deg, tick.lid
    return yaw, pitch, lid


# (row title, axis label, limit attribute of GazeParams, trace colour) for the two rows of panels
AXES = (
    ("horizontal", "yaw (deg, + = agent's right)", "eye_yaw_limit_deg", "#1f4e79"),
    ("vertical", "pitch (deg, + = up)", "eye_pitch_limit_deg", "#7b3f99"),
)


def trajectory_figure(params: GazeParams, yaw: np.ndarray, pitch: np.ndarray, lid: np.ndarray) -> Figure:
    """One column per panel: horizontal position in the top row, vertical in the bottom one, both
    across with time going up (the paper's Figure 4 shows the horizontal one)."""
    import matplotlib.pyplot as plt

    frames = yaw.shape[0]
    frame_index = np.arange(frames)
    fig, axes = plt.subplots(2, len(PANELS), figsize=(3.0 * len(PANELS), 12.0), sharey=True)
    for row, ((name, label, limit_name, colour), angles) in enumerate(zip(AXES, (yaw, pitch), strict=True)):
        limit = float(getattr(params, limit_name))
        for k, (ax, (title, _, _)) in enumerate(zip(axes[row], PANELS, strict=True)):
            ax.plot(angles[:, k], frame_index, color=colour, linewidth=0.7, label=name)
            closed = lid[:, k] > 0.5
            ax.plot(np.full(closed.sum(), limit * 0.93), frame_index[closed], "|", color="#c0504d", markersize=3)
            ax.set_title(f"{title}\n{name}", fontsize=10)
            ax.set_xlim(-limit, limit)
            ax.set_xticks([-20, -10, 0, 10, 20])
            ax.set_xlabel(label, fontsize=9)
            ax.axvline(0.0, color="0.8", linewidth=0.6, zorder=0)
        axes[row, 0].set_ylabel(f"frame (30 fps), time going up; {frames} frames")
    axes[0, 0].set_ylim(0, frames)
    fig.suptitle("Pupil trajectory per eye mode: horizontal (top) and vertical (bottom) position "
                 "(red ticks: lids closed)", fontsize=12)
    fig.tight_layout()
    return fig


def plot_trajectories(params: GazeParams, frames: int, seed: int, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig = trajectory_figure(params, *simulate_panels(params, frames, seed))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_statistics(params: GazeParams, draws: int, seed: int, path: Path) -> None:
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(seed)
    fig, axes = plt.subplots(2, 4, figsize=(16, 7.5))
    for ax, role in zip(axes[0, :2], ("talking", "listening"), strict=True):
        limit = params.roles[role].max_magnitude_deg
        magnitude = magnitude_from_uniform(rng.random(draws), params, limit)
        ax.hist(magnitude, bins=80, density=True, color="#9dc3e6", label=f"{draws:,} draws")
        a = np.linspace(magnitude.min(), limit, 400)
        ax.plot(a, _magnitude_pdf(a, params, limit), color="#c0504d", label="eq. 1, truncated")
        ax.set_title(f"magnitude, {role} (max {limit} deg)")
        ax.set_xlabel("deg")
        ax.legend()

    ax = axes[0, 2]
    directions = direction_from_uniform(rng.random(draws), params)
    observed = [100.0 * np.mean(directions == b) for b in params.direction_bins_deg]
    ax.bar(params.direction_bins_deg, observed, width=30, color="#9dc3e6", label="drawn")
    ax.plot(params.direction_bins_deg, 100.0 * params.direction_probability, "o", color="#c0504d", label="table")
    ax.set_xticks(params.direction_bins_deg)
    ax.set_title("direction (0 right, 90 up)")
    ax.set_ylabel("%")
    ax.legend()

    ax = axes[0, 3]
    limit = params.roles["talking"].max_magnitude_deg
    duration_ms = 1000.0 * saccade_duration_s(magnitude_from_uniform(rng.random(draws), params, limit), params)
    ax.hist(duration_ms, bins=80, density=True, color="#9dc3e6", label="drawn")
    d = np.linspace(duration_ms.min(), duration_ms.max(), 400)
    slope_ms = 1000.0 * params.d_s_per_deg
    amplitude = (d - 1000.0 * params.d0_s) / slope_ms
    ax.plot(d, _magnitude_pdf(amplitude, params, limit) / slope_ms, color="#c0504d", label="eq. 2 of eq. 1")
    ax.set_title("duration, talking")
    ax.set_xlabel("ms")
    ax.legend()

    for ax, (role, kind) in zip(
        axes[1],
        (("talking", "mutual"), ("talking", "away"), ("listening", "mutual"), ("listening", "away")),
        strict=True,
    ):
        distribution = getattr(params.roles[role], f"{kind}_interval")
        holds = distribution.sample_s(rng.random(draws))
        ax.hist(holds, bins=80, density=True, color="#9dc3e6", label="drawn")
        x = np.linspace(0.0, holds.max(), 400)
        source = {"talking": "eq. 4" if kind == "mutual" else "eq. 5", "listening": "Gaussian"}[role]
        ax.plot(x, distribution.pdf_s(x), color="#c0504d", label=source)
        ax.set_title(f"interval, {role}, {kind} gaze")
        ax.set_xlabel("s")
        ax.legend()
    fig.suptitle("Eyes Alive parameter generator: draws over the analytic curves", fontsize=12)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _magnitude_pdf(a_deg: np.ndarray, params: GazeParams, limit: float) -> np.ndarray:
    # A = -a ln(P / p_ref) with P uniform on [P_min, p_max]: density (p_ref / a) exp(-A / a) / (p_max - P_min).
    p_min = float(min_uniform_p(params, limit))
    lowest = -params.a_scale_deg * np.log(params.p_max / params.p_ref)
    density = params.p_ref / params.a_scale_deg * np.exp(-a_deg / params.a_scale_deg) / (params.p_max - p_min)
    return np.where((a_deg >= lowest) & (a_deg <= limit), density, 0.0)
