"""A UDP sender that can never hold the service up: non-blocking, nothing queued, nothing read.

A receiver that is down, slow or far costs the loop one failed `sendto`: a datagram the kernel cannot take now
(its send buffer is full) or that the network refuses is dropped and counted, never retried or kept. The socket is
never read, so nothing a receiver sends back (an ICMP error, a reply) reaches the service.
"""

from __future__ import annotations

import errno
import socket
from typing import Any


class UdpSender:
    """Datagrams to one address family's receivers; `sent` and `dropped` count them."""

    def __init__(self, family: int = socket.AF_INET) -> None:
        self.socket = socket.socket(family, socket.SOCK_DGRAM)
        self.socket.setblocking(False)
        self.sent = 0
        self.dropped = 0
        self.last_error = ""  # why the latest datagram was dropped (for the log)

    def send(self, data: bytes, sockaddr: tuple[Any, ...]) -> bool:
        """Send one datagram now, or drop it; True when the kernel took it."""
        try:
            self.socket.sendto(data, sockaddr)
        except BlockingIOError:
            self._drop("the send buffer is full")
            return False
        except OSError as exc:  # unreachable network, refused, message too long: the receiver's problem, not ours
            self._drop(exc.strerror or errno.errorcode.get(exc.errno or 0, "send failed"))
            return False
        self.sent += 1
        return True

    def _drop(self, reason: str) -> None:
        self.dropped += 1
        self.last_error = reason

    def close(self) -> None:
        self.socket.close()
