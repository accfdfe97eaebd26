"""The BML examples that docs/bml.md shows: `eca check` passes each (its timeline printed, its warnings named),
and a file with a bad block fails with the file, the line and the block."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from tests.support.bus import REPO_ROOT, eca_command

EXAMPLES = sorted((REPO_ROOT / "examples" / "bml").glob("*.bml"))
WARNED = {"greta_and_constraints.bml": "BEHAVIOR_TYPE_NOT_SUPPORTED"}


def check(*paths: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(eca_command("check", *paths), capture_output=True, text=True, timeout=60, cwd=REPO_ROOT)


def test_every_example_checks_with_its_timeline_and_warnings() -> None:
    assert len(EXAMPLES) >= 4
    done = check(*map(str, EXAMPLES))
    assert done.returncode == 0, done.stderr
    for path in EXAMPLES:
        assert f"{path}: OK: block '" in done.stdout
        warning = WARNED.get(path.name)
        assert (warning is not None) == (f"{path}:" in done.stderr and "warning" in done.stderr.split(str(path))[1]
                                         .split("\n")[0]), done.stderr
        if warning:
            assert warning in done.stderr
    assert "h1:stroke" in done.stdout and "s1:w1" in done.stdout


@pytest.mark.parametrize("text, wanted", [
    ('<bml id="b1">\n<head id="h1" lexeme="NOD" start="s9:start"/></bml>', ":2:"),
    ('<bml id="b1">\n\n<head id="h1" lexeme="NOD" repetition="1000"/></bml>', ":3:"),
    ('<bml id="b1"><head id="h1"', ":1:"),
])
def test_a_bad_block_fails_naming_the_file_and_line(tmp_path: Path, text: str, wanted: str) -> None:
    path = tmp_path / "bad.bml"
    path.write_text(text)
    done = check(str(path))
    assert done.returncode == 1 and f"{path}{wanted}" in done.stderr, done.stderr
