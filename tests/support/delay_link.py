"""A cable with a delay: every Ethernet frame that comes in on one interface leaves on the other `delay_s` later, both
ways (what `tc qdisc ... netem delay` does, for kernels built without netem). Run inside a namespace of its own that
holds the two interfaces (tests/support/netns.py `hosts(..., delays=...)`):

    python -m tests.support.delay_link IFACE_A IFACE_B DELAY_S

It prints "ready" once both sockets are bound, and runs until killed. Frames keep their order (one fixed delay).
The interfaces' offloads must be off (ethtool -K ... gro off gso off tso off): a coalesced frame larger than the MTU
could not leave on the other side.
"""

from __future__ import annotations

import heapq
import itertools
import selectors
import socket
import sys
import time

ETH_P_ALL = 0x0003
MAX_FRAME = 65_536
MAX_HELD = 100_000  # frames in flight; past that new ones are dropped (a cable of bounded memory)


def run(a: str, b: str, delay_s: float) -> None:
    socks: dict[str, socket.socket] = {}
    for name in (a, b):
        s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
        s.bind((name, 0))
        s.setblocking(False)
        socks[name] = s
    other = {socks[a]: socks[b], socks[b]: socks[a]}
    by_fd = {s.fileno(): s for s in socks.values()}
    selector = selectors.DefaultSelector()
    for s in socks.values():
        selector.register(s, selectors.EVENT_READ)
    held: list[tuple[float, int, socket.socket, bytes]] = []
    order = itertools.count()
    print("ready", flush=True)
    while True:
        now = time.monotonic()
        while held and held[0][0] <= now:
            _, _, out, frame = heapq.heappop(held)
            try:
                out.send(frame)
            except OSError:
                pass  # the link is down (a cut): the frame is lost, as on a cable
        timeout = max(0.0, held[0][0] - now) if held else None
        for key, _ in selector.select(timeout):
            s = by_fd[key.fd]
            while True:
                try:
                    frame, address = s.recvfrom(MAX_FRAME)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:
                    break
                if address[2] == socket.PACKET_OUTGOING:  # what this program sent itself
                    continue
                if len(held) < MAX_HELD:
                    heapq.heappush(held, (time.monotonic() + delay_s, next(order), other[s], frame))


if __name__ == "__main__":
    if len(sys.argv) != 4:
        sys.exit("usage: python -m tests.support.delay_link IFACE_A IFACE_B DELAY_S")
    run(sys.argv[1], sys.argv[2], float(sys.argv[3]))
