"""The `eca experiment` index page in a real headless Chromium: at a laptop's 1280x800 and a 1920x1080
screen it does not scroll sideways, the conditions stand side by side, every video's poster loads and
is not covered by the player's controls until a pointer comes; a screenshot of each is kept."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from eca.services.tools.cli import main as eca
from eca.services.tools.experiment import CONDITIONS
from tests.support.browser import browser_available, chromium, wait_for

pytestmark = [pytest.mark.gl, pytest.mark.slow,
              pytest.mark.skipif(browser_available() is not None, reason=str(browser_available()))]

# Every poster as a fresh Image (not the <video>'s own, which a browser may load lazily): loaded or failed.
POSTERS = """
window.posters = window.posters || [...document.querySelectorAll("video")].map((video) => {
  const image = new Image();
  image.src = new URL(video.getAttribute("poster"), document.baseURI).href;
  return image;
});
return window.posters.map((i) => ({src: i.src, complete: i.complete, naturalWidth: i.naturalWidth}));
"""

LAYOUT = """
const root = document.documentElement;
return {scrollWidth: root.scrollWidth, clientWidth: root.clientWidth, innerWidth: window.innerWidth,
        videos: [...document.querySelectorAll("video")].map((v) => {
          const box = v.getBoundingClientRect();
          return {top: box.top, left: box.left, right: box.right, width: box.width, controls: v.controls};
        })};
"""


@pytest.fixture(scope="module")
def index_page(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("experiment")
    code = eca(["experiment", "--seconds", "2", "--size", "240x180", "--no-voice", "--no-csv", "-o", str(out)])
    assert code == 0
    return out / "index.html"


@pytest.fixture
def browser() -> Iterator[Any]:
    with chromium() as driver:
        yield driver


def show(driver: Any, page: Path, width: int, height: int) -> None:
    # The window's size includes the browser's own bars; the page is laid out in the viewport, so set that.
    driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride",
                           {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False})
    driver.get(page.as_uri())


@pytest.mark.parametrize(("width", "height"), [(1280, 800), (1920, 1080)])
def test_the_page_fits_the_screen_with_every_poster_loaded(index_page: Path, browser: Any, tmp_path: Path,
                                                            width: int, height: int) -> None:
    show(browser, index_page, width, height)
    posters = wait_for(browser, POSTERS, 20.0, "the posters loading",
                       lambda images: len(images) == len(CONDITIONS) and all(i["complete"] for i in images))
    assert all(i["naturalWidth"] > 0 for i in posters), posters
    layout = browser.execute_script(LAYOUT)
    browser.save_screenshot(str(tmp_path / f"experiment_{width}x{height}.png"))
    assert layout["innerWidth"] == width
    assert layout["scrollWidth"] <= layout["clientWidth"] <= width, layout
    videos = layout["videos"]
    # Side by side in one row, each at least as wide as a 200-px still, none past the right edge.
    assert len({round(v["top"]) for v in videos}) == 1, videos
    assert all(v["width"] >= 200 and v["right"] <= layout["clientWidth"] for v in videos), videos
    assert not any(v["controls"] for v in videos), "the controls would cover the posters' eyes"
    assert (tmp_path / f"experiment_{width}x{height}.png").stat().st_size > 50_000


def test_pointing_at_a_video_brings_its_controls(index_page: Path, browser: Any) -> None:
    from selenium.webdriver.common.action_chains import ActionChains

    show(browser, index_page, 1280, 800)
    videos = browser.find_elements("css selector", "video")
    ActionChains(browser).move_to_element(videos[1]).perform()
    wait_for(browser, "return [...document.querySelectorAll('video')].map((v) => v.controls)", 5.0,
             "the pointed-at video's controls", lambda shown: shown[1] and sum(shown) == 1)
    ActionChains(browser).move_to_element(browser.find_element("tag name", "h1")).perform()
    wait_for(browser, "return [...document.querySelectorAll('video')].some((v) => v.controls)", 5.0,
             "the controls going again", lambda shown: shown is False)
