"""Numbers out of range are refused by the CLI before anything starts, naming the option."""

from __future__ import annotations

import pytest

from eca.services.tools.cli import main


@pytest.mark.parametrize("argv, option", [
    (["monitor", "--count", "0"], "--count"),
    (["monitor", "--seconds", "-1"], "--seconds"),
    (["monitor", "--seconds", "nan"], "--seconds"),
    (["record", "--seconds", "inf", "out.rec"], "--seconds"),
    (["replay", "--speed", "-2", "in.rec"], "--speed"),
    (["replay", "--speed", "nan", "in.rec"], "--speed"),
    (["up", "--seconds", "-5"], "--seconds"),
    (["send", "--timeout", "-1", "role", "talking"], "--timeout"),
])
def test_an_out_of_range_number_is_refused_naming_the_option(argv: list[str], option: str,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        main(argv)
    assert done.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {option}:" in err and "Traceback" not in err
