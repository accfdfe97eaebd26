"""Network namespaces as hosts, for tests of eca across machines (as root; CI runs as root).

`hosts("dm", "model", "web")` makes one namespace per name, each with its own address on a private /24, all
linked through a bridge in the root namespace (which has an address on it too, so the test itself reaches every
host). Loopback is up in each. A "host" runs a command with `host.popen(argv)` / `host.run(argv)`; `host.cut()`
and `host.heal()` take its link down and up (a partition, as `ip link set dev down` does to a real cable).
Everything is removed on exit, whatever happened. Names carry the pid and a counter, so parallel test workers
never collide.

A filesystem `ipc://` endpoint is reachable from every namespace (one filesystem): cross-host links in a test
must be `tcp://` to these addresses, or the test passes through the filesystem without noticing.
"""

from __future__ import annotations

import itertools
import os
import random
import shutil
import subprocess
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

_count = itertools.count(1)
_ROOT = Path(__file__).resolve().parents[2]  # the repository: where `-m tests.support...` runs


def netns_available() -> str | None:
    """None when namespaces can be made here; otherwise why not (a skip reason)."""
    if os.geteuid() != 0:
        return "network namespaces need root"
    if shutil.which("ip") is None:
        return "the ip command (iproute2) is not installed"
    probe = f"ecap{os.getpid() % 100000}"
    made = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if made.returncode != 0:
        return f"cannot create a network namespace: {made.stderr.strip()}"
    subprocess.run(["ip", "netns", "delete", probe], capture_output=True)
    return None


def _ip(*args: str) -> None:
    done = subprocess.run(["ip", *args], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)}: {done.stderr.strip()}")


@dataclass
class Host:
    name: str  # the namespace
    address: str  # its address on the bridge's /24
    veth_outside: str  # its cable's end in the root namespace (cut/heal take it down/up)

    def argv(self, argv: Sequence[str]) -> list[str]:
        return ["ip", "netns", "exec", self.name, *argv]

    def popen(self, argv: Sequence[str], **kwargs: Any) -> subprocess.Popen[bytes]:
        return subprocess.Popen(self.argv(argv), **kwargs)

    def run(self, argv: Sequence[str], **kwargs: Any) -> subprocess.CompletedProcess[Any]:
        return subprocess.run(self.argv(argv), **kwargs)

    def cut(self) -> None:
        """Partition this host from every other (its link goes down; sockets stay open on both sides)."""
        _ip("link", "set", "dev", self.veth_outside, "down")

    def heal(self) -> None:
        _ip("link", "set", "dev", self.veth_outside, "up")


@dataclass
class Network:
    hosts: dict[str, Host]
    bridge: str
    root_address: str  # the root namespace's (the test's own) address on the bridge

    def __getitem__(self, name: str) -> Host:
        return self.hosts[name]


def _free_prefix() -> str:
    """A /24 of 10.<x>.<y>.0 that no interface here is on: two networks on one prefix (another test worker's) would
    route each other's packets to the wrong bridge. Drawn from this process's own seeded sequence."""
    used = subprocess.run(["ip", "-4", "-o", "addr", "show"], capture_output=True, text=True).stdout
    draw = random.Random(os.getpid() * 1_000_003 + next(_count))
    for _ in range(1000):
        prefix = f"10.{draw.randrange(10, 250)}.{draw.randrange(0, 250)}"
        if f" {prefix}." not in used:
            return prefix
    raise RuntimeError("no free 10.x.y.0/24 for a test network")


def _no_offloads(ns: str | None, link: str) -> None:
    """Frames one MTU at most on `link` (a delay link forwards frames as they are; see tests/support/delay_link.py)."""
    argv = ["ethtool", "-K", link, "gro", "off", "gso", "off", "tso", "off", "tx", "off", "rx", "off"]
    done = subprocess.run(argv if ns is None else ["ip", "netns", "exec", ns, *argv], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)}: {done.stderr.strip()}")


def _delay_link(ns: str, a: str, b: str, delay_s: float) -> subprocess.Popen[str]:
    """tests/support/delay_link.py between `a` and `b` in namespace `ns`, once it is forwarding."""
    proc = subprocess.Popen(["ip", "netns", "exec", ns, sys.executable, "-m", "tests.support.delay_link", a, b,
                             repr(delay_s)], cwd=_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    line = proc.stdout.readline()  # the program says "ready" once bound, or ends (an error on stderr)
    if line.strip() != "ready":
        proc.kill()
        _, err = proc.communicate(timeout=5)
        raise RuntimeError(f"the delay link in {ns} did not start: {err.strip()[-500:]}")
    return proc


BRIDGE_PREFIX = "ecb"  # every test network's bridge in the root namespace is named so
OWN_BRIDGES: set[str] = set()  # the bridges this process made (its networks' own)


def others_bridge_addresses() -> set[str]:
    """The addresses of the test networks' bridges that another process made (another test worker's, which it removes
    when its test ends): see only_own_networks."""
    import ifaddr

    return {str(ip.ip if isinstance(ip.ip, str) else ip.ip[0]) for adapter in ifaddr.get_adapters()
            if adapter.name.startswith(BRIDGE_PREFIX) and adapter.name not in OWN_BRIDGES for ip in adapter.ips}


def only_own_networks() -> None:
    """aioice (the WebRTC of the test process's own peers: test clients, services run in threads) offers no candidate
    on another test worker's network, which that worker removes when its test ends, under any connection whose pair
    was there. Its own networks, and every other interface, it still offers. (A browser in the root namespace offers
    every bridge: Chromium's --force-webrtc-ip-handling-policy left them in.)"""
    import aioice.ice

    gather = aioice.ice.get_host_addresses
    if getattr(gather, "only_own_networks", False):
        return

    def host_addresses(use_ipv4: bool, use_ipv6: bool) -> list[str]:
        others = others_bridge_addresses()
        return [address for address in gather(use_ipv4, use_ipv6) if address not in others]

    host_addresses.only_own_networks = True  # type: ignore[attr-defined]
    aioice.ice.get_host_addresses = host_addresses


@contextmanager
def hosts(*names: str, delays: dict[str, float] | None = None) -> Iterator[Network]:
    """One namespace per name on a private bridge; all removed afterwards.

    `delays`: hosts whose cable to the bridge holds every frame this many seconds each way (a far host: a round trip
    of twice that to any other), through a namespace of its own between them that runs tests/support/delay_link.py
    (needs ethtool)."""
    if not 1 <= len(names) <= 50:
        raise ValueError("between 1 and 50 hosts")
    delays = dict(delays or {})
    if set(delays) - set(names) or any(not 0.0 <= d <= 5.0 for d in delays.values()):
        raise ValueError(f"delays name hosts of {names}, each 0..5 s: {delays}")
    tag = f"{os.getpid() % 100000}{next(_count)}"
    prefix = _free_prefix()
    bridge = f"{BRIDGE_PREFIX}{tag}"[:15]
    OWN_BRIDGES.add(bridge)
    made_ns: list[str] = []
    made_links: list[str] = []
    links: list[subprocess.Popen[str]] = []
    try:
        _ip("link", "add", bridge, "type", "bridge")
        made_links.append(bridge)
        _ip("addr", "add", f"{prefix}.1/24", "dev", bridge)
        _ip("link", "set", bridge, "up")
        out: dict[str, Host] = {}
        for i, name in enumerate(names, start=2):
            ns = f"eca{tag}{name}"[:32]
            _ip("netns", "add", ns)
            made_ns.append(ns)
            outside, inside = f"eo{tag}{i}"[:15], f"ei{tag}{i}"[:15]
            if name not in delays:
                _ip("link", "add", outside, "type", "veth", "peer", "name", inside)
            else:
                # two cables through a namespace of their own: outside <-> b | delay link | a <-> inside; the outside
                # end is on the bridge as for any host, so cut() still works
                link_ns = f"eca{tag}{name}"[:30] + "dl"
                _ip("netns", "add", link_ns)
                made_ns.append(link_ns)
                a, b = f"ea{tag}{i}"[:15], f"eb{tag}{i}"[:15]
                _ip("link", "add", outside, "type", "veth", "peer", "name", b, "netns", link_ns)
                _ip("link", "add", inside, "type", "veth", "peer", "name", a, "netns", link_ns)
                for end in (a, b):
                    _ip("netns", "exec", link_ns, "ip", "link", "set", end, "up")
                    _no_offloads(link_ns, end)
                _no_offloads(None, outside)
                links.append(_delay_link(link_ns, a, b, delays[name]))
            made_links.append(outside)
            _ip("link", "set", inside, "netns", ns)
            _ip("link", "set", outside, "master", bridge)
            _ip("link", "set", outside, "up")
            _ip("netns", "exec", ns, "ip", "addr", "add", f"{prefix}.{i}/24", "dev", inside)
            _ip("netns", "exec", ns, "ip", "link", "set", inside, "up")
            if name in delays:
                _no_offloads(ns, inside)
            _ip("netns", "exec", ns, "ip", "link", "set", "lo", "up")
            out[name] = Host(ns, f"{prefix}.{i}", outside)
        yield Network(out, bridge, f"{prefix}.1")
    finally:
        for proc in links:
            proc.kill()
            proc.communicate()
        for link in reversed(made_links):
            subprocess.run(["ip", "link", "delete", link], capture_output=True)
        for ns in made_ns:
            subprocess.run(["ip", "netns", "delete", ns], capture_output=True)
