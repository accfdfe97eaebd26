"""The paper's experiment: one dialogue rendered under each eye condition, side by side.

Rodrigues et al. compared (a) no eye movement, (b) eyes driven by Perlin noise only and (c) saccadic
eyes with Perlin-noise blinks, in the upper-face view; we add (d) our blink model coupled to gaze and
(e) what the paper recommends: saccades with context-aware fixational noise and the blink model.

Each condition gives a video, a poster for it (a frame of that video with the eyes open, so the page
shows the face before anything plays) and a trajectory plot; `write_index` lays them out for any number
of conditions, so a new condition is one more entry in CONDITIONS.
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
    key: str  # the eye mode (agent.gaze.params.MODES)
    label: str


CONDITIONS = (
    Condition("static", "(a) no eye movement"),
    Condition("noise", "(b) Perlin-noise eyes and blinks"),
    Condition("saccade", "(c) saccadic eyes, Perlin-noise blinks"),
    Condition("saccade+blink", "(d) saccadic eyes, blink model coupled to gaze"),
    Condition("saccade+noise+blink",
              "(e) saccades, context-aware fixational noise, blink model — the paper's recommendation"),
)


def slug(key: str) -> str:
    return key.replace("+", "_")


@dataclass(frozen=True)
class Panel:
    """One condition's files, named relative to the index page."""

    condition: Condition
    video: str
    poster: str
    plot: str

    @classmethod
    def of(cls, condition: Condition) -> Panel:
        name = slug(condition.key)
        return cls(condition, f"{name}.mp4", f"{name}_poster.png", f"{name}_trajectory.png")


# The plot is drawn small in inches so that, shrunk to a fifth of a laptop screen, its 8-point text is
# still about 9 px high; the resolution keeps it sharp when a wide screen shows it larger.
PLOT_INCHES = (2.4, 3.6)
PLOT_DPI = 160
PLOT_SIZE_PX = (round(PLOT_INCHES[0] * PLOT_DPI), round(PLOT_INCHES[1] * PLOT_DPI))


def plot_trajectory(yaw_deg: np.ndarray, lid: np.ndarray, fps: float, title: str, path: Path) -> None:
    """Horizontal pupil position across, time (frames) going up, as in the paper's Figure 4."""
    frames = np.arange(yaw_deg.size)
    fig, ax = plt.subplots(figsize=PLOT_INCHES, dpi=PLOT_DPI)
    ax.plot(yaw_deg, frames, color="#1f4e79", linewidth=0.8)
    closed = lid > 0.5
    if closed.any():
        ax.scatter(yaw_deg[closed], frames[closed], s=2, color="#c0392b", label="lid closed", zorder=3)
        ax.legend(loc="upper right", fontsize=7, frameon=False)
    ax.set_xlim(-30, 30)
    ax.set_ylim(0, max(frames[-1], 1))
    ax.set_xlabel("horizontal eye position (deg)\n+ = the agent's right", fontsize=8)
    ax.set_ylabel(f"time (frames at {fps:g} fps)", fontsize=8)
    ax.set_title(title, fontsize=8)
    ax.tick_params(labelsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


# A poster from about a second in: past the first frame, whose face has not settled into its first
# gaze, and before most dialogues change anything. A lid below 0.1 reads as an open eye.
POSTER_AFTER_S = 1.0
OPEN_LID = 0.1


def poster_frame(t_s: np.ndarray, lid: np.ndarray, after_s: float = POSTER_AFTER_S,
                 open_below: float = OPEN_LID) -> int:
    """The frame a video's poster shows: the first from `after_s` on whose lids are open; failing that
    (a render shorter than `after_s`, or lids closed from then to the end), the open frame nearest before
    it; failing that, the frame with the lids most open. The same render always gives the same frame."""
    if t_s.size == 0 or t_s.shape != lid.shape:
        raise ValueError(f"a poster needs one lid value per frame, got {t_s.shape} and {lid.shape}")
    is_open = lid < open_below
    later = np.flatnonzero(is_open & (t_s >= after_s))
    if later.size:
        return int(later[0])
    earlier = np.flatnonzero(is_open & (t_s < after_s))
    if earlier.size:
        return int(earlier[-1])
    return int(np.argmin(lid))


def write_poster(video: Path, t_s: float, path: Path) -> None:
    """Save the video's frame shown at `t_s` (the decoded one, so the poster matches what plays) as PNG."""
    import av

    chosen = None
    with av.open(str(video)) as container:
        for frame in container.decode(video=0):
            if chosen is not None and abs(frame.time - t_s) >= abs(chosen.time - t_s):
                break  # frames come in display order: the distance only grows from here
            chosen = frame
    if chosen is None:
        raise ValueError(f"{video}: no video frame to make a poster from")
    chosen.to_image().save(path)


PAGE_STYLE = """
body { font: 16px/1.4 system-ui, sans-serif; color: #222; margin: 0 auto; padding: 1rem 1.5rem;
       max-width: 100rem; }
h1 { font-size: 1.4rem; margin: 0 0 .4rem; }
.notes { max-width: 60rem; margin: 0 0 1rem; }
/* As many columns as fit at 13rem or more (five on a 1280-px laptop, so the conditions play side by
   side), fewer rows on a narrower screen; min() keeps one column from overflowing a phone. */
.conditions { display: grid; gap: 1.5rem 1rem;
              grid-template-columns: repeat(auto-fit, minmax(min(13rem, 100%), 1fr)); }
/* A subgrid shares the heading, video and plot rows across a row of conditions, so videos line up
   however many lines each label wraps to. */
.condition { display: grid; grid-row: span 3; grid-template-rows: subgrid; row-gap: .4rem; margin: 0;
             min-width: 0; }
.condition h2 { font-size: .95rem; font-weight: 600; margin: 0; align-self: end; }
.condition video, .condition img { display: block; width: 100%; height: auto; }
.condition video { background: #ddd; }
"""

# Native controls, when shown, cover the lower third of a still, where the upper view has the eyes: they
# appear only while a pointer or the keyboard is on a video, or it plays. Without scripts they stay.
PAGE_SCRIPT = """
for (const video of document.querySelectorAll("video")) {
  const hide = () => { if (video.paused && !video.matches(":hover, :focus")) video.controls = false; };
  const show = () => { video.controls = true; };
  video.addEventListener("pointerenter", show);
  video.addEventListener("focus", show);
  video.addEventListener("play", show);
  video.addEventListener("pointerleave", hide);
  video.addEventListener("blur", hide);
  video.addEventListener("pause", hide);
  hide();
}
"""


def write_index(out_dir: Path, title: str, panels: list[Panel], notes: str,
                video_size: tuple[int, int]) -> None:
    """index.html (a grid of the conditions, videos with posters, plots below) and index.md (for a
    repository browser: each poster links to its video)."""
    vw, vh = video_size
    pw, ph = PLOT_SIZE_PX
    e = html.escape  # for attributes; text needs only <, > and & escaped

    def text(value: str) -> str:
        return html.escape(value, quote=False)

    # width and height give the browser each picture's shape before it loads, so the page does not jump.
    sections = "\n".join(
        f'<section class="condition"><h2>{text(p.condition.label)}</h2>\n'
        f'<video src="{e(p.video)}" poster="{e(p.poster)}" width="{vw}" height="{vh}" controls muted '
        f'preload="metadata" playsinline tabindex="0"></video>\n'
        f'<img src="{e(p.plot)}" width="{pw}" height="{ph}" '
        f'alt="{e(f"horizontal pupil position over time, {p.condition.label}")}"></section>'
        for p in panels)
    (out_dir / "index.html").write_text(
        f'<!doctype html>\n<html lang="en">\n<meta charset="utf-8">\n'
        f'<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        f"<title>{text(title)}</title>\n<style>{PAGE_STYLE}</style>\n"
        f'<h1>{text(title)}</h1>\n<p class="notes">{text(notes)} Point at a video for its controls.</p>\n'
        f'<div class="conditions">\n{sections}\n</div>\n<script>{PAGE_SCRIPT}</script>\n</html>\n', encoding="utf-8")

    def cell(value: str) -> str:  # a pipe would end a Markdown table cell early
        return value.replace("|", "\\|")

    header = "| " + " | ".join(cell(p.condition.label) for p in panels) + " |\n|" + "---|" * len(panels) + "\n"
    videos = "| " + " | ".join(f"[![{cell(p.condition.key)}, open the video]({p.poster})]({p.video})"
                               for p in panels) + " |\n"
    plots = "| " + " | ".join(f"![{cell(p.condition.key)}]({p.plot})" for p in panels) + " |\n"
    (out_dir / "index.md").write_text(f"# {title}\n\n{notes}\n\n{header}{videos}{plots}", encoding="utf-8")
