"""Suite-wide set-up: the shared `bus` fixture, the renderer's compiled code for the tests that draw, no WebRTC
candidates on another test worker's networks (tests/support/netns.py only_own_networks), and the workers' test
networks removed once they have all ended."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

import tests.support.bus
from eca.protocol.endpoints import BusConfig
from tests.support.bus import BrokerThread, private_bus_config
from tests.support.netns import netns_available, only_own_networks, remove_stale_routers

_compiled = False


def pytest_configure(config: pytest.Config) -> None:
    only_own_networks()
    tests.support.bus.REALTIME = False  # the suite's instances at the ordinary priority (tests/support/bus.py)


def pytest_unconfigure(config: pytest.Config) -> None:
    if not hasattr(config, "workerinput") and netns_available() is None:  # the controller, after its workers
        remove_stale_routers()


def pytest_runtest_setup(item: pytest.Item) -> None:
    """The renderer's compiled per-frame code, loaded (or compiled, on a machine that never ran setup) before
    the first test that draws (marked `gl`) or starts real processes that may (`slow`), so that none of them
    pays for it inside a measurement or a readiness timeout. Tests that draw nothing never load it."""
    global _compiled
    if not _compiled and (item.get_closest_marker("gl") or item.get_closest_marker("slow")):
        from eca.services.processes.renderer.kernels import warm_up

        warm_up()
        _compiled = True


@pytest.fixture
def bus_extra() -> str:
    """TOML tables the private instance of `bus` adds to the default config; a module overrides it."""
    return ""


@pytest.fixture
def bus(bus_extra: str) -> Iterator[BusConfig]:
    """A private instance (its own runtime directory, so tests run in parallel) with a real broker in a
    thread of the test process."""
    with private_bus_config(extra=bus_extra) as config, BrokerThread(config):
        yield config
