"""`eca check`: the demo content passes, broken files fail with file:line:column, usage errors exit 2."""

from __future__ import annotations

import pickle
from pathlib import Path

import pytest

from eca.agent.face.emotions import PAPER_EMOTIONS
from eca.agent.script import EmotionCue, HeadCue, RoleCue, SayCue, ScriptError, ScriptErrors, load_script, parse_params
from eca.services.tools.cli import main

ROOT = Path(__file__).resolve().parent.parent
DEMO = ROOT / "eca" / "configs" / "demo"
DATA = Path(__file__).parent / "data" / "scripts"


def test_every_demo_file_passes_check(capsys: pytest.CaptureFixture[str]) -> None:
    files = sorted(str(p) for p in DEMO.iterdir() if p.suffix in (".xml", ".txt"))
    assert len(files) == 6  # the dialogue of one agent, its four parameter files, the dialogue of three
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


def test_check_reports_every_error_of_a_file_in_order_then_goes_on(tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture[str]) -> None:
    params = tmp_path / "params.txt"
    params.write_text("header\nelement transition 3\nproperty int duration\nproperty double nod\nend_header\n"
                      "1;x\n1;0.5\n0;7\n")
    script = tmp_path / "d.xml"
    script.write_text('<dialogue agent="ada">\n'
                      '  <turn speaker="ada" emotion="glad">Hi</turn>\n'
                      '  <silence/>\n'
                      '</dialogue>\n')
    assert main(["check", str(params), str(script), str(DATA / "paper_head.txt")]) == 1
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [
        f"{params}:6:3: value 'x' does not parse as double for property nod",
        f"{params}:8:1: duration 0 must be greater than 0 seconds",
        f"{params}:8:3: value 7.0 for property nod is out of range [-1, 1]",
        f"{script}:2:3: <turn>: unknown emotion 'glad'; expected one of " + ", ".join(PAPER_EMOTIONS),
        f"{script}:3:3: <silence>: missing attribute 'duration'",
    ]
    assert "paper_head.txt: OK: head movements" in captured.out  # the files after a bad one are checked


def test_a_refused_header_line_is_reported_without_its_consequences() -> None:
    text = ("header\nelement transition 2\nproperty int duration\nproperty double nodd\n"
            "property string role\nend_header\n1;0;talking\n1;x;dancing\n")
    with pytest.raises(ScriptErrors) as info:
        parse_params(text, "p.txt")
    # the misspelt property is reported once; its values are still read as doubles, the rest checked
    first, *rest = [str(e) for e in info.value.errors]
    assert first.startswith("p.txt:4:17: unknown property 'nodd'; known properties: duration, ")
    assert rest == [
        "p.txt:8:3: value 'x' does not parse as double for property nodd",
        "p.txt:8:5: unknown role 'dancing'; expected one of talking, listening, silence",
    ]


def test_script_errors_read_as_the_first_and_hold_them_all() -> None:
    errors = ScriptErrors([ScriptError("a.txt", 2, 1, "first"), ScriptError("a.txt", 5, 3, "second")])
    assert isinstance(errors, ScriptError)
    assert (errors.file, errors.line, errors.column, errors.message) == ("a.txt", 2, 1, "first")
    assert str(errors) == "a.txt:2:1: first\na.txt:5:3: second"
    again = pickle.loads(pickle.dumps(errors))
    assert str(again) == str(errors) and len(again.errors) == 2
    assert ScriptError("b.txt", 1, 1, "x").errors[0].message == "x"  # one error is a list of one
    with pytest.raises(ValueError):
        ScriptErrors([])
