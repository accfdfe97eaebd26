"""`eca check`: the demo content passes, broken files fail with file:line:column, usage errors exit 2."""

from __future__ import annotations

from pathlib import Path

import pytest

from agent.face.emotions import PAPER_EMOTIONS
from agent.script import EmotionCue, HeadCue, RoleCue, SayCue, load_script
from services.cli import main

ROOT = Path(__file__).resolve().parent.parent
DEMO = ROOT / "configs" / "demo"
DATA = Path(__file__).parent / "data" / "scripts"


def test_every_demo_file_passes_check(capsys: pytest.CaptureFixture[str]) -> None:
    files = sorted(str(p) for p in DEMO.iterdir() if p.suffix in (".xml", ".txt"))
    assert len(files) == 5
    assert main(["check", *files]) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == len(files) and all(": OK: " in line for line in out)
    assert "dialogue: ada with user" in out[0]


def test_the_demo_dialogue_has_the_shape_the_demo_needs() -> None:
    t = load_script(DEMO / "dialogue.xml").timeline
    assert 45.0 <= t.length_s <= 75.0
    roles = {c.role for c in t.cues if isinstance(c, RoleCue)}
    assert roles == {"talking", "listening", "silence"}
    emotions = {c.name for c in t.cues if isinstance(c, EmotionCue)}
    assert emotions == set(PAPER_EMOTIONS)
    assert sum(isinstance(c, HeadCue) for c in t.cues) >= 3
    says = [c for c in t.cues if isinstance(c, SayCue)]
    assert {c.agent for c in says} == {"ada", "user"} and all(c.text for c in says)
    kinds = {e.kind for e in t.elements if e.file.endswith(".txt")}
    assert kinds == {"emotion", "gaze", "head", "status"}


def test_check_reports_errors_with_positions_and_exit_1(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "head.txt"
    bad.write_text((DATA / "paper_head.txt").read_text().replace("2;1;0.8;0", "2;1;x;0"))
    assert main(["check", str(DATA / "paper_head.txt"), str(bad)]) == 1
    captured = capsys.readouterr()
    assert "paper_head.txt: OK: head movements: 2 elements, 5.0 s" in captured.out
    assert captured.err.strip() == f"{bad}:9:5: value 'x' does not parse as double for property nod_value"


def test_check_without_files_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["check"])
    assert info.value.code == 2
