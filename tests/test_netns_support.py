"""The test networks (tests/support/netns.py) and the WebRTC of the test process: candidates on the networks this
process made, none on another test worker's (which that worker removes under any connection using it)."""

from __future__ import annotations

import aioice.ice
import pytest

from tests.support.netns import OWN_BRIDGES, hosts, netns_available


@pytest.mark.skipif(netns_available() is not None, reason=f"{netns_available()}")
def test_webrtc_here_offers_its_own_network_and_not_another_workers() -> None:
    with hosts("a") as net:
        assert net.root_address in aioice.ice.get_host_addresses(True, False)  # this process's network
        OWN_BRIDGES.discard(net.bridge)  # the same bridge, as another worker's
        try:
            assert net.root_address not in aioice.ice.get_host_addresses(True, False)
        finally:
            OWN_BRIDGES.add(net.bridge)
    assert aioice.ice.get_host_addresses(True, False)  # the machine's own interfaces stay
