"""HAProxy in front of several eca hosts, for the tests and benches: the shipped sample configuration
(eca/configs/haproxy.cfg) rendered for given hosts, run as a real `haproxy -db` process, and eca hosts to put
behind it.

`balancer([("h1", "127.0.0.1:8081"), ...])` renders the config into a private folder, starts HAProxy on a free
port, waits until it accepts connections and every host's state has settled, and stops it afterwards; its
`states()` read each host's state (UP, NOLB, DOWN) from HAProxy's runtime API. `eca_hosts([...])` runs
`eca up --web --per-visitor` hosts on private buses and yields their addresses. `balancer` skips (pytest) when
HAProxy is not installed: `haproxy_available()` says why.
"""

from __future__ import annotations

import csv
import io
import ipaddress
import re
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path

from eca import shipped_configs
from eca.protocol.endpoints import BusConfig
from eca.services.tools.child_processes import LineReader, eca_command
from tests.support.bus import private_bus_config, running
from tests.support.netns import Host

TEMPLATE = shipped_configs() / "haproxy.cfg"
PLACEHOLDERS = ("bind", "stats_socket", "check_inter", "servers", "tracked_servers")
_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_-]{0,31}")
_HOSTNAME = re.compile(r"[A-Za-z0-9]([A-Za-z0-9.-]{0,251}[A-Za-z0-9])?")
START_TIMEOUT_S = 15.0
MAX_SOCKET_PATH = 100  # a unix socket's path must fit sun_path (108 bytes)


class ConfigError(ValueError):
    """A value that cannot go into the configuration: the message names it."""


def haproxy_available() -> str | None:
    """None when HAProxy can run here; otherwise why not (a skip reason)."""
    if shutil.which("haproxy") is None:
        return "haproxy is not installed (Debian: apt-get install haproxy; .ci/setup installs it)"
    return None


def check_address(value: str, what: str) -> str:
    """`host:port` with an IPv4 address, a bracketed IPv6 one or a host name, and a port in 1..65535."""
    match = re.fullmatch(r"(\[[0-9A-Fa-f:.]+\]|[^\s:\[\]]+):(\d{1,5})", value) if isinstance(value, str) else None
    if match is None:
        raise ConfigError(f"{what} must be host:port (an IPv6 address in brackets), got {value!r}")
    host, port = match.group(1), int(match.group(2))
    if not 1 <= port <= 65535:
        raise ConfigError(f"{what}: the port must lie in 1..65535, got {port}")
    if host.startswith("["):
        try:
            ipaddress.IPv6Address(host[1:-1])
        except ValueError:
            raise ConfigError(f"{what}: {host} is not an IPv6 address") from None
    elif not _HOSTNAME.fullmatch(host):
        raise ConfigError(f"{what}: {host!r} is not an address or host name")
    return value


def render_config(servers: Sequence[tuple[str, str]], bind: str, stats_socket: Path, check_inter_ms: int = 1000,
                  template: Path = TEMPLATE) -> str:
    """The shipped template with its placeholders filled, each value checked first (ConfigError naming it): so
    nothing but a server line can be added where a server goes."""
    if not servers:
        raise ConfigError("at least one eca host is needed")
    names = [name for name, _ in servers]
    for name, address in servers:
        if not isinstance(name, str) or not _NAME.fullmatch(name):
            raise ConfigError(f"server name {name!r}: a letter, then up to 31 letters, digits, '_' or '-'")
        check_address(address, f"server {name}")
    if len(set(names)) != len(names):
        raise ConfigError(f"server names must differ: {names}")
    check_address(bind, "bind")
    socket_path = str(stats_socket)
    if not stats_socket.is_absolute() or len(socket_path) > MAX_SOCKET_PATH or re.search(r"\s", socket_path):
        raise ConfigError(f"stats_socket must be an absolute path without spaces, at most {MAX_SOCKET_PATH} "
                          f"characters: {socket_path!r}")
    if isinstance(check_inter_ms, bool) or not isinstance(check_inter_ms, int) or not 100 <= check_inter_ms <= 60_000:
        raise ConfigError(f"check_inter_ms must be a whole number in 100..60000, got {check_inter_ms!r}")
    values = {
        "bind": bind,
        "stats_socket": socket_path,
        "check_inter": f"{check_inter_ms}ms",
        "servers": "\n".join(f"    server {name} {address} cookie {name}" for name, address in servers),
        "tracked_servers": "\n".join(f"    server {name} {address} cookie {name} track eca/{name}"
                                     for name, address in servers),
    }
    text = template.read_text()
    for key in PLACEHOLDERS:
        if text.count("{{" + key + "}}") < 1:
            raise ConfigError(f"{template} has no {{{{{key}}}}} placeholder")
    out = []
    for line in text.splitlines():
        # the placeholders' explanations in the template's comments stay as they are
        if not line.lstrip().startswith("#"):
            for key, value in values.items():
                line = line.replace("{{" + key + "}}", value)
        out.append(line)
    rendered = "\n".join(out) + "\n"
    left = [line for line in rendered.splitlines() if "{{" in line and not line.lstrip().startswith("#")]
    if left:
        raise ConfigError(f"{template} has placeholders this renderer does not know: {left}")
    return rendered


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as probe:
        probe.bind((host, 0))
        return int(probe.getsockname()[1])


def free_ports(count: int, host: str = "127.0.0.1") -> int:
    """A port P such that P .. P + count - 1 are all free now (web workers listen on consecutive ports)."""
    for _ in range(100):
        base = free_port(host)
        held: list[socket.socket] = []
        try:
            for port in range(base, base + count):
                held.append(socket.socket())
                held[-1].bind((host, port))
            return base
        except OSError:
            continue  # one of them is taken (or past 65535): another base
        finally:
            for sock in held:
                sock.close()
    raise RuntimeError(f"no {count} consecutive free ports on {host}")


@dataclass
class Balancer:
    """A running HAProxy: where visitors connect, its config and log, and its runtime API."""

    url: str
    config_path: Path
    stats_socket: Path
    log: LineReader
    process: subprocess.Popen[bytes]

    def command(self, line: str) -> str:
        """One command on HAProxy's runtime API (management.txt, 9.3), its answer."""
        with socket.socket(socket.AF_UNIX) as api:
            api.settimeout(5.0)
            api.connect(str(self.stats_socket))
            api.sendall(line.encode() + b"\n")
            chunks = []
            while chunk := api.recv(65536):
                chunks.append(chunk)
        return b"".join(chunks).decode("utf-8", "replace")

    def states(self, backend: str = "eca") -> dict[str, str]:
        """Each server's state in a backend as `show stat` says it: "UP", "NOLB", "DOWN", "UP 1/2" (going down)..."""
        text = self.command("show stat").lstrip("# ")
        return {row["svname"]: row["status"] for row in csv.DictReader(io.StringIO(text))
                if row.get("pxname") == backend and row.get("svname") not in ("FRONTEND", "BACKEND")}

    def wait_for_states(self, wanted: dict[str, str], timeout_s: float, backend: str = "eca") -> dict[str, str]:
        """Poll until each named server is in the wanted state; the states seen last (TimeoutError if not)."""
        deadline = time.monotonic() + timeout_s
        while True:
            seen = self.states(backend)
            if all(seen.get(name) == state for name, state in wanted.items()):
                return seen
            if time.monotonic() > deadline:
                raise TimeoutError(f"HAProxy's servers are {seen}, not {wanted}, after {timeout_s} s")
            time.sleep(0.05)  # polling HAProxy's checks, which run on their own interval


@contextmanager
def balancer(servers: Sequence[tuple[str, str]], check_inter_ms: int = 500, host: str = "127.0.0.1",
             wait_checked: bool = True) -> Iterator[Balancer]:
    """HAProxy over `servers` ((name, host:port) each) on a free port of `host`, until the block ends. With
    `wait_checked`, it is yielded once every server's state has settled (none still between states, as HAProxy
    shows an unchecked server: "UP 1/2"), so what a test sends first is routed on the hosts' real states."""
    reason = haproxy_available()
    if reason is not None:
        import pytest

        pytest.skip(reason)
    folder = Path(tempfile.mkdtemp(prefix="eca-lb-"))
    try:
        for attempt in range(3):  # the free port may be taken between probing and binding it: another one
            port = free_port(host)
            config_path = folder / "haproxy.cfg"
            stats_socket = folder / "api.sock"
            config_path.write_text(render_config(servers, f"{host}:{port}", stats_socket, check_inter_ms))
            checked = subprocess.run(["haproxy", "-c", "-f", str(config_path)], capture_output=True, text=True)
            if checked.returncode != 0:
                raise RuntimeError(f"HAProxy refuses the rendered config:\n{checked.stdout}{checked.stderr}")
            with running(["haproxy", "-f", str(config_path), "-db"], stop_signal=signal.SIGTERM) as (proc, log):
                if not _wait_listening(proc, host, port, stats_socket):
                    if attempt < 2 and any("cannot bind" in line.lower() for line in log.lines):
                        continue
                    raise RuntimeError("HAProxy did not start:\n" + "\n".join(log.lines[-20:]))
                lb = Balancer(f"http://{host}:{port}/", config_path, stats_socket, log, proc)
                if wait_checked:
                    deadline = time.monotonic() + START_TIMEOUT_S
                    while any("/" in s or not s for s in lb.states().values()):
                        if time.monotonic() > deadline:
                            raise TimeoutError(f"HAProxy did not check its servers: {lb.states()}")
                        time.sleep(0.05)  # polling the first round of checks
                yield lb
                return
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _wait_listening(proc: subprocess.Popen[bytes], host: str, port: int, stats_socket: Path) -> bool:
    """Poll until HAProxy accepts on its port and its runtime API socket is there; False when it exited."""
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            return False
        try:
            with socket.create_connection((host, port), timeout=0.5):
                if stats_socket.exists():
                    return True
        except OSError:
            pass
        time.sleep(0.02)  # polling the start, which takes some tens of ms
    return False


@dataclass
class EcaHost:
    """One eca host: its private bus config, its web address (host:port) and page URL, and its process group."""

    config: BusConfig
    address: str
    url: str
    process: subprocess.Popen[bytes]
    log: LineReader

    def kill(self) -> None:
        """The whole host gone at once (its supervisor and every service), as a machine that loses power."""
        import os

        os.killpg(self.process.pid, signal.SIGKILL)
        self.process.wait(timeout=10)
        # The group's other processes die a moment after its leader: gone when its web port refuses connections.
        host, port = self.address.rsplit(":", 1)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            try:
                socket.create_connection((host, int(port)), timeout=0.2).close()
            except OSError:
                return
            time.sleep(0.01)  # polling the port until it refuses
        raise TimeoutError(f"the host at {self.address} still accepts connections 10 s after SIGKILL")


@contextmanager
def eca_hosts(max_conversations: Sequence[int], extra_args: Sequence[str] = (), ready_timeout_s: float = 180.0,
              max_viewers: int | None = None, network: Sequence[Host] | None = None,
              token: str | None = None) -> Iterator[list[EcaHost]]:
    """One `eca up --web --per-visitor` per entry of `max_conversations` (its `[conversations] max`; `[web]
    max_viewers` too, when given), each on a private bus, with faces the pages draw (no GL on the server) and
    silent audio, listening on a free port of 127.0.0.1, or, with `network`, each in its own network namespace on
    its address (a host of its own; off loopback the pages need `token`). All are started before any is waited
    for: their starts overlap. Stopped (SIGINT to each group, SIGKILL after 5 s) when the block ends."""
    if network is not None and (len(network) != len(max_conversations) or token is None):
        raise ValueError("one network host per eca host, and a token for pages off loopback")
    with ExitStack() as stack:
        started = []
        for i, count in enumerate(max_conversations):
            config = stack.enter_context(private_bus_config(services=["dialogue", "gaze", "audio"]))
            text, found = re.subn(r"^(\[conversations\][^\[]*?^max = )\d+", rf"\g<1>{count}",
                                  config.config_path.read_text(), count=1, flags=re.MULTILINE | re.DOTALL)
            if not found:
                raise RuntimeError("the config has no [conversations] max to set")
            if max_viewers is not None:
                text, found = re.subn(r"^(\[web\][^\[]*?^max_viewers = )\d+", rf"\g<1>{max_viewers}", text,
                                      count=1, flags=re.MULTILINE | re.DOTALL)
                if not found:
                    raise RuntimeError("the config has no [web] max_viewers to set")
            config.config_path.write_text(text)
            argv = eca_command("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet",
                               "--web", "--web-port", "0", "--per-visitor", "--face", "head", "--web-draw", "browser",
                               "--silent-audio", *extra_args)
            if network is not None:
                assert token is not None
                argv = network[i].argv([*argv, "--web-host", network[i].address, "--web-token", token])
            proc, reader = stack.enter_context(running(argv))
            started.append((config, proc, reader))
        hosts = []
        for config, proc, reader in started:
            reader.wait_for("[up] ready in", ready_timeout_s)
            line = reader.lines[reader.wait_for("[web] INFO serving http://", 10.0)]
            match = re.search(r"http://(\S+?)/", line)
            if match is None:
                raise RuntimeError(f"no address in {line!r}")
            hosts.append(EcaHost(config, match.group(1), f"http://{match.group(1)}/", proc, reader))
        yield hosts
