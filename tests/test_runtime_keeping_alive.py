"""A service busy with one long, bounded piece of work (a GL context and the faces' first frames, made while a page
loads) still beats to its supervisor, from a thread of its own, and stops beating once the work ends or overruns
its bound: a hang is still seen as one."""

from __future__ import annotations

import time

import zmq

from eca.services.processes.liveness import LivenessListener, liveness_endpoint
from eca.services.processes.runtime import Service
from tests.support.bus import private_bus_config


def beats_over(listener: LivenessListener, seconds: float) -> int:
    deadline = time.monotonic() + seconds
    count = 0
    while time.monotonic() < deadline:
        count += len(listener.drain())
        time.sleep(0.02)  # polling the supervisor's side
    return count


def test_beats_come_during_the_work_and_stop_after_it_or_past_its_bound() -> None:
    with private_bus_config() as config:
        ctx: zmq.Context[zmq.Socket[bytes]] = zmq.Context()
        listener = LivenessListener(ctx, config)
        service = Service(config, ctx=ctx, liveness=liveness_endpoint(config))
        interval = config.heartbeat_interval_s
        try:
            with service.keeping_alive(max_s=6 * interval):
                during = beats_over(listener, 3 * interval)  # the loop is "busy": no beat of its own
            beats_over(listener, 0.2)  # a beat sent as the work ended, still on its way
            after = beats_over(listener, 3 * interval)
            with service.keeping_alive(max_s=2 * interval):
                beats_over(listener, 3 * interval)  # past the bound
                overrun = beats_over(listener, 3 * interval)
        finally:
            listener.close()
            service.close()
            ctx.term()
    assert during >= 2, during
    assert after == 0 and overrun == 0, (after, overrun)
