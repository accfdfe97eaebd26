"""Network namespaces as hosts, for tests of eca across machines (as root; CI runs as root).

`hosts("dm", "model", "web")` makes one namespace per name, each with its own address on a private /24, all
linked through a bridge. Loopback is up in each. A "host" runs a command with `host.popen(argv)` /
`host.run(argv)`; `host.cut()` and `host.heal()` take its link down and up (a partition, as `ip link set dev down`
does to a real cable). Everything is removed on exit, whatever happened.

The bridges are not in the root namespace but in a router namespace of this process's own ("ecr<pid>", made at its
first network and removed when it exits), joined to the root namespace by one link ("ecu<pid>", address
10.<b>.0.1): the test itself reaches every host through it, and each host has a route back to it. So the root
namespace, where the test's browsers and WebRTC peers gather their candidates, sees one link per test process for
the whole session, not a bridge made and removed with every test: a browser that had paired on another worker's
bridge lost its connection when that worker's test ended (Chromium offers a candidate on each link of the root
namespace, and may send from it; caught in a page's pair list). Each process draws its block 10.<b>.0.0/16 under
a file lock, so parallel test workers never share one; its networks are 10.<b>.<n>.0/24.

A filesystem `ipc://` endpoint is reachable from every namespace (one filesystem): cross-host links in a test
must be `tcp://` to these addresses, or the test passes through the filesystem without noticing.
"""

from __future__ import annotations

import atexit
import fcntl
import itertools
import os
import shutil
import subprocess
import sys
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
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
    veth_outside: str  # its cable's end on the bridge, in the router namespace (cut/heal take it down/up)
    router: str  # the router namespace the bridge is in

    def argv(self, argv: Sequence[str]) -> list[str]:
        return ["ip", "netns", "exec", self.name, *argv]

    def popen(self, argv: Sequence[str], **kwargs: Any) -> subprocess.Popen[bytes]:
        return subprocess.Popen(self.argv(argv), **kwargs)

    def run(self, argv: Sequence[str], **kwargs: Any) -> subprocess.CompletedProcess[Any]:
        return subprocess.run(self.argv(argv), **kwargs)

    def cut(self) -> None:
        """Partition this host from every other (its link goes down; sockets stay open on both sides)."""
        _ip("-n", self.router, "link", "set", "dev", self.veth_outside, "down")

    def heal(self) -> None:
        _ip("-n", self.router, "link", "set", "dev", self.veth_outside, "up")


@dataclass
class Network:
    hosts: dict[str, Host]
    root_address: str  # the root namespace's (the test's own) address, as the hosts reach it (through the router)

    def __getitem__(self, name: str) -> Host:
        return self.hosts[name]


ROUTER_PREFIX = "ecr"  # each test process's router namespace: ecr<pid>
UPLINK_PREFIX = "ecu"  # its link in the root namespace: ecu<pid>
OWN_LINKS: set[str] = set()  # the root namespace's links this process made (its uplink)
_LOCK_FILE = Path("/tmp/eca-test-networks.lock")


@dataclass
class _Router:
    ns: str
    uplink: str
    block: int  # this process's networks are 10.<block>.<n>.0/24, n = 1..254; the uplink is 10.<block>.0.0/30
    in_use: set[int] = field(default_factory=set)

    @property
    def root_address(self) -> str:
        return f"10.{self.block}.0.1"

    def take(self) -> int:
        free = next((n for n in range(1, 255) if n not in self.in_use), None)
        if free is None:
            raise RuntimeError("254 test networks at once in one process")
        self.in_use.add(free)
        return free


_router: _Router | None = None
_router_guard = threading.Lock()


def _router_here() -> _Router:
    """This process's router namespace, made at its first network."""
    global _router
    with _router_guard:
        if _router is None:
            _router = _make_router()
        return _router


@contextmanager
def _allocation_lock() -> Iterator[None]:
    with open(_LOCK_FILE, "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        yield


def _make_router() -> _Router:
    pid = os.getpid()
    ns, uplink, inside = f"{ROUTER_PREFIX}{pid}", f"{UPLINK_PREFIX}{pid}"[:15], "uplink"
    with _allocation_lock():
        remove_stale_routers()
        block = _free_block()
        _ip("netns", "add", ns)
        try:
            _ip("link", "add", uplink, "type", "veth", "peer", "name", inside, "netns", ns)
            _ip("addr", "add", f"10.{block}.0.1/30", "dev", uplink)
            _ip("link", "set", uplink, "up")
            _ip("-n", ns, "addr", "add", f"10.{block}.0.2/30", "dev", inside)
            _ip("-n", ns, "link", "set", inside, "up")
            _ip("-n", ns, "link", "set", "lo", "up")
            _ip("route", "add", f"10.{block}.0.0/16", "via", f"10.{block}.0.2", "dev", uplink)
            forward = subprocess.run(["ip", "netns", "exec", ns, "sysctl", "-q", "-w", "net.ipv4.ip_forward=1"],
                                     capture_output=True, text=True)
            if forward.returncode != 0:
                raise RuntimeError(f"forwarding in {ns}: {forward.stderr.strip()}")
        except BaseException:
            subprocess.run(["ip", "netns", "delete", ns], capture_output=True)  # its end of the uplink goes too
            raise
    OWN_LINKS.add(uplink)
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        atexit.register(subprocess.run, ["ip", "netns", "delete", ns], capture_output=True)
    # else the controller removes it once every worker has ended (remove_stale_routers in tests/conftest.py): a
    # worker that ended first would otherwise take its link away under the other's running test
    return _Router(ns, uplink, block)


def remove_stale_routers() -> None:
    """The router namespaces of test processes that are gone (test workers, or processes killed before their exit
    handler ran)."""
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout.split()
    for name in listed:
        if name.startswith(ROUTER_PREFIX) and name[len(ROUTER_PREFIX):].isdigit():
            try:
                os.kill(int(name[len(ROUTER_PREFIX):]), 0)
            except ProcessLookupError:
                subprocess.run(["ip", "netns", "delete", name], capture_output=True)
            except PermissionError:
                pass  # alive


def _free_block() -> int:
    """A 10.<b>.0.0/16 that no address or route here uses (another test process's block among them)."""
    used = subprocess.run(["ip", "-4", "-o", "addr", "show"], capture_output=True, text=True).stdout
    used += subprocess.run(["ip", "-4", "route", "show"], capture_output=True, text=True).stdout
    for block in range(20, 250):
        if f"10.{block}." not in used:
            return block
    raise RuntimeError("no free 10.b.0.0/16 for this process's test networks")


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


def others_link_addresses() -> set[str]:
    """The addresses of the root namespace's links to other test processes' routers (another test worker's, which
    goes when that worker ends): see only_own_networks."""
    import ifaddr

    return {str(ip.ip if isinstance(ip.ip, str) else ip.ip[0]) for adapter in ifaddr.get_adapters()
            if adapter.name.startswith(UPLINK_PREFIX) and adapter.name not in OWN_LINKS for ip in adapter.ips}


def only_own_networks() -> None:
    """aioice (the WebRTC of the test process's own peers: test clients, services run in threads) offers no candidate
    on another test process's link to its networks, which goes when that process ends, under any connection whose
    pair was there. Its own link, and every other interface, it still offers. (A browser in the root namespace
    offers every link: Chromium's --force-webrtc-ip-handling-policy left them in.)"""
    import aioice.ice

    gather = aioice.ice.get_host_addresses
    if getattr(gather, "only_own_networks", False):
        return

    def host_addresses(use_ipv4: bool, use_ipv6: bool) -> list[str]:
        others = others_link_addresses()
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
    router = _router_here()
    number = router.take()
    prefix = f"10.{router.block}.{number}"
    bridge = f"br{number}"
    r = router.ns
    made_ns: list[str] = []
    made_links: list[str] = []  # in the router namespace
    links: list[subprocess.Popen[str]] = []
    try:
        _ip("-n", r, "link", "add", bridge, "type", "bridge")
        made_links.append(bridge)
        _ip("-n", r, "addr", "add", f"{prefix}.1/24", "dev", bridge)
        _ip("-n", r, "link", "set", bridge, "up")
        out: dict[str, Host] = {}
        for i, name in enumerate(names, start=2):
            ns = f"eca{tag}{name}"[:32]
            _ip("netns", "add", ns)
            made_ns.append(ns)
            outside, inside = f"eo{tag}{i}"[:15], f"ei{tag}{i}"[:15]
            if name not in delays:
                _ip("-n", r, "link", "add", outside, "type", "veth", "peer", "name", inside, "netns", ns)
            else:
                # two cables through a namespace of their own: outside <-> b | delay link | a <-> inside; the outside
                # end is on the bridge as for any host, so cut() still works
                link_ns = f"eca{tag}{name}"[:30] + "dl"
                _ip("netns", "add", link_ns)
                made_ns.append(link_ns)
                a, b = f"ea{tag}{i}"[:15], f"eb{tag}{i}"[:15]
                _ip("-n", r, "link", "add", outside, "type", "veth", "peer", "name", b, "netns", link_ns)
                _ip("-n", link_ns, "link", "add", a, "type", "veth", "peer", "name", inside, "netns", ns)
                for end in (a, b):
                    _ip("-n", link_ns, "link", "set", end, "up")
                    _no_offloads(link_ns, end)
                _no_offloads(r, outside)
                links.append(_delay_link(link_ns, a, b, delays[name]))
            made_links.append(outside)
            _ip("-n", r, "link", "set", outside, "master", bridge)
            _ip("-n", r, "link", "set", outside, "up")
            _ip("-n", ns, "addr", "add", f"{prefix}.{i}/24", "dev", inside)
            _ip("-n", ns, "link", "set", inside, "up")
            # back to the test (and this process's other networks) through the router; no default route: nothing
            # in a host reaches past this machine's test networks
            _ip("-n", ns, "route", "add", f"10.{router.block}.0.0/16", "via", f"{prefix}.1")
            if name in delays:
                _no_offloads(ns, inside)
            _ip("-n", ns, "link", "set", "lo", "up")
            out[name] = Host(ns, f"{prefix}.{i}", outside, r)
        yield Network(out, router.root_address)
    finally:
        for proc in links:
            proc.kill()
            proc.communicate()
        for link in reversed(made_links):
            subprocess.run(["ip", "-n", r, "link", "delete", link], capture_output=True)
        for ns in made_ns:
            subprocess.run(["ip", "netns", "delete", ns], capture_output=True)
        router.in_use.discard(number)
