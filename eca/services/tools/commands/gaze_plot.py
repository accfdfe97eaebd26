"""`eca gaze-plot`: pictures of the gaze model, like the paper's Figure 4, and its statistics."""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from eca.agent.config import ConfigError
from eca.agent.gaze.engine import GazeEngine
from eca.agent.gaze.generator import direction_from_uniform, magnitude_from_uniform, min_uniform_p, saccade_duration_s
from eca.agent.gaze.params import FACE_FEATURES, KINDS, GazeParams

if TYPE_CHECKING:  # matplotlib is imported when drawing, after the backend is chosen
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

NS_PER_S = 1_000_000_000
FPS = 30
# (title, eye mode, role) for each column of the trajectory figure: the paper's conditions (a)-(c), the
# blink model (d), and the paper's recommendation (e), eca's default.
PANELS = (
    ("(a) static", "static", "talking"),
    ("(b) Perlin noise", "noise", "talking"),
    ("(c) saccades", "saccade", "talking"),
    ("(c) saccades", "saccade", "listening"),
    ("(d) saccades + blinks", "saccade+blink", "talking"),
    ("(e) saccades + noise + blinks", "saccade+noise+blink", "talking"),
    ("(e) saccades + noise + blinks", "saccade+noise+blink", "listening"),
)
# How each kind of saccade (KINDS) is marked where it lands: (legend label, marker, size, colour).
MARKERS: dict[str, tuple[str, str, float, str]] = {
    "away": ("away saccade (Eyes Alive)", "^", 4.5, "#e07b00"),
    "mutual": ("return to mutual gaze", "o", 3.5, "#2a9d8f"),
    "head": ("head-led saccade", "s", 3.5, "#6d597a"),
    "scan": ("scan: partner's eye or mouth", "D", 2.2, "#d62d7a"),
    "micro": ("microsaccade", "o", 1.8, "#1b1b1b"),
}
BLINK_COLOUR = "#c0504d"


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "gaze-plot",
        help="draw the pupil trajectory per eye mode and the saccade statistics as PNG",
        description="Write gaze_trajectory.png (pupil position across, time going up, like the paper's "
        "Figure 4, one column per eye mode and role: horizontal position (yaw) on top, vertical (pitch) "
        "below, each saccade marked by its kind where it lands, blinks as ticks) and gaze_statistics.png "
        "(histograms of magnitude, direction, duration and interval over the model's analytic curves).",
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


@dataclass(frozen=True)
class Saccades:
    """One panel's saccades: onset (in frames, fractional), kind (KINDS index) and landing (degrees)."""

    frame: np.ndarray
    kind: np.ndarray
    to_yaw: np.ndarray
    to_pitch: np.ndarray


@dataclass(frozen=True)
class Traces:
    """Per frame (30 fps) and panel: yaw, pitch (degrees) and lid (0 open .. 1 closed), shape (frames,
    panels); per panel its saccades and the onsets of the blink model's blinks (in frames)."""

    yaw: np.ndarray
    pitch: np.ndarray
    lid: np.ndarray
    saccades: list[Saccades]
    blinks: list[np.ndarray]


def simulate_panels(params: GazeParams, frames: int, seed: int) -> Traces:
    """Run one agent per panel for `frames` frames at 30 fps."""
    engine = GazeEngine(len(PANELS), seed=seed, params=params)
    for agent, (_, mode, role) in enumerate(PANELS):
        engine.set_mode(agent, mode, 0)
        engine.set_role(agent, role, 0)
    yaw = np.empty((frames, len(PANELS)))
    pitch = np.empty((frames, len(PANELS)))
    lid = np.empty((frames, len(PANELS)))
    onsets: list[tuple[np.ndarray, ...]] = []
    blinks: list[tuple[np.ndarray, np.ndarray]] = []
    for frame in range(frames):
        tick = engine.tick(frame * NS_PER_S // FPS)
        yaw[frame], pitch[frame], lid[frame] = tick.yaw_deg, tick.pitch_deg, tick.lid
        s = tick.saccades
        onsets.append((s.agent, s.onset_ns, s.kind, s.to_yaw_deg, s.to_pitch_deg))
        blinks.append((tick.blinks.agent, tick.blinks.onset_ns))
    agent, onset, kind, to_yaw, to_pitch = (np.concatenate(column) for column in zip(*onsets, strict=True))
    blink_agent, blink_onset = (np.concatenate(column) for column in zip(*blinks, strict=True))
    per_frame = FPS / NS_PER_S
    saccades = [
        Saccades(onset[mine] * per_frame, kind[mine], to_yaw[mine], to_pitch[mine])
        for mine in (agent == k for k in range(len(PANELS)))
    ]
    return Traces(yaw, pitch, lid, saccades, [blink_onset[blink_agent == k] * per_frame for k in range(len(PANELS))])


# (row title, axis label, limit attribute of GazeParams, trace colour) for the two rows of panels
AXES = (
    ("horizontal", "yaw (deg, + = agent's right)", "eye_yaw_limit_deg", "#1f4e79"),
    ("vertical", "pitch (deg, + = up)", "eye_pitch_limit_deg", "#7b3f99"),
)


# The last column zooms into the last panel (the paper's recommendation while listening): its first seconds,
# a few degrees around the partner's face, where the scans and microsaccades show.
ZOOM_SECONDS = 20
ZOOM_DEG = 6.0


def trajectory_figure(params: GazeParams, traces: Traces) -> Figure:
    """One column per panel and a zoom into the last: horizontal position in the top row, vertical in the
    bottom one, both across with time going up (the paper's Figure 4 shows the horizontal one). Each saccade
    is marked by its kind where it lands; red ticks at the right edge mark the frames with the lids mostly
    closed."""
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    frames = traces.yaw.shape[0]
    zoom_frames = min(frames, ZOOM_SECONDS * FPS)
    columns = len(PANELS) + 1
    fig, axes = plt.subplots(2, columns, figsize=(2.55 * columns, 13.0),
                             gridspec_kw={"width_ratios": [1.0] * len(PANELS) + [1.3]})
    for row, ((name, label, limit_name, colour), angles) in enumerate(
        zip(AXES, (traces.yaw, traces.pitch), strict=True)
    ):
        limit = float(getattr(params, limit_name))
        zoom = axes[row, -1]
        for k, (ax, (title, mode, role)) in enumerate(zip(axes[row, :-1], PANELS, strict=True)):
            _draw_panel(ax, traces, k, row, angles[:, k], colour, limit, frames)
            ax.set_title(f"{title}\n{mode}, {role}\n{name}", fontsize=9.5)
            ax.set_xlim(-limit, limit)
            ax.set_xticks([-20, -10, 0, 10, 20])
            ax.set_xlabel(label, fontsize=8.5)
            ax.set_ylim(0, frames)
            if k:
                ax.tick_params(labelleft=False)
        _draw_panel(zoom, traces, len(PANELS) - 1, row, angles[:zoom_frames, -1], colour, ZOOM_DEG, zoom_frames)
        # Where the partner's features are: the eyes side by side (yaw), the mouth below them (pitch).
        features = dict(zip(FACE_FEATURES, params.fixation.features_deg[:, row], strict=True))
        shown = {"right eye": features["right eye"], "left eye": features["left eye"]} if row == 0 else {
            "eyes": features["right eye"], "mouth": features["mouth"]}
        for feature, at in shown.items():
            zoom.axvline(at, color="#d62d7a", linewidth=0.7, linestyle=":", zorder=0)
            zoom.text(at, zoom_frames * 0.995, feature, fontsize=8, color="#d62d7a", ha="center", va="top",
                      rotation=90, bbox={"facecolor": "white", "edgecolor": "none", "pad": 1.0})
        zoom.set_title(f"zoom into the last column: first\n{zoom_frames / FPS:.0f} s, ±{ZOOM_DEG:.0f}° around the "
                       f"partner's face\n{name}", fontsize=9.5)
        zoom.set_xlim(-ZOOM_DEG, ZOOM_DEG)
        zoom.set_ylim(0, zoom_frames)
        zoom.set_xlabel(label, fontsize=8.5)
        axes[row, 0].set_ylabel(f"frame at {FPS} fps, time going up ({frames} frames = {frames / FPS:.0f} s)")
    kinds = {KINDS[code] for saccades in traces.saccades for code in np.unique(saccades.kind)}
    handles = [Line2D([], [], color=AXES[0][3], linewidth=1.0, label="pupil position")]
    handles += [Line2D([], [], marker=marker, markersize=max(size * 1.6, 5), color=colour, linestyle="none",
                       label=text) for kind, (text, marker, size, colour) in MARKERS.items() if kind in kinds]
    handles.append(Line2D([], [], marker="_", markersize=8, markeredgewidth=1.5, color=BLINK_COLOUR,
                          linestyle="none", label="blink (lids mostly closed)"))
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=10, frameon=False)
    fig.suptitle("Pupil trajectory per eye mode, like the paper's Figure 4: horizontal (top) and vertical "
                 "(bottom) position; each saccade marked where it lands", fontsize=13)
    fig.tight_layout(rect=(0.0, 0.03, 1.0, 1.0))
    return fig


def _draw_panel(ax: Axes, traces: Traces, k: int, row: int, angles: np.ndarray, colour: str, limit: float,
                frames: int) -> None:
    """Panel k's trace of one angle (row 0 yaw, 1 pitch) over its first `frames` frames, its saccades marked
    by kind where they land and its closed lids as ticks at the right edge."""
    frame_index = np.arange(frames)
    ax.plot(angles, frame_index, color=colour, linewidth=0.7)
    saccades = traces.saccades[k]
    shown = saccades.frame < frames
    landing = (saccades.to_yaw if row == 0 else saccades.to_pitch)[shown]
    for code, kind in enumerate(KINDS):
        mine = saccades.kind[shown] == code
        if np.any(mine):
            _, marker, size, marker_colour = MARKERS[kind]
            ax.plot(landing[mine], saccades.frame[shown][mine], marker, markersize=size, color=marker_colour,
                    markeredgewidth=0.0, linestyle="none", label=kind)
    closed = frame_index[traces.lid[:frames, k] > 0.5]
    ax.plot(np.full(closed.size, limit * 0.93), closed, "_", color=BLINK_COLOUR, markersize=5, markeredgewidth=1.2,
            linestyle="none", label="blink")
    ax.tick_params(labelsize=8)
    ax.axvline(0.0, color="0.85", linewidth=0.6, zorder=0)


def plot_trajectories(params: GazeParams, frames: int, seed: int, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig = trajectory_figure(params, simulate_panels(params, frames, seed))
    fig.savefig(path, dpi=100)
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
