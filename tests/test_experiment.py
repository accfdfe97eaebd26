"""`eca experiment`: the poster frame each video shows before it plays, the index page for any number of
conditions (escaped labels, a poster on every video), and a real short run's page and files."""

from __future__ import annotations

import csv
from html.parser import HTMLParser
from pathlib import Path

import av
import numpy as np
import pytest
from PIL import Image

from eca.agent.gaze.params import MODES
from eca.services.tools.cli import main as eca
from eca.services.tools.experiment import (
    CONDITIONS,
    OPEN_LID,
    POSTER_AFTER_S,
    Condition,
    Panel,
    poster_frame,
    write_index,
)


class Page(HTMLParser):
    """The parts of an index page the tests read: each condition's heading text and its media."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.sections: list[dict[str, str]] = []
        self.stylesheet = ""
        self._in: str | None = None
        self.feed(text)
        self.close()

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        values = {k: v or "" for k, v in attrs}
        if tag == "section":
            self.sections.append({"heading": ""})
        elif tag in ("video", "img") and self.sections:
            self.sections[-1].update({f"{tag}.{k}": v for k, v in values.items()})
        self._in = tag

    def handle_endtag(self, tag: str) -> None:
        self._in = None

    def handle_data(self, data: str) -> None:
        if self._in == "h2" and self.sections:
            self.sections[-1]["heading"] += data
        elif self._in == "style":
            self.stylesheet += data


def test_the_poster_is_the_first_open_eyed_frame_from_one_second_on() -> None:
    t = np.arange(90) / 30.0
    lid = np.zeros(90)
    assert t[poster_frame(t, lid)] == pytest.approx(POSTER_AFTER_S)
    lid[28:36] = 0.8  # a blink across the one-second mark
    assert poster_frame(t, lid) == 36
    lid[36] = OPEN_LID  # half-open is not open
    assert poster_frame(t, lid) == 37


def test_a_render_without_an_open_eye_late_enough_falls_back_to_the_latest_earlier_one() -> None:
    t = np.arange(20) / 30.0  # shorter than a second
    lid = np.full(20, 0.9)
    lid[[3, 7]] = 0.0
    assert poster_frame(t, lid) == 7
    lid[:] = np.linspace(0.9, 0.5, 20)  # never open: the most open one
    assert poster_frame(t, lid) == 19


def test_a_poster_needs_a_lid_value_per_frame() -> None:
    with pytest.raises(ValueError, match="one lid value per frame"):
        poster_frame(np.arange(3) / 30.0, np.zeros(2))
    with pytest.raises(ValueError):
        poster_frame(np.zeros(0), np.zeros(0))


def test_every_condition_is_an_eye_mode_with_files_of_its_own() -> None:
    assert {c.key for c in CONDITIONS} <= set(MODES)
    names = [name for c in CONDITIONS for name in vars(Panel.of(c)).values() if isinstance(name, str)]
    assert len(names) == len(set(names)) == 3 * len(CONDITIONS)
    assert len({c.label for c in CONDITIONS}) == len(CONDITIONS)


@pytest.mark.parametrize("count", [1, 4, 5, 7])
def test_the_page_has_one_section_per_condition_each_video_with_its_poster(tmp_path: Path, count: int) -> None:
    panels = [Panel.of(Condition(f"mode{i}", f"({i}) condition {i}")) for i in range(count)]
    write_index(tmp_path, "Title", panels, "Notes.", (480, 360))
    page = Page((tmp_path / "index.html").read_text(encoding="utf-8"))
    assert [s["heading"] for s in page.sections] == [p.condition.label for p in panels]
    for section, panel in zip(page.sections, panels, strict=True):
        assert (section["video.src"], section["video.poster"]) == (panel.video, panel.poster)
        assert (section["video.width"], section["video.height"]) == ("480", "360")
        assert section["img.src"] == panel.plot
    # The layout: as many columns as fit, every picture as wide as its column.
    assert "minmax(" in page.stylesheet and "width: 100%" in page.stylesheet
    markdown = (tmp_path / "index.md").read_text(encoding="utf-8")
    assert all(f"]({p.poster})]({p.video})" in markdown for p in panels)


def test_the_page_escapes_labels_title_and_notes(tmp_path: Path) -> None:
    label = """(x) <b>bold</b> & "quoted" — 'it's' | piped"""
    panel = Panel(Condition("a+b", label), 'v"1.mp4', "p<1>.png", "t&1.png")
    write_index(tmp_path, "<i>Title</i>", [panel], "Notes </p><script>alert(1)</script>", (160, 120))
    text = (tmp_path / "index.html").read_text(encoding="utf-8")
    assert "<b>" not in text and "<i>" not in text and "alert(1)</script>" not in text
    page = Page(text)
    (section,) = page.sections
    assert section["heading"] == label
    assert (section["video.src"], section["video.poster"], section["img.src"]) == ('v"1.mp4', "p<1>.png", "t&1.png")
    assert label in section["img.alt"]
    # A pipe would end a Markdown table cell early.
    assert "\\| piped" in (tmp_path / "index.md").read_text(encoding="utf-8")


def decoded_frame(video: Path, t_s: float) -> np.ndarray:
    with av.open(str(video)) as container:
        for frame in container.decode(video=0):
            if abs(frame.time - t_s) < 1e-6:
                return frame.to_ndarray(format="rgb24")
    raise AssertionError(f"{video}: no frame at {t_s} s")


@pytest.mark.gl
def test_a_run_writes_for_every_condition_a_video_its_poster_and_a_plot(tmp_path: Path) -> None:
    out = tmp_path / "experiment"
    assert eca(["experiment", "--seconds", "1.5", "--size", "160x120", "--no-voice", "-o", str(out)]) == 0
    page = Page((out / "index.html").read_text(encoding="utf-8"))
    assert [s["heading"] for s in page.sections] == [c.label for c in CONDITIONS]
    for section, cond in zip(page.sections, CONDITIONS, strict=True):
        video, poster = out / section["video.src"], out / section["video.poster"]
        assert video.is_file() and poster.is_file() and (out / section["img.src"]).is_file()
        with open(video.with_suffix(".csv")) as fh:
            frames = [(float(r["t_s"]), float(r["lid"])) for r in csv.DictReader(fh)]
        t, lid = (np.array(column) for column in zip(*frames, strict=True))
        k = poster_frame(t, lid)
        assert t[k] >= POSTER_AFTER_S and lid[k] < OPEN_LID, cond.key
        with Image.open(poster) as image:
            assert image.size == (160, 120)
            pixels = np.asarray(image.convert("RGB"))
        # The poster is the video's own frame at that time, and not an empty one.
        assert np.array_equal(pixels, decoded_frame(video, float(t[k]))), cond.key
        assert pixels.std() > 20, cond.key
