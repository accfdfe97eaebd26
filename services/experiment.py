"""The paper's experiment: one dialogue rendered under each eye condition, side by side.

Rodrigues et al. compared (a) no eye movement, (b) eyes driven by Perlin noise only and (c) saccadic
eyes with Perlin-noise blinks, in the upper-face view; we add (d) our blink model coupled to gaze.
"""

from __future__ import annotations

import html
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


@dataclass(frozen=True)
class Condition:
    key: str  # the eye mode
    label: str


CONDITIONS = (
    Condition("static", "(a) no eye movement"),
    Condition("noise", "(b) Perlin-noise eyes and blinks"),
    Condition("saccade", "(c) saccadic eyes, Perlin-noise blinks"),
    Condition("saccade+blink", "(d) saccadic eyes, blink model coupled to gaze"),
)


def slug(key: str) -> str:
    return key.replace("+", "_")


def plot_trajectory(yaw_deg: np.ndarray, lid: np.ndarray, fps: float, title: str, path: Path) -> None:
    """Horizontal pupil position across, time (frames) going up, as in the paper's Figure 4."""
    frames = np.arange(yaw_deg.size)
    fig, ax = plt.subplots(figsize=(3.2, 6.0), dpi=110)
    ax.plot(yaw_deg, frames, color="#1f4e79", linewidth=0.8)
    closed = lid > 0.5
    if closed.any():
        ax.scatter(yaw_deg[closed], frames[closed], s=2, color="#c0392b", label="lid closed", zorder=3)
        ax.legend(loc="upper right", fontsize=7, frameon=False)
    ax.set_xlim(-30, 30)
    ax.set_ylim(0, max(frames[-1], 1))
    ax.set_xlabel("horizontal eye position (deg, + = agent's right)", fontsize=7)
    ax.set_ylabel(f"time (frames at {fps:g} fps)", fontsize=7)
    ax.set_title(title, fontsize=8)
    ax.tick_params(labelsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def write_index(out_dir: Path, title: str, rows: list[tuple[Condition, str, str]], notes: str) -> None:
    """index.html (videos play side by side) and index.md (for a repository browser)."""
    cells = "\n".join(
        f'<td><h3>{html.escape(c.label)}</h3><video src="{v}" controls muted width="320"></video><br>'
        f'<img src="{p}" width="320" alt="pupil trajectory, {html.escape(c.key)}"></td>' for c, v, p in rows)
    (out_dir / "index.html").write_text(
        f"<!doctype html><meta charset='utf-8'><title>{html.escape(title)}</title>"
        f"<h1>{html.escape(title)}</h1><p>{html.escape(notes)}</p><table><tr>{cells}</tr></table>\n")
    header = "| " + " | ".join(c.label for c, _, _ in rows) + " |\n|" + "---|" * len(rows) + "\n"
    videos = "| " + " | ".join(f"[video]({v})" for _, v, _ in rows) + " |\n"
    plots = "| " + " | ".join(f"![{c.key}]({p})" for c, _, p in rows) + " |\n"
    (out_dir / "index.md").write_text(f"# {title}\n\n{notes}\n\n{header}{videos}{plots}")
