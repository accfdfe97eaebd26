"""`eca record` and `eca replay` on bad input: a clear error naming the file, no traceback."""

from __future__ import annotations

from pathlib import Path

import pytest

from services.cli import main
from services.testing import private_bus_config


def test_record_into_an_unwritable_place_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "no-such-dir" / "bus.rec"
    with private_bus_config() as config:
        code = main(["record", str(target), "--config", str(config.config_path), "--instance", config.instance,
                     "--seconds", "0.1"])
    assert code == 2
    err = capsys.readouterr().err
    assert "eca record:" in err and str(target) in err and "No such file" in err
    assert not target.parent.exists()
