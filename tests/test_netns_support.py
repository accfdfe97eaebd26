"""The test networks (tests/support/netns.py): their bridges are in a router namespace of this process's own, so
the root namespace (where the tests' browsers and WebRTC peers gather candidates) gains one link per test process,
not one per network; the test still reaches every host and each host the test; and the WebRTC of the test process
offers no candidate on another test process's link."""

from __future__ import annotations

import socket
import subprocess
import sys

import aioice.ice
import pytest

from tests.support.netns import OWN_LINKS, UPLINK_PREFIX, hosts, netns_available

pytestmark = pytest.mark.skipif(netns_available() is not None, reason=f"{netns_available()}")


def root_links() -> set[str]:
    out = subprocess.run(["ip", "-o", "link", "show"], capture_output=True, text=True, check=True).stdout
    return {line.split(":")[1].strip().split("@")[0] for line in out.splitlines()}


def test_networks_come_and_go_without_a_link_in_the_root_namespace_and_reach_the_test() -> None:
    with hosts("first"):
        pass  # this process's router and its uplink exist from its first network on
    before = root_links()
    with hosts("a", "b") as net:
        during = root_links()
        echo = net["a"].popen([sys.executable, "-c", (
            "import socket; s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.bind(('0.0.0.0', 40000)); "
            "data, peer = s.recvfrom(64); s.sendto(data.upper(), peer)")])
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
                sock.bind((net.root_address, 0))
                sock.settimeout(0.5)
                answer = b""
                for _ in range(20):  # until the host's program listens
                    sock.sendto(b"ping", (net["a"].address, 40000))
                    try:
                        answer = sock.recv(64)
                        break
                    except TimeoutError:
                        continue
        finally:
            echo.kill()
            echo.wait()
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as listener:  # a host reaches the test's address
            listener.bind((net.root_address, 0))
            listener.settimeout(10.0)
            port = listener.getsockname()[1]
            sender = net["b"].popen([sys.executable, "-c", (
                "import socket; s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.settimeout(5); "
                f"s.sendto(b'hello', ('{net.root_address}', {port})); print(s.recv(64).decode())")],
                stdout=subprocess.PIPE, text=True)
            data, peer = listener.recvfrom(64)
            listener.sendto(data.upper(), peer)
            heard, _ = sender.communicate(timeout=10)
    after = root_links()
    assert before == during == after  # no link of the root namespace came or went with the network
    assert any(name.startswith(UPLINK_PREFIX) and name in OWN_LINKS for name in before)
    assert answer == b"PING"  # the test reaches a host from its own address, and the host answers it
    assert data == b"hello" and peer[0] == net["b"].address and heard.strip() == "HELLO"


def test_webrtc_here_offers_its_own_link_and_not_another_processes() -> None:
    with hosts("a") as net:
        assert net.root_address in aioice.ice.get_host_addresses(True, False)  # this process's link
        [own] = [name for name in OWN_LINKS]
        OWN_LINKS.discard(own)  # the same link, as another process's
        try:
            assert net.root_address not in aioice.ice.get_host_addresses(True, False)
        finally:
            OWN_LINKS.add(own)
    assert aioice.ice.get_host_addresses(True, False)  # the machine's own interfaces stay
