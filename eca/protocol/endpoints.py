"""Where the bus is: endpoints and limits from the runtime config (configs/default.toml)."""

from __future__ import annotations

import ipaddress
import os
import re
import stat
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from eca import shipped_configs
from eca.protocol.curve import CurveKeyError, CurveKeys, load_keys

_AGENT_ID = re.compile(r"[A-Za-z0-9_-]{1,32}")  # as the codec's agent ids (protocol/codec.py)

DEFAULT_CONFIG = shipped_configs() / "default.toml"
_MAX_IPC_PATH = 107  # sun_path limit on Linux


class BusConfigError(ValueError):
    """The runtime config is wrong; the message names the file and the key."""


@dataclass(frozen=True)
class BusConfig:
    frontend: str  # the broker's XSUB binds here; publishers connect
    backend: str  # the broker's XPUB binds here; subscribers connect
    instance: str
    runtime_dir: Path  # private to the instance (mode 0700), for either transport
    hwm: int
    max_message_bytes: int
    heartbeat_interval_s: float
    heartbeat_timeout_s: float
    connect_timeout_s: float  # how long a process with no supervisor waits for the broker
    config_path: Path
    raw: dict[str, Any]  # the whole file, for service-specific tables
    agents: tuple[str, ...] = ("ada",)  # [agents] ids: the agents this instance animates, in seat order
    curve: CurveKeys | None = None  # CURVE keys: every socket onto the bus encrypts and authenticates (§15)

    @property
    def remote_link(self) -> bool:
        """Whether the bus runs over TCP, where a link can drop for a while and heal (ZMTP heartbeats on)."""
        return self.frontend.startswith("tcp://")


def load_config_file(path: str | Path | None = None) -> tuple[Path, dict[str, Any]]:
    config_path = Path(path) if path else Path(os.environ.get("ECA_CONFIG", DEFAULT_CONFIG))
    try:
        with open(config_path, "rb") as fh:
            return config_path, tomllib.load(fh)
    except FileNotFoundError:
        raise BusConfigError(f"{config_path}: config file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise BusConfigError(f"{config_path}: {exc}") from None


def load_bus_config(path: str | Path | None = None, instance: str | None = None,
                    create_dir: bool = True) -> BusConfig:
    config_path, raw = load_config_file(path)
    bus = _table(raw, "bus", config_path)
    beat = _table(raw, "heartbeat", config_path)
    where = f"{config_path} [bus]"
    instance = instance or os.environ.get("ECA_INSTANCE") or _get(bus, "instance", str, where)
    if not instance.replace("-", "").replace("_", "").isalnum() or len(instance) > 40:
        raise BusConfigError(f"{where}: instance {instance!r} must be 1-40 letters, digits, '-' or '_'")
    transport = _get(bus, "transport", str, where)
    curve = _curve(bus, config_path, where)
    # Every instance has its private directory, whatever the transport: the broker's lock, the
    # supervisor's liveness socket and the dialogue service's state snapshot live there.
    runtime_dir = Path(_get(bus, "runtime_dir", str, where) or default_runtime_root()) / instance
    if create_dir:
        make_private_dir(runtime_dir)
    if transport == "ipc":
        frontend, backend = f"ipc://{runtime_dir}/pub", f"ipc://{runtime_dir}/sub"
        if len(backend) - len("ipc://") > _MAX_IPC_PATH:
            raise BusConfigError(f"{where}: runtime directory path {runtime_dir} is too long for ipc")
    elif transport == "tcp":
        host = _get(bus, "tcp_host", str, where)
        if not is_loopback(host) and not _get(bus, "allow_remote", bool, where):
            raise BusConfigError(f"{where}: tcp_host {host!r} is not loopback; set allow_remote = true to "
                                 "expose the bus beyond this machine")
        if not is_loopback(host) and curve is None:
            # no plaintext bus off this machine: anyone on the network could read and drive the agents
            raise BusConfigError(f"{where}: tcp_host {host!r} is not loopback and no CURVE keys are set: the bus "
                                 "leaves this machine only encrypted; set curve_server_key and curve_client_key "
                                 "(`eca keys new NAME`, docs/protocol.md §15)")
        front_port = _get(bus, "tcp_frontend_port", int, where)
        back_port = _get(bus, "tcp_backend_port", int, where)
        frontend, backend = f"tcp://{host}:{front_port}", f"tcp://{host}:{back_port}"
    else:
        raise BusConfigError(f"{where}: transport must be 'ipc' or 'tcp', got {transport!r}")
    interval = _get(beat, "interval_s", float, f"{config_path} [heartbeat]")
    timeout = _get(beat, "timeout_s", float, f"{config_path} [heartbeat]")
    if not 0 < interval <= 0.5:
        raise BusConfigError(f"{config_path} [heartbeat]: interval_s must be in (0, 0.5] (2 Hz or more)")
    if timeout <= interval:
        raise BusConfigError(f"{config_path} [heartbeat]: timeout_s must exceed interval_s")
    connect_timeout = _get(bus, "connect_timeout_s", float, where) if "connect_timeout_s" in bus else 10.0
    if not 0 < connect_timeout <= 3600:
        raise BusConfigError(f"{where}: connect_timeout_s must be in (0, 3600], got {connect_timeout}")
    return BusConfig(frontend=frontend, backend=backend, instance=instance, runtime_dir=runtime_dir,
                     hwm=_get(bus, "hwm", int, where),
                     max_message_bytes=_get(bus, "max_message_bytes", int, where),
                     heartbeat_interval_s=interval, heartbeat_timeout_s=timeout,
                     connect_timeout_s=connect_timeout, config_path=config_path,
                     raw=raw, agents=_agents(raw, config_path), curve=curve)


CURVE_KEYS = ("curve_server_key", "curve_client_key", "curve_allowed_dir")


def _curve(bus: dict[str, Any], path: Path, where: str) -> CurveKeys | None:
    """The [bus] CURVE keys, loaded and checked (None when none is set). Relative paths are the config file's
    neighbours, so a folder of config and keys can be copied to another host as it is."""
    given: dict[str, Path | None] = {}
    for key in CURVE_KEYS:
        value = bus.get(key, "")
        if not isinstance(value, str):
            raise BusConfigError(f"{where}: '{key}' must be a path (a string), got {value!r}"[:300])
        given[key] = (path.parent / Path(value).expanduser()) if value.strip() else None
    server, client, allowed = (given[k] for k in CURVE_KEYS)
    if server is None and client is None:
        if allowed is not None:
            raise BusConfigError(f"{where}: curve_allowed_dir is set but curve_server_key is not: the allow-list "
                                 "is the broker's, and needs the server's key pair")
        return None
    if server is None or client is None:
        missing = "curve_server_key" if server is None else "curve_client_key"
        raise BusConfigError(f"{where}: CURVE needs both curve_server_key and curve_client_key; '{missing}' is "
                             "not set")
    try:
        return load_keys(server, client, allowed)
    except CurveKeyError as exc:
        raise BusConfigError(f"{where}: {exc}") from None


MAX_AGENTS = 64  # one instance's faces; far more than share a screen


def _agents(raw: dict[str, Any], path: Path) -> tuple[str, ...]:
    """[agents] ids, checked: distinct agent ids (1-32 letters, digits, '_' or '-'), not 'user'."""
    where = f"{path} [agents]"
    table = raw.get("agents", {"ids": ["ada"]})
    if not isinstance(table, dict):
        raise BusConfigError(f"{path}: 'agents' must be a table")
    ids = _get(table, "ids", list, where)
    bad = [a for a in ids if not (isinstance(a, str) and _AGENT_ID.fullmatch(a)) or a == "user"]
    if not ids or len(ids) > MAX_AGENTS or bad or len(set(ids)) != len(ids):
        raise BusConfigError(f"{where}: 'ids' must list 1 to {MAX_AGENTS} distinct agent ids (letters, digits, "
                             f"'_' or '-', at most 32; not 'user'), got {ids!r}"[:400])
    return tuple(ids)


def default_runtime_root() -> Path:
    xdg = os.environ.get("XDG_RUNTIME_DIR")
    return Path(xdg) / "eca" if xdg else Path(f"/tmp/eca-{os.getuid()}")


def make_private_dir(path: Path) -> None:
    """Create `path` (and its eca parent) with mode 0700 and refuse one that others can reach."""
    for part in (path.parent, path):
        part.mkdir(mode=0o700, exist_ok=True)
        info = part.stat()
        if info.st_uid != os.getuid():
            raise BusConfigError(f"runtime directory {part} belongs to another user")
        if stat.S_IMODE(info.st_mode) & 0o077:
            os.chmod(part, 0o700)


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def _table(raw: dict[str, Any], name: str, path: Path) -> dict[str, Any]:
    table = raw.get(name)
    if not isinstance(table, dict):
        raise BusConfigError(f"{path}: missing table [{name}]")
    return table


def _get(table: dict[str, Any], key: str, kind: type, where: str) -> Any:
    if key not in table:
        raise BusConfigError(f"{where}: missing key '{key}'")
    value = table[key]
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if not isinstance(value, kind) or (kind is not bool and isinstance(value, bool)):
        raise BusConfigError(f"{where}: '{key}' must be {kind.__name__}, got {value!r}")
    return value
