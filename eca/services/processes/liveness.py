"""The supervisor's own line to its processes: heartbeats that never pass through the broker.

Every child of `eca up` beats on the bus (for anyone watching) and also straight to the supervisor,
over a PUSH socket to the PULL socket the supervisor binds at `ipc://<runtime dir>/supervisor`. So
whether a process is alive is never judged through the bus it may itself be waiting for: a broker that
is slow to come back costs the healthy services nothing. (circus keeps its control channel apart from
its event channel for the same reason.) The channel is private to the instance's runtime directory
(mode 0700), yet what arrives on it is still decoded by the codec like any bus message.
"""

from __future__ import annotations

from pathlib import Path

import zmq

from eca.protocol.codec import ProtocolError, decode, encode
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import Heartbeat

_FILE = "supervisor"
_MAX_BEAT_BYTES = 1024  # a heartbeat is about 150 bytes


def liveness_endpoint(config: BusConfig) -> str:
    return f"ipc://{config.runtime_dir}/{_FILE}"


class LivenessSender:
    """A child's side: sends each heartbeat to the supervisor, never blocking and never queueing old ones."""

    def __init__(self, ctx: zmq.Context, endpoint: str) -> None:
        self.socket = ctx.socket(zmq.PUSH)
        self.socket.setsockopt(zmq.SNDHWM, 4)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.IMMEDIATE, 1)  # no queue while unconnected: a stale beat proves nothing
        self.socket.connect(endpoint)

    def beat(self, heartbeat: Heartbeat) -> None:
        try:
            self.socket.send(encode(heartbeat), zmq.NOBLOCK)
        except zmq.Again:
            pass  # the supervisor is not reading right now; the next beat says the same, fresher

    def close(self) -> None:
        self.socket.close()


class LivenessListener:
    """The supervisor's side: the heartbeats its children sent since the last read."""

    def __init__(self, ctx: zmq.Context, config: BusConfig) -> None:
        self.endpoint = liveness_endpoint(config)
        self._path = Path(self.endpoint.removeprefix("ipc://"))
        self.socket = ctx.socket(zmq.PULL)
        self.socket.setsockopt(zmq.RCVHWM, 1000)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.MAXMSGSIZE, _MAX_BEAT_BYTES)
        self.socket.bind(self.endpoint)
        self.rejected = 0

    def drain(self, limit: int = 10_000) -> list[Heartbeat]:
        beats: list[Heartbeat] = []
        for _ in range(limit):
            try:
                frame = self.socket.recv(zmq.NOBLOCK)
            except zmq.Again:
                break
            try:
                msg = decode(frame, _MAX_BEAT_BYTES)
            except ProtocolError:
                self.rejected += 1
                continue
            if isinstance(msg, Heartbeat):
                beats.append(msg)
            else:
                self.rejected += 1
        return beats

    def close(self) -> None:
        self.socket.close()
        self._path.unlink(missing_ok=True)
