"""A real headless Chromium for the web front-end's tests and benchmark (Debian's `chromium` and
`chromium-driver`, driven by selenium), with fake media devices: a WAV file as the microphone.

The flags keep a browser on a machine with no network beyond loopback quiet (no background fetches that
would fail), grant the microphone without asking, and let the page play sound without a user gesture.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"


# The flags that give headless Chromium WebGL without a GPU: ANGLE on SwiftShader's Vulkan, or ANGLE on the
# system's EGL (Mesa's llvmpipe on a machine without a GPU; the page's renderer string says which it got).
SOFTWARE_GL: dict[str, tuple[str, ...]] = {
    "swiftshader": ("--enable-unsafe-swiftshader", "--use-angle=swiftshader", "--ignore-gpu-blocklist"),
    "egl": ("--use-gl=angle", "--use-angle=gl-egl", "--ignore-gpu-blocklist"),
}


class BrowserMissing(RuntimeError):
    """Chromium or its driver is not installed (`.ci/setup` installs Debian's)."""


def browser_available() -> str | None:
    """Why no browser can run here, or None when one can."""
    for path in (CHROMIUM, CHROMEDRIVER):
        if not Path(path).exists():
            return f"{path} is missing: install Debian's chromium and chromium-driver"
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed"
    return None


@contextmanager
def chromium(microphone_wav: Path | None = None, window: tuple[int, int] = (1280, 800),
             webgl: bool = True, gl: str = "swiftshader") -> Iterator[Any]:
    """A selenium driver of a fresh headless Chromium (its own empty profile), quit afterwards. With `webgl`, WebGL
    in software: `gl` "swiftshader" (Chromium's own; it offers it only when asked) or "egl" (the system's EGL through
    ANGLE: Mesa's llvmpipe on a machine without a GPU, several times faster than SwiftShader at drawing the head, for
    figures that need the page to draw near its display's rate; a GPU's driver where there is one); without
    `webgl`, a browser with no WebGL."""
    if gl not in SOFTWARE_GL:
        raise ValueError(f"gl must be one of {', '.join(SOFTWARE_GL)}, not {gl!r}")
    problem = browser_available()
    if problem:
        raise BrowserMissing(problem)
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    profile = Path(tempfile.mkdtemp(prefix="eca-chromium-"))
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    # the GPU process stays for "egl": it is where ANGLE runs the system's EGL (SwiftShader runs without one)
    gpu = () if webgl and gl == "egl" else ("--disable-gpu",)
    for flag in ("--headless=new", "--no-sandbox", *gpu, "--disable-dev-shm-usage", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--disable-quic", "--use-fake-ui-for-media-stream", "--use-fake-device-for-media-stream",
                 "--autoplay-policy=no-user-gesture-required", f"--window-size={window[0]},{window[1]}",
                 f"--user-data-dir={profile}"):
        options.add_argument(flag)
    if webgl:
        for flag in SOFTWARE_GL[gl]:
            options.add_argument(flag)
    else:
        options.add_argument("--disable-webgl")
    if microphone_wav is not None:
        options.add_argument(f"--use-file-for-fake-audio-capture={microphone_wav}%noloop")
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    try:
        yield driver
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)


WEBGL_RENDERER_JS = """
const gl = document.createElement("canvas").getContext("webgl2");
const info = gl && gl.getExtension("WEBGL_debug_renderer_info");
return gl ? gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER) : null;
"""


def webgl_renderer(driver: Any) -> str | None:
    """The renderer a page's WebGL 2 draws with (e.g. "ANGLE (Mesa/X.org, llvmpipe ...)"), None without WebGL 2."""
    renderer = driver.execute_script(WEBGL_RENDERER_JS)
    return None if renderer is None else str(renderer)


def wait_for(driver: Any, script: str, timeout_s: float, what: str,
             check: Callable[[Any], bool] = bool) -> Any:
    """Poll a JavaScript expression (`return ...`) until `check` holds for its value; its value."""
    deadline = time.monotonic() + timeout_s
    value = None
    while time.monotonic() < deadline:
        value = driver.execute_script(script)
        if check(value):
            return value
        time.sleep(0.1)  # polling a page from outside: no event to wait on
    raise TimeoutError(f"{what}: not within {timeout_s} s (last value {value!r})")


PAGE_STATS = """
const done = arguments[arguments.length - 1];
if (!window.eca || !window.eca.pc) { done(null); return; }
window.eca.pc.getStats().then((report) => {
  const out = {video: [], audio: []};
  report.forEach((s) => {
    if (s.type === "inbound-rtp") out[s.kind].push({
      mid: s.mid, framesDecoded: s.framesDecoded, frameWidth: s.frameWidth, frameHeight: s.frameHeight,
      framesPerSecond: s.framesPerSecond, totalAudioEnergy: s.totalAudioEnergy, audioLevel: s.audioLevel,
      totalSamplesDuration: s.totalSamplesDuration, packetsReceived: s.packetsReceived,
      estimatedPlayoutTimestamp: s.estimatedPlayoutTimestamp, jitterBufferDelay: s.jitterBufferDelay,
      jitterBufferEmittedCount: s.jitterBufferEmittedCount});
  });
  done(out);
});
"""


def page_stats(driver: Any) -> dict[str, list[dict[str, Any]]] | None:
    """The page's inbound RTP statistics (getStats), video and audio."""
    return driver.execute_async_script(PAGE_STATS)


def audio_energy(driver: Any) -> float:
    stats = page_stats(driver)
    return float(stats["audio"][0]["totalAudioEnergy"] or 0.0) if stats and stats["audio"] else 0.0


def video_stats(driver: Any) -> dict[str, Any]:
    stats = page_stats(driver)
    return stats["video"][0] if stats and stats["video"] else {}


def poll(value: Callable[[], float], good: Callable[[float], bool], timeout_s: float) -> float | None:
    """`value()` once it is good, or its last value at the timeout."""
    deadline = time.monotonic() + timeout_s
    got = value()
    while not good(got) and time.monotonic() < deadline:
        time.sleep(0.2)  # polling the page from outside: no event to wait on
        got = value()
    return got


def wait_for_frames(driver: Any, count: int, timeout_s: float) -> dict[str, Any]:
    """The video statistics once `count` frames of the face have been decoded."""
    deadline = time.monotonic() + timeout_s
    stats: dict[str, Any] = {}
    while time.monotonic() < deadline:
        stats = video_stats(driver)
        if (stats.get("framesDecoded") or 0) >= count:
            return stats
        time.sleep(0.2)  # polling the page from outside: no event to wait on
    raise TimeoutError(f"{count} frames of the face not decoded within {timeout_s} s (last {stats})")


def face_skin_share(driver: Any, screenshot: Path, element_id: str = "face") -> float:
    """The share of the page element's box (the face's video) in `screenshot` that is the face's warm skin
    (red well above blue): about a quarter for the 2D face at 640x480; none for an empty player (#111) or grey."""
    import numpy as np
    from PIL import Image

    box = driver.execute_script(f"const r = document.getElementById('{element_id}').getBoundingClientRect(); "
                                "return [r.x, r.y, r.width, r.height];")
    x, y, width, height = (round(v) for v in box)
    picture = np.asarray(Image.open(screenshot).convert("RGB"))[y:y + height, x:x + width].astype(int)
    return float(((picture[..., 0] > 150) & (picture[..., 0] - picture[..., 2] > 50)).mean())


def canvas_pixels(driver: Any) -> Any:
    """What the page's first face drawn by the page itself shows now (it presents a frame first): (H, W, 3) uint8."""
    import base64
    import io

    import numpy as np
    from PIL import Image

    url = driver.execute_script("const f = Object.values(window.eca.drawn)[0]; f.present(); "
                                "return f.canvas.toDataURL('image/png')")
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))).convert("RGB"))


def head_box(pixels: Any) -> tuple[int, int, int, int]:
    """(top, bottom, left, right) of what is not the background (the corner's colour) in a drawn face."""
    import numpy as np

    background = pixels[2, 2].astype(int)
    mask = np.abs(pixels.astype(int) - background).sum(axis=2) > 30
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    assert rows.size and cols.size, "nothing but the background is drawn"
    return int(rows[0]), int(rows[-1]), int(cols[0]), int(cols[-1])


def band_change(before: Any, after: Any, box: tuple[int, int, int, int], lo: float, hi: float) -> float:
    """Mean absolute change (0..255) within a horizontal band of the head, `lo`..`hi` of its height from its top,
    over its middle half in width."""
    import numpy as np

    top, bottom, left, right = box
    h, w = bottom - top, right - left
    rows = slice(top + int(lo * h), top + int(hi * h))
    cols = slice(left + w // 4, right - w // 4)
    return float(np.abs(after[rows, cols].astype(int) - before[rows, cols].astype(int)).mean())
