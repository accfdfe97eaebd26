"""Garbage in, ScriptError out: no input makes the script parsers raise anything else."""

from __future__ import annotations

from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from eca.agent.script import ScriptError, load_script, parse_dialogue, parse_params

DATA = Path(__file__).parent / "data" / "scripts"
PAPER = (DATA / "paper_head.txt").read_text()
TABLE = (DATA / "table.xml").read_text()
FAST = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _parses_or_script_error(call) -> None:  # type: ignore[no-untyped-def]
    try:
        call()
    except ScriptError as exc:
        assert exc.errors
        for error in exc.errors:  # every problem collected has a position and words
            assert error.line >= 1 and error.column >= 1 and error.message
            assert str(error) == f"{error.file}:{error.line}:{error.column}: {error.message}"


@FAST
@given(st.binary(max_size=400))
def test_random_bytes(data: bytes) -> None:
    _parses_or_script_error(lambda: parse_params(data, "x.txt"))
    _parses_or_script_error(lambda: parse_dialogue(data, "x.xml", DATA))


@FAST
@given(st.text(max_size=400))
def test_random_text(text: str) -> None:
    _parses_or_script_error(lambda: parse_params(text, "x.txt"))
    _parses_or_script_error(lambda: parse_dialogue(text.encode("utf-8", "surrogatepass"), "x.xml", DATA))


def _mutate(source: str, edits: list[tuple[int, int, str]]) -> str:
    """Deletes and inserts at positions in a valid file, to reach past the first checks."""
    text = source
    for pos, cut, insert in edits:
        at = pos % (len(text) + 1)
        text = text[:at] + insert + text[at + cut:]
    return text


_EDITS = st.lists(
    st.tuples(st.integers(0, 10_000), st.integers(0, 4),
              st.sampled_from(["", ";", "x", "-", "1", "99999", "\n", " ", "<", ">", '"', "=", "e9",
                               "nan", "#", "property int a\n", "end_header\n", "<turn/>", "'", "&amp;",
                               "0" * 50, "\u00e9", "\r"])),
    max_size=6,
)


@FAST
@given(_EDITS)
def test_mutated_paper_example(edits: list[tuple[int, int, str]]) -> None:
    text = _mutate(PAPER, edits)
    _parses_or_script_error(lambda: parse_params(text, "head.txt"))


@FAST
@given(_EDITS)
def test_mutated_dialogue(edits: list[tuple[int, int, str]]) -> None:
    data = _mutate(TABLE, edits).encode()
    _parses_or_script_error(lambda: parse_dialogue(data, "table.xml", DATA))


@settings(max_examples=40, deadline=None)
@given(st.binary(max_size=200))
def test_random_files_through_the_loader(tmp_path_factory, data: bytes) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path_factory.mktemp("fuzz") / "f.xml"
    path.write_bytes(data)
    _parses_or_script_error(lambda: load_script(path))
