"""The instance config's agents: one typed setting, read in one place, checked with a clear message."""

from __future__ import annotations

from pathlib import Path

import pytest

from eca.protocol.endpoints import BusConfigError, load_bus_config
from tests.support.bus import write_test_config


def test_the_agents_come_from_one_place_in_seat_order(tmp_path: Path) -> None:
    config = load_bus_config(write_test_config(tmp_path, agents=["bob", "ada", "cy"]), instance="agents1")
    assert config.agents == ("bob", "ada", "cy")
    assert load_bus_config(write_test_config(tmp_path), instance="agents2").agents == ("ada",)


@pytest.mark.parametrize("ids, problem", [
    ('[]', "1 to 64 distinct"), ('["ada", "ada"]', "distinct"), ('["user"]', "not 'user'"),
    ('["a b"]', "letters, digits"), ('["x" ]', None), ('"ada"', "must be list"), ('[1]', "letters"),
])
def test_a_bad_agent_list_is_named_with_its_file(tmp_path: Path, ids: str, problem: str | None) -> None:
    path = write_test_config(tmp_path)
    path.write_text(path.read_text().replace('ids = ["ada"]', f"ids = {ids}", 1))
    if problem is None:
        assert load_bus_config(path, instance="agents3").agents == ("x",)
        return
    with pytest.raises(BusConfigError) as info:
        load_bus_config(path, instance="agents4")
    assert str(path) in str(info.value) and "[agents]" in str(info.value) and problem in str(info.value)
