"""The service's own WebRTC peers under the [web.ice] settings (web/ice.py): their STUN/TURN servers and transport
policy (an aiortc RTCConfiguration), and the host addresses they offer.

aiortc has no setting for the host addresses: aioice gathers on every interface it finds (ifaddr). So aioice's
`get_host_addresses` is wrapped once per process, and the wrapper keeps only the addresses of the interfaces named
for the connection being answered, which `gathering` puts in a context variable: each viewer's answer is a task of
its own, so services with different settings in one process (tests run them in threads) do not mix.
"""

from __future__ import annotations

import contextvars
import ipaddress
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import aioice.ice
import ifaddr
from aiortc import RTCConfiguration, RTCIceServer, RTCIceTransportPolicy

from eca.services.processes.web.ice import IceSettings

_INTERFACES: contextvars.ContextVar[tuple[str, ...]] = contextvars.ContextVar("eca_ice_interfaces", default=())


def configuration(settings: IceSettings) -> RTCConfiguration:
    """One peer's configuration: never None, which would have aiortc ask Google's public STUN server."""
    return RTCConfiguration(
        iceServers=[RTCIceServer(urls=url, username=username, credential=credential)
                    for url, username, credential in settings.for_peer()],
        iceTransportPolicy=RTCIceTransportPolicy(settings.transport_policy))


def addresses_of(interfaces: tuple[str, ...]) -> dict[str, list[str]]:
    """Each named interface's or address's addresses on this host now (an empty list: not here). IPv6 link-local
    addresses are left out, as aioice leaves them out."""
    found: dict[str, list[str]] = {name: [] for name in interfaces}
    for adapter in ifaddr.get_adapters():
        for ip in adapter.ips:
            if isinstance(ip.ip, str):
                address = ip.ip
            elif ip.ip[2] == 0:  # (address, flowinfo, scope id): a scope id marks a link-local address
                address = ip.ip[0]
            else:
                continue
            for name in interfaces:
                if name == adapter.nice_name or name == adapter.name or _same_address(name, address):
                    found[name].append(address)
    return found


def _same_address(name: str, address: str) -> bool:
    try:
        return ipaddress.ip_address(name) == ipaddress.ip_address(address)
    except ValueError:
        return False


def check_interfaces(settings: IceSettings) -> list[str]:
    """The named interfaces and addresses this host does not have (a warning each). ValueError, naming what the host
    has, when it has none of them: the service could offer no host candidate at all."""
    if not settings.interfaces:
        return []
    found = addresses_of(settings.interfaces)
    missing = [name for name, addresses in found.items() if not addresses]
    if len(missing) == len(found):
        here = sorted({a.nice_name for a in ifaddr.get_adapters()})
        raise ValueError(f"[web.ice] interfaces: none of {', '.join(settings.interfaces)} is on this host (it has "
                         f"{', '.join(here)}); WebRTC peers would have no address to offer")
    return missing


@contextmanager
def gathering(settings: IceSettings) -> Iterator[None]:
    """Within it (in the task that answers an offer, and the tasks it starts), aioice gathers host candidates only
    on `settings.interfaces` (all when empty)."""
    _wrap_aioice()
    token = _INTERFACES.set(settings.interfaces)
    try:
        yield
    finally:
        _INTERFACES.reset(token)


def _wrap_aioice() -> None:
    original: Any = aioice.ice.get_host_addresses
    if getattr(original, "eca_restricted", False):
        return

    def get_host_addresses(use_ipv4: bool, use_ipv6: bool) -> list[str]:
        addresses: list[str] = original(use_ipv4, use_ipv6)
        interfaces = _INTERFACES.get()
        if not interfaces:
            return addresses
        allowed = {a for found in addresses_of(interfaces).values() for a in found}
        return [a for a in addresses if a in allowed]

    get_host_addresses.eca_restricted = True  # type: ignore[attr-defined]
    aioice.ice.get_host_addresses = get_host_addresses
