"""Where headless frames go: an H.264 MP4 (PyAV, which bundles FFmpeg with libx264) and/or PNG files.

Frames are numbered by their slot at the fixed frame rate: frame k is shown at k / fps seconds. A frame
slot the renderer could not fill in time is skipped, and the video's timestamps say so (the previous
image stays on screen for longer), so the video keeps real time.
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path
from typing import Protocol

import numpy as np


class FrameSink(Protocol):
    def write(self, rgb: np.ndarray, index: int) -> None:
        """One (H, W, 3) uint8 image, top row first, for frame slot `index`."""

    def close(self) -> None: ...


class VideoWriter:
    """H.264 in MP4 at a fixed frame rate (yuv420p, so width and height must be even)."""

    def __init__(
        self, path: str | Path, fps: float, size: tuple[int, int], crf: int = 23, preset: str = "veryfast"
    ) -> None:
        import av  # imported here: only headless video needs FFmpeg

        width, height = size
        if width % 2 or height % 2:
            raise ValueError(f"H.264 video needs an even width and height, got {width}x{height}")
        if not 1 <= fps <= 240:
            raise ValueError(f"video frame rate must lie in [1, 240], got {fps}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.size = (int(width), int(height))
        rate = Fraction(fps).limit_denominator(1001)
        self._container = av.open(str(self.path), mode="w")
        self._stream = self._container.add_stream("libx264", rate=rate)
        self._stream.width, self._stream.height = self.size
        self._stream.pix_fmt = "yuv420p"
        self._stream.time_base = 1 / rate
        self._stream.options = {"crf": str(int(crf)), "preset": preset}
        self._last_index = -1
        self.frames = 0
        self._av = av

    def write(self, rgb: np.ndarray, index: int) -> None:
        if rgb.shape != (self.size[1], self.size[0], 3):
            raise ValueError(f"expected a {self.size[0]}x{self.size[1]} RGB image, got shape {rgb.shape}")
        if index <= self._last_index:
            raise ValueError(f"frame slots must increase: {index} after {self._last_index}")
        frame = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
        frame.pts = int(index)
        for packet in self._stream.encode(frame):
            self._container.mux(packet)
        self._last_index = index
        self.frames += 1

    def close(self) -> None:
        if self._container is None:
            return
        for packet in self._stream.encode(None):
            self._container.mux(packet)
        self._container.close()
        self._container = None  # type: ignore[assignment]


class PngWriter:
    """One PNG per frame, named by its slot: frame_000000.png, frame_000001.png, ..."""

    def __init__(self, directory: str | Path, every: int = 1) -> None:
        from PIL import Image

        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.every = max(1, int(every))
        self.frames = 0
        self._image = Image

    def write(self, rgb: np.ndarray, index: int) -> None:
        if index % self.every:
            return
        self._image.fromarray(np.ascontiguousarray(rgb)).save(self.directory / f"frame_{index:06d}.png")
        self.frames += 1

    def close(self) -> None:
        pass


def read_video_frames(path: str | Path) -> list[np.ndarray]:
    """Every frame of a video as (H, W, 3) uint8 RGB (for tests and checks)."""
    import av

    with av.open(str(path)) as container:
        return [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
