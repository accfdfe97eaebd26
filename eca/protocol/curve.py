"""CURVE keys for a bus that leaves this machine (docs/protocol.md §15).

ZeroMQ's CURVE mechanism encrypts every connection and authenticates both ends by their long-term key
pairs: the broker proves it holds the secret key whose public half its clients were given, and each
client proves it holds its own; the broker's ZAP handler (services/processes/broker.py) admits only
the client public keys it allows. Keys are zmq.auth certificate files: `NAME.key` holds the public key,
`NAME.key_secret` the pair, in Z85 (40 characters for 32 bytes). A secret file readable by anyone but its
owner is refused: a key others could copy authenticates nobody.
"""

from __future__ import annotations

import os
import stat
from dataclasses import dataclass, field
from pathlib import Path

import zmq

PUBLIC_SUFFIX = ".key"
SECRET_SUFFIX = ".key_secret"
_Z85_LEN = 40  # 32 bytes of key, Z85-encoded


class CurveKeyError(ValueError):
    """A key file or folder is missing, unreadable, malformed or too open; the message names it."""


@dataclass(frozen=True)
class CurveKeys:
    """The keys of one host's processes: every socket onto the bus uses them."""

    server_public: bytes  # Z85: the broker's public key (every client pins it)
    client_public: bytes  # Z85: this host's own pair, with which every process here connects
    client_secret: bytes = field(repr=False)
    server_secret: bytes | None = field(default=None, repr=False)  # on the broker's host only
    allowed_dir: Path | None = None  # the broker's: public key files of the clients it lets in
    server_key_file: Path = Path()
    client_key_file: Path = Path()


def _z85(value: bytes | None, path: Path, what: str) -> bytes | None:
    if value is None:
        return None
    if len(value) != _Z85_LEN:
        raise CurveKeyError(f"{path}: the {what} is {len(value)} characters; a CURVE key is {_Z85_LEN} (Z85)")
    try:
        raw = zmq.utils.z85.decode(value)
    except (ValueError, KeyError, IndexError):
        raise CurveKeyError(f"{path}: the {what} is not Z85 text") from None
    if len(raw) != 32:
        raise CurveKeyError(f"{path}: the {what} does not decode to 32 bytes")
    return value


def load_key_file(path: Path, need_secret: bool) -> tuple[bytes, bytes | None]:
    """(public, secret or None) from a zmq.auth certificate file, checked. `need_secret`: the file must hold
    the secret key too, and nobody but its owner may read it."""
    import zmq.auth  # loaded only where CURVE is used

    try:
        info = path.stat()
    except FileNotFoundError:
        raise CurveKeyError(f"{path}: no such key file") from None
    except OSError as exc:
        raise CurveKeyError(f"{path}: cannot read the key file: {exc.strerror}") from None
    if not stat.S_ISREG(info.st_mode):
        raise CurveKeyError(f"{path}: not a regular file")
    try:
        public, secret = zmq.auth.load_certificate(path)
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise CurveKeyError(f"{path}: not a CURVE key file ({exc}); make one with `eca keys new NAME`") from None
    public_z85 = _z85(public, path, "public key")
    secret_z85 = _z85(secret, path, "secret key")
    assert public_z85 is not None
    if secret_z85 is not None:
        check_secret_mode(path, info)
        if zmq.curve_public(secret_z85) != public_z85:
            raise CurveKeyError(f"{path}: its public key is not the one of its secret key")
    elif need_secret:
        raise CurveKeyError(f"{path}: holds no secret key; give the `{SECRET_SUFFIX}` file of the pair")
    return public_z85, secret_z85


def check_secret_mode(path: Path, info: os.stat_result | None = None) -> None:
    info = info or path.stat()
    mode = stat.S_IMODE(info.st_mode)
    if mode & 0o077:
        raise CurveKeyError(f"{path}: a secret key readable by others (mode {mode:04o}) is refused; "
                            f"chmod 600 {path}")
    if info.st_uid != os.getuid():
        raise CurveKeyError(f"{path}: the secret key file belongs to another user (uid {info.st_uid})")


def load_allowed(directory: Path) -> dict[bytes, str]:
    """The allowed client public keys (Z85) in `directory`'s `*.key` files, each with its file's name."""
    if not directory.is_dir():
        raise CurveKeyError(f"{directory}: the allowed-clients folder does not exist (or is not a folder)")
    allowed: dict[bytes, str] = {}
    for path in sorted(directory.glob(f"*{PUBLIC_SUFFIX}")):
        public, _ = load_key_file(path, need_secret=False)
        allowed[public] = path.stem
    return allowed


def load_keys(server_key: Path, client_key: Path, allowed_dir: Path | None) -> CurveKeys:
    server_public, server_secret = load_key_file(server_key, need_secret=False)
    client_public, client_secret = load_key_file(client_key, need_secret=True)
    assert client_secret is not None
    if allowed_dir is not None:
        load_allowed(allowed_dir)  # every file in it is checked at start, not at the first handshake
    return CurveKeys(server_public=server_public, client_public=client_public, client_secret=client_secret,
                     server_secret=server_secret, allowed_dir=allowed_dir, server_key_file=server_key,
                     client_key_file=client_key)


def client_options(sock: zmq.Socket[bytes], keys: CurveKeys) -> None:
    """Make `sock` a CURVE client of the broker (before connect: options set later do not take)."""
    sock.setsockopt(zmq.CURVE_SERVERKEY, keys.server_public)
    sock.setsockopt(zmq.CURVE_PUBLICKEY, keys.client_public)
    sock.setsockopt(zmq.CURVE_SECRETKEY, keys.client_secret)


def server_options(sock: zmq.Socket[bytes], keys: CurveKeys) -> None:
    """Make `sock` a CURVE server (before bind)."""
    if keys.server_secret is None:
        raise CurveKeyError(f"{keys.server_key_file}: holds no secret key, and the broker needs it: give the "
                            f"server's `{SECRET_SUFFIX}` file as curve_server_key on the broker's host")
    sock.setsockopt(zmq.CURVE_SERVER, 1)
    sock.setsockopt(zmq.CURVE_PUBLICKEY, keys.server_public)
    sock.setsockopt(zmq.CURVE_SECRETKEY, keys.server_secret)


def link_options(sock: zmq.Socket[bytes], interval_s: float, timeout_s: float) -> None:
    """ZMTP heartbeats on a link that may cross a network (before connect or bind): a peer that stays silent
    for `timeout_s` is taken for gone and its connection dropped (what a cable pulled for minutes would
    otherwise leave half-open), and a connect that hangs on an unreachable host is retried within a second
    instead of waiting out TCP's SYN back-off, so a healed link reconnects at once."""
    sock.setsockopt(zmq.HEARTBEAT_IVL, max(1, int(interval_s * 1000)))
    sock.setsockopt(zmq.HEARTBEAT_TIMEOUT, max(1, int(timeout_s * 1000)))
    sock.setsockopt(zmq.HEARTBEAT_TTL, max(100, int(timeout_s * 1000)))
    sock.setsockopt(zmq.CONNECT_TIMEOUT, 1000)
