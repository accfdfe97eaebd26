"""The gaze service's command line (`python -m eca.services.processes.run gaze ...`)."""

from __future__ import annotations

import pytest

from eca.services.processes.gaze import GazeService
from tests.support.bus import private_bus_config


@pytest.mark.parametrize(("argv", "says"), [
    (["--seed"], "expected one argument"),
    (["--seed", "x"], "invalid int value: 'x'"),
    (["--sed", "3"], "unknown gaze arguments: --sed 3"),
])
def test_bad_arguments_are_a_clear_error(argv: list[str], says: str, capsys: pytest.CaptureFixture[str]) -> None:
    with private_bus_config() as config, pytest.raises(SystemExit) as stopped:
        GazeService.from_args(config, argv)
    assert stopped.value.code == 2
    err = capsys.readouterr().err
    assert "[gaze] ERROR" in err and says in err

