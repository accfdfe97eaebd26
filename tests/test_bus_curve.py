"""The bus with CURVE keys (docs/protocol.md §15), on loopback TCP: key files and the config's refusals, the
broker's ZAP allow-list, an unknown key refused, reported (rate-limited) and nothing it sends applied, and
handshakes of garbage, cut short or replayed leaving the broker serving."""

from __future__ import annotations

import os
import shutil
import socket
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest
import zmq

from eca.protocol.bus import BusTimeout, LinkWatch, Publisher, Subscriber
from eca.protocol.client import AgentClient
from eca.protocol.codec import encode
from eca.protocol.curve import CurveKeyError
from eca.protocol.endpoints import BusConfig, BusConfigError, load_bus_config
from eca.protocol.messages import EmotionState, Error, SetEmotion
from eca.services.processes.broker import Broker
from eca.services.processes.dialogue import DialogueService
from eca.services.processes.runtime import wait_until
from eca.services.tools import cli
from eca.services.tools.commands.keys import list_pairs, new_pair
from tests.support.bus import BrokerThread, ServiceThread, write_test_config


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def bus_table(run_dir: Path, host: str, ports: tuple[int, int], server_key: str = "", client_key: str = "",
              allowed: str = "", instance: str = "curve") -> str:
    return (f'[bus]\ntransport = "tcp"\ninstance = "{instance}"\nruntime_dir = "{run_dir}"\ntcp_host = "{host}"\n'
            f"tcp_frontend_port = {ports[0]}\ntcp_backend_port = {ports[1]}\nallow_remote = true\nhwm = 20000\n"
            f"max_message_bytes = 4194304\nconnect_timeout_s = 10.0\ncurve_server_key = \"{server_key}\"\n"
            f'curve_client_key = "{client_key}"\ncurve_allowed_dir = "{allowed}"\n')


@dataclass
class CurveSetup:
    """Keys and configs for a broker's host ("model") and client hosts, as `eca keys` makes them."""

    root: Path
    host: str
    ports: tuple[int, int]
    model: Path  # the broker's host's config: the server pair, its own pair, the allowed folder

    def client(self, name: str, server_key: str = "server.key") -> Path:
        """A client host's config: the server's public key and its own pair (made if new)."""
        keys = self.root / "keys"
        if not (keys / f"{name}.key_secret").exists():
            new_pair(keys, name)
        directory = self.root / name
        directory.mkdir(exist_ok=True)
        return write_test_config(directory, extra=bus_table(directory / "run", self.host, self.ports,
                                                            str(keys / server_key),
                                                            str(keys / f"{name}.key_secret")))


def curve_setup(root: Path, host: str = "127.0.0.1", allow: tuple[str, ...] = ("dm",),
                services: list[str] | None = None, agents: list[str] | None = None, extra: str = "") -> CurveSetup:
    keys, allowed, model = root / "keys", root / "allowed", root / "model"
    for name in ("server", "model", *allow):
        new_pair(keys, name)
    allowed.mkdir()
    model.mkdir()
    for name in allow:
        shutil.copy(keys / f"{name}.key", allowed / f"{name}.key")
    ports = (free_port(), free_port())
    # relative paths: the config's neighbours
    table = bus_table(model / "run", host, ports, "../keys/server.key_secret", "../keys/model.key_secret",
                      "../allowed")
    return CurveSetup(root, host, ports, write_test_config(model, services, agents, table + extra))


@contextmanager
def short_dir() -> Iterator[Path]:
    """A private folder with a short path: the supervisor's ipc socket lives under it (107 bytes at most)."""
    path = Path(tempfile.mkdtemp(prefix="ecc-"))
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)


@pytest.fixture
def setup() -> Iterator[CurveSetup]:
    with short_dir() as root:
        yield curve_setup(root)


# --- key files and config ---------------------------------------------------------------------------


def test_keys_new_makes_a_private_pair_and_list_shows_its_public_key(tmp_path: Path, capsys) -> None:
    keys = tmp_path / "k"
    assert cli.main(["keys", "new", "ada-host", "--dir", str(keys)]) == 0
    secret, public = keys / "ada-host.key_secret", keys / "ada-host.key"
    assert oct(secret.stat().st_mode & 0o777) == "0o600" and oct(keys.stat().st_mode & 0o777) == "0o700"
    key = public.read_text().split('public-key = "')[1][:40]
    assert key in capsys.readouterr().out
    assert cli.main(["keys", "list", "--dir", str(keys)]) == 0
    assert f"ada-host                 {key}  pair (public + secret)" in capsys.readouterr().out
    # no silent overwrite, no odd names
    assert cli.main(["keys", "new", "ada-host", "--dir", str(keys)]) == 1
    assert "exists; give --force" in capsys.readouterr().err
    with pytest.raises(CurveKeyError, match="use 1-64 letters"):
        new_pair(keys, "../evil")
    # a bad file is named in the list, not a crash; the rest still listed
    (keys / "junk.key").write_text("not a certificate\n")
    lines = list_pairs(keys)
    assert any(line.startswith("junk") and "BAD:" in line and "junk.key" in line for line in lines), lines
    assert any(key in line for line in lines)
    assert cli.main(["keys", "list", "--dir", str(tmp_path / "none")]) == 1
    assert "no such folder" in capsys.readouterr().err


def config_error(setup: CurveSetup, table: str) -> str:
    path = write_test_config(setup.root / "model", extra=table)
    with pytest.raises(BusConfigError) as info:
        load_bus_config(path)
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    return message


def test_the_config_refuses_a_plaintext_remote_bus_and_every_bad_key(setup: CurveSetup) -> None:
    keys, run = setup.root / "keys", setup.root / "model" / "run"
    ports = setup.ports
    # loopback TCP without keys stays allowed; a remote address without keys is one clear line
    write_test_config(setup.root / "model", extra=bus_table(run, "127.0.0.1", ports))
    assert load_bus_config(setup.root / "model" / "eca.toml").curve is None
    assert "is not loopback and no CURVE keys are set" in config_error(setup, bus_table(run, "10.9.8.7", ports))
    assert "'curve_client_key' is not set" in config_error(
        setup, bus_table(run, "10.9.8.7", ports, server_key=str(keys / "server.key")))
    assert "curve_allowed_dir is set but curve_server_key is not" in config_error(
        setup, bus_table(run, "127.0.0.1", ports, allowed=str(setup.root / "allowed")))
    assert "no such key file" in config_error(
        setup, bus_table(run, "127.0.0.1", ports, str(keys / "nope.key"), str(keys / "dm.key_secret")))
    # a public file where the pair is needed
    assert "holds no secret key" in config_error(
        setup, bus_table(run, "127.0.0.1", ports, str(keys / "server.key"), str(keys / "dm.key")))
    # a secret key others can read
    os.chmod(keys / "dm.key_secret", 0o644)
    assert "readable by others (mode 0644)" in config_error(
        setup, bus_table(run, "127.0.0.1", ports, str(keys / "server.key"), str(keys / "dm.key_secret")))
    os.chmod(keys / "dm.key_secret", 0o600)
    # garbage, a truncated key, a key that is not its secret's
    (keys / "junk.key").write_text("curve\n    public-key = \"short\"\n")
    assert "a CURVE key is 40 (Z85)" in config_error(
        setup, bus_table(run, "127.0.0.1", ports, str(keys / "junk.key"), str(keys / "dm.key_secret")))
    (keys / "bin.key").write_bytes(b"\xff\xfe\x00garbage")
    assert "not a CURVE key file" in config_error(
        setup, bus_table(run, "127.0.0.1", ports, str(keys / "bin.key"), str(keys / "dm.key_secret")))
    mixed = keys / "mixed.key_secret"
    mixed.write_text((keys / "dm.key_secret").read_text().replace(
        (keys / "dm.key").read_text().split('public-key = "')[1][:40],
        (keys / "server.key").read_text().split('public-key = "')[1][:40]))
    os.chmod(mixed, 0o600)
    assert "is not the one of its secret key" in config_error(
        setup, bus_table(run, "127.0.0.1", ports, str(keys / "server.key"), str(mixed)))
    assert "the allowed-clients folder does not exist" in config_error(
        setup, bus_table(run, "127.0.0.1", ports, str(keys / "server.key_secret"), str(keys / "dm.key_secret"),
                         str(setup.root / "nowhere")))
    assert "must be a path" in config_error(
        setup, bus_table(run, "127.0.0.1", ports).replace('curve_server_key = ""', "curve_server_key = 3"))


def test_a_broker_given_only_the_servers_public_key_refuses_to_start(setup: CurveSetup) -> None:
    config = load_bus_config(setup.client("dm"))  # a client's config: the server's public key only
    with pytest.raises(CurveKeyError, match="holds no secret key, and the broker needs it"):
        Broker(config, zmq.Context())
    # and it left no lock behind: a broker with the right keys starts on the same instance
    model = load_bus_config(setup.model)
    Broker(model, zmq.Context()).close()


# --- the ZAP allow-list -------------------------------------------------------------------------------


@pytest.fixture
def model_bus(setup: CurveSetup) -> Iterator[tuple[CurveSetup, BusConfig, BrokerThread]]:
    config = load_bus_config(setup.model)
    with BrokerThread(config) as broker:
        yield setup, config, broker


def errors_seen(sub: Subscriber, until: float, first: bool = False) -> list[Error]:
    """The errors that arrive before `until` (with `first`: until the first report of a refusal)."""
    got: list[Error] = []
    while (left := until - time.monotonic()) > 0:
        r = sub.recv(left)
        if r is not None and isinstance(r.message, Error):
            got.append(r.message)
            if first and r.message.kind == "unauthorized":
                break
    return got


def test_an_unknown_key_gets_nothing_through_is_reported_and_nothing_it_sends_is_applied(model_bus) -> None:
    setup, config, broker = model_bus
    dm = load_bus_config(setup.client("dm"))
    rogue = load_bus_config(setup.client("rogue"))
    ctx = zmq.Context()
    with ServiceThread(DialogueService(config)), AgentClient(dm, agent="ada", source="dm") as client:
        client.wait_applied(client.set_emotion("happy", 0.8, transition_s=0.0))
        watch = Subscriber(ctx, dm, ["", "error."])
        watch.wait_ready()
        # the rogue's subscriber gets no barrier answer, and says why
        spy = Subscriber(ctx, rogue, [""])
        with pytest.raises(BusTimeout, match=r"refused this host's key .*add its public key file"):
            spy.wait_ready(1.0)
        pub = Publisher(ctx, rogue, "rogue")
        for i in range(20):  # sent blind: nothing the rogue sends may be applied
            pub.publish(SetEmotion(agent="ada", request_id=f"rogue-{i}", name="angry", intensity=1.0))
        rogue_key = rogue.curve.client_public.decode()  # type: ignore[union-attr]
        reports = [e for e in errors_seen(watch, time.monotonic() + 5.0, first=True) if e.kind == "unauthorized"]
        assert reports and all(e.topic == "" and e.agent == "*" and e.service == "broker" for e in reports)
        assert rogue_key in reports[0].reason and "127.0.0.1" in reports[0].reason
        # the legitimate client's next command goes through and is the state; none of the rogue's came by
        client.wait_applied(client.set_emotion("surprised", 0.4, transition_s=0.0))
        assert client.state["emotion"].name == "surprised"  # type: ignore[attr-defined]
        seen = watch.drain()
        assert not [r for r in seen if r.message is not None and r.message.source == "rogue"]
        assert not [r for r in seen if "rogue-" in str(getattr(r.message, "request_id", ""))]
        assert not [m for m in client._inbox if isinstance(m, EmotionState) and m.name == "angry"]
        assert spy.drain() == []
        assert broker.broker.zap is not None and broker.broker.zap.refused >= 2
        for s in (watch, spy, pub):
            s.close()
    ctx.term()


def test_a_flood_of_refused_handshakes_is_reported_a_few_times_only(model_bus) -> None:
    setup, config, broker = model_bus
    dm = load_bus_config(setup.client("dm"))
    ctx = zmq.Context()
    watch = Subscriber(ctx, dm, ["error."])
    watch.wait_ready()
    server_key = config.curve.server_public  # type: ignore[union-attr]
    socks = []
    t0 = time.monotonic()
    for _ in range(60):  # sixty fresh keys, as fast as they come
        public, secret = zmq.curve_keypair()
        s = ctx.socket(zmq.PUB)
        s.setsockopt(zmq.LINGER, 0)
        s.curve_serverkey, s.curve_publickey, s.curve_secretkey = server_key, public, secret
        s.connect(config.frontend)
        socks.append(s)
    zap = broker.broker.zap
    assert zap is not None
    assert wait_until(lambda: zap.refused >= 60, 10.0), zap.refused
    reports = [e for e in errors_seen(watch, time.monotonic() + 0.6) if e.kind == "unauthorized"]
    elapsed = time.monotonic() - t0
    assert 1 <= len(reports) <= 1 + 4 * elapsed, (len(reports), elapsed)
    assert zap.unreported > 0 or any("more refusals not reported" in e.reason for e in reports)
    for s in socks:
        s.close()
    watch.close()
    ctx.term()


def test_a_key_added_to_the_allowed_folder_is_let_in_without_a_restart(model_bus) -> None:
    setup, config, _ = model_bus
    late = load_bus_config(setup.client("late"))
    ctx = zmq.Context()
    sub = Subscriber(ctx, late, [])
    with pytest.raises(BusTimeout, match="refused"):
        sub.wait_ready(1.0)
    sub.close()
    shutil.copy(setup.root / "keys" / "late.key", setup.root / "allowed" / "late.key")
    sub = Subscriber(ctx, late, [])
    sub.wait_ready(5.0)
    sub.close()
    ctx.term()


# --- bad handshakes ---------------------------------------------------------------------------------


class Recorder:
    """A TCP relay in front of the broker's frontend that records what the client sends (to replay it)."""

    def __init__(self, target: tuple[str, int]) -> None:
        self.target = target
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.sent = bytearray()
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        client, _ = self.listener.accept()
        upstream = socket.create_connection(self.target)

        def pump(src: socket.socket, dst: socket.socket, record: bool) -> None:
            try:
                while data := src.recv(65536):
                    if record:
                        self.sent += data
                    dst.sendall(data)
            except OSError:
                pass

        threading.Thread(target=pump, args=(upstream, client, False), daemon=True).start()
        pump(client, upstream, True)


def raw_send(port: int, data: bytes, wait_s: float = 0.3) -> None:
    with socket.create_connection(("127.0.0.1", port), timeout=2) as s:
        try:
            s.sendall(data)
            s.settimeout(wait_s)
            while s.recv(4096):
                pass
        except OSError:
            pass


def test_garbage_truncated_and_replayed_handshakes_leave_the_broker_serving(model_bus) -> None:
    setup, config, broker = model_bus
    dm_path = setup.client("dm")
    dm = load_bus_config(dm_path)
    ctx = zmq.Context()
    # a real client's handshake, recorded through a relay, then sent again from a raw socket
    recorder = Recorder(("127.0.0.1", setup.ports[0]))
    relayed = load_bus_config(write_test_config(setup.root / "dm", extra=bus_table(
        setup.root / "dm" / "run", "127.0.0.1", (recorder.port, setup.ports[1]),
        str(setup.root / "keys" / "server.key"), str(setup.root / "keys" / "dm.key_secret"))))
    pub = Publisher(ctx, relayed, "dm")
    pub.wait_ready(5.0)
    pub.publish(SetEmotion(agent="ada", name="happy"))
    assert wait_until(lambda: len(recorder.sent) > 300, 5.0)
    pub.close()
    handshake = bytes(recorder.sent)
    zap = broker.broker.zap
    assert zap is not None
    refused_before = zap.refused
    for port in setup.ports:
        raw_send(port, os.urandom(4096))  # garbage
        raw_send(port, handshake[:11])  # a greeting cut short
        raw_send(port, handshake[:64] + b"\x00" * 10)  # a greeting, then nonsense
        raw_send(port, handshake)  # the whole handshake and a message, replayed
        raw_send(port, handshake[:200])  # a replayed HELLO and part of INITIATE
        raw_send(port, b"\xff" + b"\x00" * 8 + b"\x7f" + encode(SetEmotion(agent="ada", name="angry")))
    # the broker is up and serves a legitimate client at once; no replay got a key in, nor reached ZAP as it
    dm_pub = Publisher(ctx, dm, "dm")
    dm_sub = Subscriber(ctx, dm, ["cmd.ada."])
    dm_pub.wait_ready(5.0)
    dm_sub.wait_ready(5.0)
    dm_pub.publish(SetEmotion(agent="ada", name="sad"))
    got = dm_sub.recv(5.0)
    assert got is not None and isinstance(got.message, SetEmotion) and got.message.name == "sad"
    assert dm_sub.drain() == []  # nothing of the replays (their "happy", the raw "angry") came through
    assert zap.refused == refused_before
    assert broker._thread.is_alive() and broker.broker.failures == 0
    for s in (dm_pub, dm_sub):
        s.close()
    ctx.term()


# --- state versions and the link ---------------------------------------------------------------------


def test_a_subscriber_never_takes_an_older_state_of_the_same_publisher(model_bus) -> None:
    _, config, _ = model_bus
    ctx = zmq.Context()
    sub = Subscriber(ctx, config, ["state."])

    def frames(t_ns: int, name: str, source: str = "dialogue") -> list[bytes]:
        return [b"state.ada.emotion", encode(EmotionState(agent="ada", name=name, intensity=0.5, t_ns=t_ns,
                                                          source=source, seq=1))]

    now = time.monotonic_ns()
    assert sub.accept(frames(now, "happy")) is not None
    assert sub.accept(frames(now - 5 * 10**9, "sad")) is None and sub.stale == 1  # a backlog's older state
    assert sub.accept(frames(now + 1, "angry")) is not None
    assert sub.accept(frames(now - 120 * 10**9, "natural")) is not None  # its host's clock restarted
    assert sub.accept(frames(now - 10**9, "sad", source="other")) is not None  # another clock: not compared
    sub.close()
    ctx.term()


def test_a_client_sees_the_broker_go_within_the_heartbeat_timeout(setup: CurveSetup) -> None:
    config = load_bus_config(setup.model)
    dm = load_bus_config(setup.client("dm"))
    ctx = zmq.Context()
    broker = BrokerThread(config)
    with broker:
        watch = LinkWatch(ctx, dm)
        assert wait_until(lambda: watch.up() and watch.beats >= 2, 5.0)
    gone = time.monotonic()
    assert wait_until(lambda: not watch.up(), dm.heartbeat_timeout_s + 1.0)
    assert time.monotonic() - gone <= dm.heartbeat_timeout_s + 0.5
    watch.close()
    ctx.term()
