"""How the web service's WebRTC peers and its pages find a way to each other: the [web.ice] settings.

- `servers`: STUN and TURN servers ("stun:host:port", "turn:host:port?transport=udp|tcp", "turns:host:port"). The
  pages get all of them (from /config, with credentials); the service's own peers (aiortc) use the first STUN and
  the first TURN server (aioice takes one of each). None by default: the service offers its host addresses only,
  and asks no outside server anything (aiortc on its own asks Google's public STUN server at every connection).
- TURN credentials: `username` and `credential` (or `credential_file`), the same for every page; or
  `secret_file`, the secret a TURN server shares for time-limited credentials (coturn's `use-auth-secret` /
  `static-auth-secret`, the "TURN REST API" scheme): each page and each connection gets a username of its expiry
  time and a password that is that username's HMAC-SHA1 under the secret, valid for `credential_ttl_s`.
- `transport_policy`: "all", or "relay" (the service's own media only through the TURN server).
- `interfaces`: the interface names or addresses whose host candidates the service offers (empty: all). A host
  with container bridges or VPN links otherwise offers a candidate on each, and the page may pick one that goes
  away under it.
"""

from __future__ import annotations

import base64
import ipaddress
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

MAX_SERVERS = 8
MAX_URL_CHARS = 512
MAX_CREDENTIAL_CHARS = 512
MAX_INTERFACES = 32
POLICIES = ("all", "relay")
# RFC 7064/7065 URIs as browsers take them: a host name, an IPv4 address or a bracketed IPv6 one, an optional port,
# and for TURN an optional transport
_HOST = r"(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9]([A-Za-z0-9.-]{0,251}[A-Za-z0-9])?)"
SERVER_URL = re.compile(rf"(?P<scheme>stun|turns?):{_HOST}(:(?P<port>[0-9]{{1,5}}))?"
                        r"(\?transport=(?P<transport>udp|tcp))?")
INTERFACE_NAME = re.compile(r"[A-Za-z0-9_.:@-]{1,15}")  # what Linux allows in an interface's name (IFNAMSIZ - 1)


class IceSettingsError(ValueError):
    """A [web.ice] setting that cannot be: the message names it."""


@dataclass(frozen=True)
class IceServer:
    """One STUN or TURN server as the settings name it (parse_server has checked its URL)."""

    url: str
    scheme: str  # stun, turn or turns

    @property
    def turn(self) -> bool:
        return self.scheme != "stun"


def parse_server(url: Any, where: str) -> IceServer:
    if not isinstance(url, str) or not 0 < len(url) <= MAX_URL_CHARS:
        raise IceSettingsError(f"{where}: a server is a URL of 1-{MAX_URL_CHARS} characters (stun:host:port or "
                               f"turn:host:port), got {str(url)[:80]!r}")
    match = SERVER_URL.fullmatch(url)
    if match is None:
        raise IceSettingsError(f"{where}: {url[:80]!r} is not a STUN or TURN server's URL (stun:host[:port], "
                               "turn:host[:port][?transport=udp|tcp] or turns:host[:port])")
    scheme, port = match["scheme"], match["port"]
    if port and not 0 < int(port) < 65536:
        raise IceSettingsError(f"{where}: {url!r}: the port must lie in 1..65535")
    transport = match["transport"]
    if scheme == "stun" and transport:
        raise IceSettingsError(f"{where}: {url!r}: a STUN server's URL has no transport")
    if scheme == "turns" and transport == "udp":
        raise IceSettingsError(f"{where}: {url!r}: TURN over TLS runs over TCP (turns:...?transport=tcp)")
    return IceServer(url, scheme)


def turn_rest_credential(secret: bytes, expires_unix_s: int, user: str = "eca") -> tuple[str, str]:
    """A time-limited TURN credential as coturn's use-auth-secret checks it: the username is the expiry time (Unix
    seconds) and a name, the password base64(HMAC-SHA1(secret, username))."""
    import hashlib  # here, not at the top: the supervisor reads these settings too, and need not load OpenSSL
    import hmac

    username = f"{expires_unix_s}:{user}"
    password = base64.b64encode(hmac.new(secret, username.encode(), hashlib.sha1).digest()).decode()
    return username, password


@dataclass(frozen=True)
class IceSettings:
    servers: tuple[IceServer, ...] = ()
    username: str | None = None  # TURN: the same credential for every page and connection...
    credential: str | None = field(default=None, repr=False)
    secret: bytes | None = field(default=None, repr=False)  # ...or one minted from this secret for each
    credential_ttl_s: float = 86_400.0
    transport_policy: str = "all"
    interfaces: tuple[str, ...] = ()
    wall_clock: Callable[[], float] = field(default=time.time, repr=False, compare=False)

    def check(self, where: str = "[web.ice]") -> IceSettings:
        if len(self.servers) > MAX_SERVERS:
            raise IceSettingsError(f"{where}: at most {MAX_SERVERS} servers, got {len(self.servers)}")
        turn = [s for s in self.servers if s.turn]
        if turn and self.secret is None and (self.username is None or self.credential is None):
            raise IceSettingsError(f"{where}: a TURN server needs credentials: username and credential (or "
                                   "credential_file), or secret_file for time-limited ones")
        if self.secret is not None and (self.username is not None or self.credential is not None):
            raise IceSettingsError(f"{where}: secret_file mints each credential; leave username and credential out")
        if (self.username is not None or self.credential is not None or self.secret is not None) and not turn:
            raise IceSettingsError(f"{where}: TURN credentials are given but no TURN server (turn:host:port)")
        for name in ("username", "credential"):
            value = getattr(self, name)
            if value is not None and not (isinstance(value, str) and 0 < len(value) <= MAX_CREDENTIAL_CHARS
                                          and value.isprintable()):
                raise IceSettingsError(f"{where}: {name} must be 1-{MAX_CREDENTIAL_CHARS} printable characters")
        if not (isinstance(self.credential_ttl_s, (int, float)) and not isinstance(self.credential_ttl_s, bool)
                and 60 <= self.credential_ttl_s <= 7 * 86_400):
            raise IceSettingsError(f"{where}: credential_ttl_s must lie in [60, 604800] s, got "
                                   f"{self.credential_ttl_s!r}")
        if self.transport_policy not in POLICIES:
            raise IceSettingsError(f"{where}: transport_policy must be one of {', '.join(POLICIES)}, got "
                                   f"{self.transport_policy!r}")
        if self.transport_policy == "relay" and not turn:
            raise IceSettingsError(f"{where}: transport_policy \"relay\" sends everything through a TURN server; "
                                   "name one in servers")
        if len(self.interfaces) > MAX_INTERFACES:
            raise IceSettingsError(f"{where}: at most {MAX_INTERFACES} interfaces, got {len(self.interfaces)}")
        for name in self.interfaces:
            if not isinstance(name, str) or not (INTERFACE_NAME.fullmatch(name) or _is_address(name)):
                raise IceSettingsError(f"{where}: interfaces holds names of network interfaces (eth0) or their "
                                       f"addresses (192.0.2.7), got {str(name)[:80]!r}")
            if _is_address(name) and ipaddress.ip_address(name).is_loopback:
                raise IceSettingsError(f"{where}: {name} is a loopback address; neither aiortc nor browsers offer "
                                       "candidates there")
        return self

    def credentials(self) -> tuple[str, str] | tuple[None, None]:
        """The TURN username and password for one page or connection (minted now when from a secret)."""
        if self.secret is not None:
            return turn_rest_credential(self.secret, int(self.wall_clock() + self.credential_ttl_s))
        if self.username is not None and self.credential is not None:
            return self.username, self.credential
        return None, None

    def for_page(self) -> list[dict[str, Any]]:
        """The servers as a page's RTCPeerConnection takes them (its `iceServers`), credentials minted now."""
        username, credential = self.credentials()
        page: list[dict[str, Any]] = []
        for server in self.servers:
            entry: dict[str, Any] = {"urls": server.url}
            if server.turn:
                entry |= {"username": username, "credential": credential}
            page.append(entry)
        return page

    def for_peer(self) -> list[tuple[str, str | None, str | None]]:
        """The first STUN and the first TURN server (what aioice can use) as (url, username, credential), for one of
        the service's own peers."""
        username, credential = self.credentials()
        chosen: list[tuple[str, str | None, str | None]] = []
        stun = next((s for s in self.servers if not s.turn), None)
        turn = next((s for s in self.servers if s.turn), None)
        if stun is not None:
            chosen.append((stun.url, None, None))
        if turn is not None:
            chosen.append((turn.url, username, credential))
        return chosen


def _is_address(text: str) -> bool:
    try:
        ipaddress.ip_address(text)
    except ValueError:
        return False
    return True


def ice_from_table(table: Any, where: str = "[web.ice]") -> IceSettings:
    """Settings from a config's [web.ice] table; unknown keys, wrong types and unreadable files are errors naming
    them. Checked."""
    if not isinstance(table, dict):
        raise IceSettingsError(f"{where} must be a table")
    known = {f.name for f in fields(IceSettings)} - {"secret", "wall_clock"} | {"credential_file", "secret_file"}
    unknown = sorted(set(table) - known)
    if unknown:
        raise IceSettingsError(f"{where}: unknown key {unknown[0]!r}; known: {', '.join(sorted(known))}")
    if "credential" in table and "credential_file" in table:
        raise IceSettingsError(f"{where}: give credential or credential_file, not both")
    values: dict[str, Any] = {}
    for key, value in table.items():
        if key == "servers":
            if not isinstance(value, list) or len(value) > MAX_SERVERS:
                raise IceSettingsError(f"{where}: servers must be a list of at most {MAX_SERVERS} URLs")
            values["servers"] = tuple(parse_server(url, f"{where} servers") for url in value)
        elif key == "interfaces":
            if not isinstance(value, list) or len(value) > MAX_INTERFACES:
                raise IceSettingsError(f"{where}: interfaces must be a list of at most {MAX_INTERFACES} names")
            values["interfaces"] = tuple(value)
        elif key == "credential_file":
            values["credential"] = _read_secret(value, f"{where} credential_file").decode()
        elif key == "secret_file":
            values["secret"] = _read_secret(value, f"{where} secret_file")
        else:
            values[key] = value
    return IceSettings(**values).check(where)


def _read_secret(path: Any, where: str) -> bytes:
    if not isinstance(path, str) or not path:
        raise IceSettingsError(f"{where} must be a file's path")
    try:
        with open(Path(path), "rb") as file:
            data = file.read(MAX_CREDENTIAL_CHARS + 2)
    except OSError as exc:
        raise IceSettingsError(f"{where}: cannot read {path}: {exc.strerror}") from None
    text = data.strip()
    if not text or len(text) > MAX_CREDENTIAL_CHARS:
        raise IceSettingsError(f"{where}: {path} must hold 1-{MAX_CREDENTIAL_CHARS} bytes (one line)")
    try:
        if not text.decode("utf-8").isprintable():
            raise UnicodeDecodeError("utf-8", text, 0, 1, "not printable")
    except UnicodeDecodeError:
        raise IceSettingsError(f"{where}: {path} must hold printable UTF-8 text") from None
    return text
