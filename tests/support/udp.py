"""Receivers for what eca sends over UDP (the rig service's VMC and Live Link packets): a socket on a free
loopback port whose datagrams a thread keeps with their arrival times, and the Live Link Face packet decoded by
its layout (written from the layout, not from eca's packer)."""

from __future__ import annotations

import socket
import struct
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np


def decode_live_link(data: bytes) -> dict[str, Any]:
    """The packet as the layout says (PyLiveLinkFace's encode/decode): version uint32 LE, '$' + 36-char device
    id, subject name (int32 BE length + UTF-8), frame number int32 BE, sub-frame float32 BE, rate numerator and
    denominator int32 BE, count uint8, then count float32 BE."""
    version = struct.unpack("<I", data[0:4])[0]
    device = data[4:41].decode("utf-8")
    (name_len,) = struct.unpack(">i", data[41:45])
    name = data[45:45 + name_len].decode("utf-8")
    at = 45 + name_len
    frame, sub, num, den, count = struct.unpack(">ifiiB", data[at:at + 17])
    values = struct.unpack(f">{count}f", data[at + 17:])
    return {"version": version, "device": device, "subject": name, "frame": frame, "sub": sub, "rate": (num, den),
            "count": count, "values": np.array(values)}


class Catcher:
    """A UDP socket on a free loopback port; a thread keeps `(clock(), decode(datagram))` in `got`, in arrival
    order (`clock`: time.monotonic seconds by default, time.monotonic_ns for a bench's nanoseconds)."""

    def __init__(self, decode: Callable[[bytes], Any] = bytes, clock: Callable[[], float] = time.monotonic) -> None:
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.socket.bind(("127.0.0.1", 0))
        self.socket.settimeout(0.05)
        self.port = self.socket.getsockname()[1]
        self.got: list[tuple[float, Any]] = []
        self._decode, self._clock = decode, clock
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.socket.recv(65536)
            except TimeoutError:
                continue
            self.got.append((self._clock(), self._decode(data)))

    def wait_for(self, predicate: Callable[[Any], bool], timeout_s: float) -> Any | None:
        """The first item kept that meets `predicate`, polling what arrived until `timeout_s`; None if none."""
        deadline = time.monotonic() + timeout_s
        seen = 0
        while time.monotonic() < deadline:
            for _, item in self.got[seen:]:
                seen += 1
                if predicate(item):
                    return item
            time.sleep(0.01)  # pacing a poll of the collected list: the thread appends as datagrams come
        return None

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.socket.close()
