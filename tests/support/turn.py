"""A real TURN server (coturn's turnserver, Debian's coturn) on a test host, for tests of WebRTC through a relay.

`turn_server(host, secret)` starts it on the host's address (UDP and TCP 3478, relay ports 49160-49200 there) with
time-limited credentials from `secret` (use-auth-secret, the scheme eca's [web.ice] secret_file mints), and returns
once it answers a STUN binding request from the test itself. Its output is kept for a failure's message (`log()`);
it is stopped on exit (and its process group).
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from aioice import stun

from eca.services.tools.child_processes import LineReader
from tests.support.bus import running
from tests.support.netns import Host

PORT = 3478
REALM = "eca.test"


def turn_available() -> str | None:
    """None when coturn is installed; otherwise why not (a skip reason)."""
    return None if shutil.which("turnserver") else "coturn's turnserver is not installed (apt install coturn)"


@dataclass
class TurnServer:
    address: str
    output: LineReader

    @property
    def url(self) -> str:
        return f"turn:{self.address}:{PORT}"

    @property
    def lines(self) -> list[str]:
        return self.output.lines

    def log(self, last: int = 60) -> str:
        return "\n".join(self.lines[-last:])


def stun_answers(address: str, port: int = PORT, timeout_s: float = 0.5) -> bool:
    """Whether a STUN binding request to address:port gets a success answer within the timeout."""
    request = stun.Message(message_method=stun.Method.BINDING, message_class=stun.Class.REQUEST)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.settimeout(timeout_s)
        sock.sendto(bytes(request), (address, port))
        try:
            data, _ = sock.recvfrom(2048)
        except OSError:
            return False
    answer = stun.parse_message(data)
    return answer.transaction_id == request.transaction_id and answer.message_class == stun.Class.RESPONSE


@contextmanager
def turn_server(host: Host, secret: str, timeout_s: float = 10.0) -> Iterator[TurnServer]:
    with tempfile.TemporaryDirectory(prefix="eca-turn-") as tmp:
        argv = ["turnserver", "-n", f"--listening-ip={host.address}", f"--relay-ip={host.address}",
                f"--listening-port={PORT}", "--min-port=49160", "--max-port=49200", "--use-auth-secret",
                f"--static-auth-secret={secret}", f"--realm={REALM}", "--no-tls", "--no-dtls", "--no-cli",
                "--log-file=stdout", "--simple-log", f"--db={os.path.join(tmp, 'turndb')}",
                f"--pidfile={os.path.join(tmp, 'pid')}", "--verbose"]
        with running(host.argv(argv), stop_signal=signal.SIGTERM) as (proc, output):
            server = TurnServer(host.address, output)
            deadline = time.monotonic() + timeout_s
            while not stun_answers(host.address):  # each try waits up to 0.5 s for the answer
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"coturn did not answer on {host.address}:{PORT}:\n{server.log()}")
            yield server
