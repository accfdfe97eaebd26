"""The PLY-like parameter files: the paper's example, each kind, time semantics, and every error."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from eca.agent.face.flexors import FLEXOR_INDEX
from eca.agent.script import ScriptError, load_params, load_script, parse_params

DATA = Path(__file__).parent / "data" / "scripts"


def test_the_papers_head_example_parses_as_printed() -> None:
    params = load_params(DATA / "paper_head.txt")
    assert params.kind == "head"
    first, second = params.elements
    assert (first.start_s, first.duration_s, first.head) == (0.0, 2.0, (1.0, 0.8, 0.0))
    assert (second.start_s, second.duration_s, second.head) == (2.0, 3.0, (-1.0, -1.0, 0.7))
    assert first.transition_s == 2.0  # a head transition moves over its whole duration
    for name, value in (("turn", 1.0), ("nod", 0.8), ("tilt", 0.0)):
        assert first.flexors[FLEXOR_INDEX[name]] == value
    # the eyes (and every flexor the head does not drive) get the "do not care" value
    assert math.isnan(first.flexors[FLEXOR_INDEX["look_x"]])
    assert not first.cares_about("smile_l") and first.cares_about("nod")
    assert params.length_s == 5.0


def test_a_head_file_becomes_head_cues() -> None:
    timeline = load_script(DATA / "paper_head.txt", agent="ada").timeline
    assert [(c.t_s, c.turn, c.nod, c.tilt, c.duration_s) for c in timeline.cues] == [
        (0.0, 1.0, 0.8, 0.0, 2.0),
        (2.0, -1.0, -1.0, 0.7, 3.0),
    ]
    assert timeline.agents == ("ada",) and timeline.length_s == 5.0


def _file(props: str, rows: str, count: int | None = None) -> str:
    n = count if count is not None else len([r for r in rows.splitlines() if r.strip()])
    return f"header\nelement transition {n}\n{props}end_header\n{rows}"


def test_emotion_file_by_name_or_index_with_start_times() -> None:
    text = _file(
        "property double start\nproperty double duration\nproperty string emotion\n"
        "property float intensity\n",
        "0;2;Half Angry;1\n2.5;1;happy;0.5\n",
    )
    elements = parse_params(text, "e.txt").elements
    assert [(e.start_s, e.emotion, e.intensity, e.kind) for e in elements] == [
        (0.0, "half-angry", 1.0, "emotion"),
        (2.5, "happy", 0.5, "emotion"),
    ]
    assert elements[0].transition_s == 0.5 and elements[1].transition_s == 0.5
    # the pose of the emotion is in the flexors; unrelated flexors stay do-not-care
    assert elements[1].flexors[FLEXOR_INDEX["smile_l"]] > 0
    assert math.isnan(elements[1].flexors[FLEXOR_INDEX["look_x"]])
    by_index = parse_params(_file("property int duration\nproperty int emotion\n", "1;4\n"), "e.txt")
    assert by_index.elements[0].emotion == "angry"


def test_status_file_and_roles_in_force() -> None:
    text = _file("property int duration\nproperty string role\n", "2;talking\n1;Speaking\n3;silence\n")
    elements = parse_params(text, "s.txt").elements
    assert [(e.start_s, e.role) for e in elements] == [(0.0, "talking"), (2.0, "talking"), (3.0, "silence")]
    by_index = parse_params(_file("property int duration\nproperty int role\n", "1;1\n"), "s.txt")
    assert by_index.elements[0].role == "listening"


def test_gaze_file_in_degrees_or_flexor_units_and_modes() -> None:
    text = _file("property double duration\nproperty double yaw\nproperty double pitch\n", "1;15;-30\n")
    (e,) = parse_params(text, "g.txt").elements
    assert (e.yaw_deg, e.pitch_deg, e.eye_mode) == (15.0, -30.0, None)
    assert e.flexors[FLEXOR_INDEX["look_x"]] == 0.5 and e.flexors[FLEXOR_INDEX["look_y"]] == -1.0
    text = _file("property double duration\nproperty string mode\nproperty double look_x\n"
                 "property double look_y\n", "1;saccade+blink;0.5;0\n")
    (e,) = parse_params(text, "g.txt").elements
    assert (e.eye_mode, e.yaw_deg, e.pitch_deg) == ("saccade+blink", 15.0, 0.0)


def test_comments_blank_lines_crlf_and_agent_column() -> None:
    text = ("header\r\n# c\r\ncomment also fine\r\nelement transition 2\r\nproperty int duration\r\n"
            "property string agent\r\nproperty double nod\r\nend_header\r\n\r\n# a pause\r\n"
            "1; bo ;0.5\r\n2;ada;-0.5\r\n")
    elements = parse_params(text, "h.txt").elements
    assert [(e.agent, e.head, e.line) for e in elements] == [
        ("bo", (None, 0.5, None), 11),
        ("ada", (None, -0.5, None), 12),
    ]


HEADER = "header\nelement transition 1\nproperty int duration\nproperty double nod_value\nend_header\n"

ERRORS = [
    # (content, line, column, message fragment)
    ("", 1, 1, "empty file"),
    ("  \n\n", 1, 1, "empty file"),
    ("ply\nformat ascii 1.0\n", 1, 1, "expected 'header' on the first line"),
    ("header\nelement transition 1\nproperty int duration\n", 4, 1, "missing 'end_header'"),
    ("header\nelement transition 1\nproperty int8 duration\nend_header\n1\n", 3, 10,
     "unknown property type 'int8'"),
    ("header\nelement transition 1\nproperty string duration\nend_header\n1\n", 3, 10,
     "property duration must be of type int or double or float, not string"),
    ("header\nelement transition 1\nproperty int duration\nproperty double frown\nend_header\n1;0\n",
     4, 17, "unknown property 'frown'"),
    ("header\nelement transition x\nproperty int duration\nproperty double nod\nend_header\n1;0\n", 2, 20,
     "element count 'x' is not a non-negative integer"),
    ("header\nelement frame 1\nproperty int duration\nproperty double nod\nend_header\n1;0\n", 2, 9,
     "unknown element 'frame'"),
    ("header\nproperty int duration\nelement transition 1\nproperty double nod\nend_header\n1;0\n", 2, 1,
     "'property' before 'element"),
    ("header\nelement transition 1\nproperty int duration\nproperty double nod\nproperty double nod_value\n"
     "end_header\n1;0;0\n", 5, 17, "property nod_value repeats nod (line 4)"),
    ("header\nelement transition 1\nproperty int duration\nproperty string role\nproperty double nod\n"
     "end_header\n1;talking;0\n", 5, 17, "belongs to head movements"),
    ("header\nelement transition 1\nproperty double nod\nend_header\n0\n", 4, 1,
     "missing property 'duration'"),
    ("header\nelement transition 1\nproperty double duration\nend_header\n1\n", 4, 1,
     "cannot tell the kind of file"),
    ("header\nelement transition 1\nproperty int duration\nproperty double yaw\nend_header\n1;0\n", 4, 17,
     "property yaw needs pitch too"),
    ("header\nfoo bar\nelement transition 1\nproperty int duration\nproperty double nod\nend_header\n1;0\n",
     2, 1, "unknown header keyword 'foo'"),
    (HEADER + "1;0\n2;0\n", 7, 1, "too many data lines: the header declares 1 transition"),
    (HEADER.replace("transition 1", "transition 3") + "1;0\n", 2, 20,
     "too few data lines: the header declares 3 transitions, the file has 1"),
    (HEADER + "1;0;0\n", 6, 5, "expected 2 values separated by ';' (duration, nod_value), found 3"),
    (HEADER + "1\n", 6, 2, "expected 2 values"),
    (HEADER + "1; x\n", 6, 4, "value 'x' does not parse as double for property nod_value"),
    (HEADER + "1.5;0\n", 6, 1, "value '1.5' does not parse as int for property duration"),
    (HEADER + "1;nan\n", 6, 3, "does not parse as double"),
    (HEADER + "1;1.5\n", 6, 3, "value 1.5 for property nod_value is out of range [-1, 1]"),
    (HEADER + "0;0\n", 6, 1, "duration 0 must be greater than 0 seconds"),
    (HEADER + "-2;0\n", 6, 1, "duration -2 must be greater than 0"),
    ("header\nelement transition 1\nproperty int duration\nproperty string emotion\nend_header\n1;glad\n",
     6, 3, "unknown emotion 'glad'; expected one of natural, happy"),
    ("header\nelement transition 1\nproperty int duration\nproperty int emotion\nend_header\n1;9\n",
     6, 3, "emotion index 9 is out of range [0, 8]"),
    ("header\nelement transition 1\nproperty int duration\nproperty string role\nend_header\n1;dancing\n",
     6, 3, "unknown role 'dancing'; expected one of talking, listening, silence"),
    ("header\nelement transition 1\nproperty int duration\nproperty string mode\nend_header\n1;blinky\n",
     6, 3, "unknown eye mode 'blinky'"),
    ("header\nelement transition 2\nproperty int start\nproperty int duration\nproperty double nod\n"
     "end_header\n3;1;0\n1;1;0\n", 8, 1, "start 1 comes before the previous transition's start"),
    ("header\nelement transition 1\nproperty int duration\nproperty int transition\nproperty double nod\n"
     "end_header\n1;2;0\n", 7, 3, "out of range [0, 1] seconds"),
]


@pytest.mark.parametrize(("content", "line", "column", "fragment"), ERRORS)
def test_every_error_names_its_line_and_column(content: str, line: int, column: int, fragment: str) -> None:
    with pytest.raises(ScriptError) as info:
        parse_params(content, "p.txt")
    err = info.value
    assert fragment in err.message
    assert (err.file, err.line, err.column) == ("p.txt", line, column), str(err)
    assert len(err.errors) == 1, str(err)  # one mistake, one error: nothing reported as its consequence
    assert str(err) == f"p.txt:{line}:{column}: {err.message}"


def test_binary_files_are_refused_with_the_position_of_the_bad_byte() -> None:
    with pytest.raises(ScriptError, match=r"^b.txt:2:3: binary file: NUL byte"):
        parse_params(b"header\nab\x00cd\n", "b.txt")
    with pytest.raises(ScriptError, match=r"^b.txt:1:4: binary file: bytes are not UTF-8"):
        parse_params(b"hea\xff\xfe\n", "b.txt")
    png = b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR"
    with pytest.raises(ScriptError, match="binary file"):
        parse_params(png, "b.png")


def test_missing_files_and_directories_raise_script_errors(tmp_path: Path) -> None:
    with pytest.raises(ScriptError, match="file not found"):
        load_params(tmp_path / "nope.txt")
    with pytest.raises(ScriptError, match="is a directory"):
        load_params(tmp_path)
