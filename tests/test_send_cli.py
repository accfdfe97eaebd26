"""`eca send` tells the truth: success means the dialogue service acknowledged that very command, a say
waited on succeeds only when it was spoken to the end, and bad arguments are refused before anything is
sent."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
import zmq

from eca.protocol.bus import Publisher
from eca.protocol.client import AgentClient
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import EmotionState, SetEmotion
from eca.services.processes.dialogue import DialogueService
from eca.services.tools.cli import main
from tests.support.bus import ServiceThread


@pytest.fixture
def bus_extra() -> str:
    return "[dialogue]\nsay_start_timeout_s = 0.3\n"  # a say no audio service takes fails soon


def send(config: BusConfig, *args: str) -> list[str]:
    return ["send", "--config", str(config.config_path), "--instance", config.instance, *args]


@pytest.mark.parametrize("timeout", ["-1", "0", "nan", "soon"])
def test_a_timeout_that_is_no_timeout_is_refused_at_once(bus: BusConfig, timeout: str,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        main(send(bus, "--timeout", timeout, "emotion", "happy"))
    assert done.value.code == 2
    err = capsys.readouterr().err
    assert "--timeout" in err and "Traceback" not in err


def test_a_value_already_in_the_cache_is_no_acknowledgement(bus: BusConfig,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    """With no dialogue service to apply it, a command whose value the cache happens to hold fails."""
    ctx = zmq.Context()
    pub = Publisher(ctx, bus, "dialogue")
    try:
        pub.wait_ready()
        pub.publish(EmotionState(agent="ada", name="happy", intensity=1.0, transition_s=0.5))
    finally:
        pub.close()
        ctx.term()
    with AgentClient(bus) as client:  # the cache has it
        assert client.state["emotion"].name == "happy"
    assert main(send(bus, "--timeout", "1", "emotion", "happy")) == 1
    assert "no acknowledgement of set_emotion within 1 s" in capsys.readouterr().err


def test_an_acknowledged_command_prints_the_state_it_caused(bus: BusConfig,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    with ServiceThread(DialogueService(bus)):
        assert main(send(bus, "head", "--turn", "0.4", "--duration", "0")) == 0
        assert "state.ada.head turn=0.4" in capsys.readouterr().out
        assert main(send(bus, "interrupt")) == 0  # nothing to stop is no failure: it is acknowledged
        assert main(send(bus, "interrupt", "--request", "never-sent")) == 1
        assert "no pending say request 'never-sent'" in capsys.readouterr().err


def test_say_wait_fails_unless_the_speech_finished(bus: BusConfig, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    wav = tmp_path / "tone.wav"
    t = np.arange(8000) / 16000
    sf.write(wav, 0.1 * np.sin(2 * math.pi * 300 * t), 16000)
    with ServiceThread(DialogueService(bus)):  # no audio service: the request fails after the start timeout
        assert main(send(bus, "say", "--file", str(wav), "--wait")) == 1
        out = capsys.readouterr().out
        assert "accepted" in out and "speech_failed" in out and "no audio service answered" in out
        assert main(send(bus, "say", "--file", str(tmp_path))) == 2
        assert "is a directory" in capsys.readouterr().err


def test_a_command_sent_again_is_acknowledged_again_but_applied_once(bus: BusConfig) -> None:
    service = DialogueService(bus)
    with ServiceThread(service), AgentClient(bus) as client:
        first = client.set_emotion("surprised", 0.3)
        client.wait_applied(first)
        client.wait_applied(client.set_emotion("annoyed", 0.6))
        again = client.send(SetEmotion(**{**vars(first), "seq": 0}))  # the first, sent again late (Lazy Pirate)
        client.wait_applied(again)
        client.wait_applied(client.set_eyes("noise"))
        assert service.agents["ada"].emotion.name == "annoyed"  # the repeat did not undo the later command


def test_every_state_verb_takes_every_field_of_its_command_within_its_limits(
        capsys: pytest.CaptureFixture[str]) -> None:
    from eca.protocol.codec import field_specs
    from eca.protocol.messages import ENVELOPE_FIELDS
    from eca.services.tools.cli import build_parser
    from eca.services.tools.commands.send import STATE_VERBS, option_name

    parser = build_parser()
    for verb, (cls, _) in STATE_VERBS.items():
        specs = [s for s in field_specs(cls) if s.name not in ENVELOPE_FIELDS and s.name != "request_id"]
        positional = [("talking" if s.name == "role" else "saccade" if s.name == "mode" else "happy")
                      for s in specs if s.required]
        args = parser.parse_args(["send", verb, *positional])
        for s in specs:
            assert getattr(args, s.name) == (cls.__dataclass_fields__[s.name].default if not s.required
                                             else getattr(args, s.name)), (verb, s.name)
        for s in (s for s in specs if s.kind is float and s.hi is not None):
            with pytest.raises(SystemExit) as done:
                parser.parse_args(["send", verb, *positional, f"--{option_name(s.name)}", str(s.hi + 1)])
            assert done.value.code == 2
            assert f"--{option_name(s.name)}" in capsys.readouterr().err
