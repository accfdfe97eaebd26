"""Keep a long-running process's heap from holding on to a flood's memory (glibc's malloc).

glibc raises its mmap threshold each time it frees a large block it had mapped (up to 32 MiB), so after
one 4 MiB message every later large buffer comes from the heap, where what a flood leaves behind stays
resident for good. A fixed threshold keeps large buffers mapped (returned to the system when freed), a
fixed trim threshold hands back the free top of the heap, two arenas keep the threads (zmq's I/O thread,
the audio threads) from holding a heap each, and `trim` returns the free pages inside the heap too.
Elsewhere than glibc these are no-ops.

The price: a buffer of the threshold or more is mapped and unmapped each time it is made. A library that makes one
per call does so at every call; msgpack's packer did for every message (its first buffer is 256 KiB), so the
protocol's codec starts its own at 16 KiB (eca/protocol/codec.py `PACK_BUFFER_BYTES`).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
from functools import cache

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_M_ARENA_MAX = -8
LARGE_BYTES = 128 * 1024  # glibc's own starting threshold, kept fixed


@cache
def _glibc() -> ctypes.CDLL | None:
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        libc = ctypes.CDLL(name)
        libc.mallopt  # noqa: B018 (present in glibc only)
        libc.malloc_trim  # noqa: B018
    except (OSError, AttributeError):
        return None
    return libc


def bound_heap() -> bool:
    """Set the thresholds for this process (call it early); False where the C library is not glibc."""
    libc = _glibc()
    if libc is None:
        return False
    ok = libc.mallopt(_M_MMAP_THRESHOLD, LARGE_BYTES) == 1
    ok &= libc.mallopt(_M_TRIM_THRESHOLD, LARGE_BYTES) == 1
    ok &= libc.mallopt(_M_ARENA_MAX, 2) == 1
    return bool(ok)


def freeze_startup_objects() -> None:
    """Take what a service holds once started (modules, configs, avatars, compiled code) out of the cyclic
    collector's view: collect once, then `gc.freeze()`. A full collection otherwise walks all of it whenever the
    young objects' churn triggers one: in the web service with six conversations those took 27-74 ms, every
    thread stopped, and a voice packet 60-90 ms late with them. What is made afterwards is collected as before."""
    gc.collect()
    gc.freeze()


def trim() -> None:
    """Return the heap's free pages to the system (cheap when there are few)."""
    libc = _glibc()
    if libc is not None:
        libc.malloc_trim(0)
