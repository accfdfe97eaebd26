"""`eca record` and `eca replay` on bad input: a clear error naming the file, no traceback."""

from __future__ import annotations

from pathlib import Path

import pytest

from eca.services.tools.cli import main
from tests.support.bus import private_bus_config


def test_record_into_an_unwritable_place_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "no-such-dir" / "bus.rec"
    with private_bus_config() as config:
        code = main(["record", str(target), "--config", str(config.config_path), "--instance", config.instance,
                     "--seconds", "0.1"])
    assert code == 2
    err = capsys.readouterr().err
    assert "eca record:" in err and str(target) in err and "No such file" in err
    assert not target.parent.exists()


def test_record_with_no_instance_says_so_instead_of_recording_nothing(tmp_path: Path,
                                                                       capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "bus.rec"
    with private_bus_config() as config:
        code = main(["record", str(target), "--config", str(config.config_path), "--instance", config.instance,
                     "--seconds", "0.5"])
    assert code == 1
    assert "no answer from the broker" in capsys.readouterr().err


def test_a_recording_starts_with_the_current_state_and_holds_what_followed(tmp_path: Path) -> None:
    from eca.protocol.client import AgentClient
    from eca.services.processes.dialogue import DialogueService
    from eca.services.tools.recording import read_recording
    from tests.support.bus import BrokerThread, ServiceThread, eca_command, running

    target = tmp_path / "bus.rec"
    with private_bus_config() as config, BrokerThread(config), ServiceThread(DialogueService(config)):
        with AgentClient(config) as client:
            client.wait_applied(client.set_emotion("annoyed", 0.4))
        argv = eca_command("record", str(target), "--config", str(config.config_path), "--instance",
                           config.instance, "--seconds", "3")
        with running(argv) as (proc, reader):
            reader.wait_for("recording ", 20.0)
            with AgentClient(config) as client:
                client.wait_applied(client.set_role("silence"))
            proc.wait(timeout=20)
    _, records = read_recording(target)
    topics = [r.topic for r in records]
    assert b"state.ada.emotion" in topics  # the state as it was when recording began, from the cache
    command = topics.index(b"cmd.ada.set_role")
    assert topics.index(b"state.ada.emotion") < command < len(topics) - 1 - topics[::-1].index(b"state.ada.role")
