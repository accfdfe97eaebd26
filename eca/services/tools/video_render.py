"""The offline renders' video: the faces of each frame drawn side by side, one panel per agent, into an MP4
with the mixed voices, and a CSV of the frames. A single agent's render is the one-panel case."""

from __future__ import annotations

import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TypeVar

import numpy as np

from eca.agent.face.composed import ComposedFace

R = TypeVar("R")
FrameSink = Callable[[int, Sequence[ComposedFace]], None]  # frame index, each panel's composed face


def panel_widths(width: int, n_panels: int) -> list[int]:
    """The picture's width split among the panels, left to right (the first ones one pixel wider where it
    does not divide)."""
    base, extra = divmod(width, n_panels)
    if base < 16:
        raise ValueError(f"--size: {width} pixels are too narrow for {n_panels} faces side by side "
                         f"(at least {16 * n_panels})")
    return [base + (1 if k < extra else 0) for k in range(n_panels)]


def render_panels(animate: Callable[[FrameSink], R], audio_of: Callable[[R], np.ndarray], n_panels: int,
                  size: tuple[int, int], fps: float, length_s: float, view: str, output: Path,
                  csv_path: Path | None, write_csv: Callable[[Path, R], None], label: str = "render",
                  face: str = "flexor") -> R:
    """Run `animate` with a sink that draws every frame's panels; mux the result's audio into `output` and
    write its CSV. Output folders are made first, so a bad place fails before any drawing."""
    from tqdm import tqdm

    from eca.services.processes.renderer import Drawers, create_headless_context, create_offscreen_target, read_rgb
    from eca.services.processes.renderer.video import VideoWriter
    from eca.services.tools.offline import mux_audio

    widths = panel_widths(size[0], n_panels)
    height = size[1]
    for folder in {output.parent, *([csv_path.parent] if csv_path is not None else [])}:
        folder.mkdir(parents=True, exist_ok=True)
    ctx = create_headless_context()
    drawer = Drawers(ctx, (widths[0], height))(face)
    targets = {w: create_offscreen_target(ctx, (w, height)) for w in set(widths)}
    with tempfile.TemporaryDirectory(prefix="eca-render-") as tmp:
        silent = Path(tmp) / "video.mp4"
        writer = VideoWriter(silent, fps, size)
        bar = tqdm(desc=label, unit="frame", total=int(length_s * fps) + 1, disable=not sys.stderr.isatty(),
                   leave=False)

        def draw(k: int, panels: Sequence[ComposedFace]) -> None:
            pictures = []
            for face, width in zip(panels, widths, strict=True):
                drawer.draw(face, targets[width], view=view)
                pictures.append(read_rgb(targets[width]))
            writer.write(pictures[0] if len(pictures) == 1 else np.hstack(pictures), k)
            bar.update(1)

        result = animate(draw)
        writer.close()
        bar.close()
        mux_audio(silent, audio_of(result), output)
    if csv_path is not None:
        write_csv(csv_path, result)
    ctx.release()
    return result
