"""Real-time scheduling for the voice's path: the broker, the audio service and the web service by default.

A voice packet that waits for a core leaves late, and a listener hears a gap. On a busy machine that wait is the
kernel's run queue, not the service's own work: with fifty conversations on two cores (bench/conversations.py), the
web service handed 48-281 of 14,000-15,700 voice frames over more than 20 ms late at the ordinary priority, and
none with these services at SCHED_RR (docs/web.md "Real-time scheduling"). Audio servers (JACK, PipeWire) and WebRTC's
own audio threads run the same way.

Each service that [realtime] names asks for SCHED_RR at [realtime] priority as it starts, for every thread it has
then (none yet, normally); the threads it makes later inherit it. A program it starts (a TTS engine, which may
take a core for a second) runs at the ordinary priority: the thread that starts it calls `ordinary_children`
first. A service that is not allowed it (it needs CAP_SYS_NICE, or an
RLIMIT_RTPRIO of at least the priority: docs/deploy.md) says so once and runs as before. The kernel keeps 5 % of
each second for ordinary work whatever real-time threads want (sched_rt_runtime_us), so a service stuck in a loop
cannot take the whole machine.
"""

from __future__ import annotations

import os
from collections.abc import Collection
from dataclasses import dataclass

from eca.protocol.endpoints import BusConfig, BusConfigError

DEFAULT_PRIORITY = 10  # low among real-time priorities: a sound server's (PipeWire's 88, JACK's 10+) comes first
DEFAULT_SERVICES = ("broker", "audio", "web")
MAX_PRIORITY = 99  # SCHED_RR's range on Linux: 1..99


@dataclass(frozen=True)
class RealtimeSettings:
    priority: int  # SCHED_RR priority, 1..99; 0: every service at the ordinary priority
    services: tuple[str, ...]  # the services that ask for it (a web worker as "web")


def realtime_settings(config: BusConfig, known: Collection[str]) -> RealtimeSettings:
    """[realtime] priority and services (each one of `known`), checked; the defaults where the table or a key is
    missing."""
    where = f"{config.config_path} [realtime]"
    table = config.raw.get("realtime", {})
    if not isinstance(table, dict):
        raise BusConfigError(f"{config.config_path}: 'realtime' must be a table")
    unknown = sorted(set(table) - {"priority", "services"})
    if unknown:
        raise BusConfigError(f"{where}: unknown key {unknown[0]!r}; known: priority, services"[:300])
    priority = table.get("priority", DEFAULT_PRIORITY)
    if type(priority) is not int or not 0 <= priority <= MAX_PRIORITY:
        raise BusConfigError(f"{where}: 'priority' must be an integer in 0..{MAX_PRIORITY} (0: off), "
                             f"got {priority!r}"[:300])
    services = table.get("services", list(DEFAULT_SERVICES))
    if not isinstance(services, list) or len(services) > len(known) or not all(
            isinstance(s, str) and s in known for s in services):
        raise BusConfigError(f"{where}: 'services' must be a list of services ({', '.join(sorted(known))}), "
                             f"got {services!r}"[:300])
    return RealtimeSettings(priority, tuple(services))


def ask_for_realtime(service: str, settings: RealtimeSettings) -> str | None:
    """Put this process's threads on SCHED_RR at the settings' priority when `settings` names `service`; what came
    of it as a line for the log (None: not asked)."""
    if settings.priority == 0 or service not in settings.services:
        return None
    if not hasattr(os, "sched_setscheduler") or not hasattr(os, "SCHED_RESET_ON_FORK"):
        return "real-time scheduling: not on this system; the ordinary priority"
    # not SCHED_RESET_ON_FORK here: on Linux a new thread is a fork in that sense, and would lose it
    param = os.sched_param(settings.priority)
    try:
        for thread in _threads():
            os.sched_setscheduler(thread, os.SCHED_RR, param)
    except OSError as exc:  # EPERM without the capability or the rlimit
        return (f"real-time scheduling (SCHED_RR {settings.priority}) not allowed here ({exc.strerror}): the "
                "ordinary priority; docs/deploy.md says how to allow it")
    return f"real-time scheduling: SCHED_RR {settings.priority}"


def ordinary_children() -> None:
    """The programs the calling thread starts from now on run at the ordinary priority, not at its real-time one
    (nothing changes for a thread at the ordinary priority, or where there is no such call)."""
    if not hasattr(os, "SCHED_RESET_ON_FORK"):
        return
    policy = os.sched_getscheduler(0)
    if policy & os.SCHED_RESET_ON_FORK or policy not in (os.SCHED_RR, os.SCHED_FIFO):
        return
    os.sched_setscheduler(0, policy | os.SCHED_RESET_ON_FORK, os.sched_getparam(0))


def _threads() -> list[int]:
    """This process's threads (the calling one alone where /proc does not list them)."""
    try:
        return [int(tid) for tid in os.listdir("/proc/self/task")]
    except OSError:
        return [0]
