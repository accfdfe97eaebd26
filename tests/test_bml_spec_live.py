"""The spec table run live: the BML 1.0 examples of tests/test_bml_spec_examples.py that hold no speech (a speech's
times are the voice's own, tested in tests/test_bml_service.py) go to a running realizer at once, each its own
block, with the table's default durations configured (a bml.toml in $ECA_CONFIG_DIR). Every sync point the
standard requires is reported by the feedback at the table's time from its block's start, within one frame,
and reported as it happens: each syncPointProgress leaves the realizer within a frame after its time, never
before it."""

from __future__ import annotations

import dataclasses
import os
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

import eca
from eca.protocol.client import AgentClient
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import BmlFeedback, Message
from tests.support.bus import eca_command, private_bus_config, running
from tests.test_bml_spec_examples import ROWS, TIMINGS

pytestmark = pytest.mark.slow
FRAME_S = 1 / 60
LIVE = [(name, xml, expected) for name, xml, speech, expected in ROWS
        if isinstance(expected, dict) and not speech and "<speech" not in xml and max(expected.values()) <= 12]


@pytest.fixture(scope="module")
def instance(tmp_path_factory: pytest.TempPathFactory) -> Iterator[BusConfig]:
    configs = tmp_path_factory.mktemp("configs")
    shipped = (Path(eca.shipped_configs()) / "bml.toml").read_text()
    timings = "\n".join(f"{f.name} = {getattr(TIMINGS, f.name)!r}" for f in dataclasses.fields(TIMINGS))
    (configs / "bml.toml").write_text(re.sub(r"\[timings\]\n(.*?\n)\n", f"[timings]\n{timings}\n\n", shipped,
                                             count=1, flags=re.S))
    with private_bus_config(services=["dialogue", "gaze"]) as config:
        argv = eca_command("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet",
                           "--bml")
        saved = os.environ.get("ECA_CONFIG_DIR")
        os.environ["ECA_CONFIG_DIR"] = str(configs)  # the children's environment is taken at their start
        try:
            with running(argv) as (_proc, reader):
                reader.wait_for("[up] ready in", 90.0)
                if saved is None:
                    os.environ.pop("ECA_CONFIG_DIR")
                else:
                    os.environ["ECA_CONFIG_DIR"] = saved
                yield config
        finally:
            if saved is None:
                os.environ.pop("ECA_CONFIG_DIR", None)


def test_the_spec_examples_are_realized_at_the_times_the_standard_requires(instance: BusConfig) -> None:
    assert len(LIVE) >= 10, [name for name, _, _ in LIVE]
    blocks = {f"live{k}": (name, xml.replace('id="bml1"', f'id="live{k}"', 1), expected)
              for k, (name, xml, expected) in enumerate(LIVE)}
    feedback: dict[str, list[BmlFeedback]] = {block: [] for block in blocks}
    ended: set[str] = set()
    with AgentClient(instance, agent="ada") as client:
        for _, xml, _ in blocks.values():
            client.wait_applied(client.bml(xml), 10.0)

        def collect(m: Message) -> bool:
            if isinstance(m, BmlFeedback) and m.block in feedback:
                feedback[m.block].append(m)
                if m.kind == "blockProgress" and m.sync == "end":
                    ended.add(m.block)
            return ended == set(blocks)

        client.wait_for(collect, 30.0)
    problems = []
    for block, (name, _, expected) in blocks.items():
        points = {(f.behaviour, f.sync): f for f in feedback[block] if f.kind == "syncPointProgress"}
        for (behaviour, sync), seconds in expected.items():
            got = points.get((behaviour, sync))
            if got is None:
                problems.append(f"{name}: no feedback for {behaviour}:{sync}")
            elif abs(got.time_s - seconds) > FRAME_S:
                problems.append(f"{name}: {behaviour}:{sync} at {got.time_s:.3f} s, the standard's {seconds:.3f} s")
        for f in points.values():  # reported as it happened: not before its time, and within a frame after it
            if not 0 <= f.t_ns - f.global_ns <= FRAME_S * 1e9 + 5e6:
                problems.append(f"{name}: {f.behaviour}:{f.sync} reported {(f.t_ns - f.global_ns) / 1e6:+.1f} ms "
                                "from its time")
    assert not problems, "\n".join(problems)
