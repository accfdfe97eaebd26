"""The Python client on its own: what it leaves behind when it cannot reach a broker."""

from __future__ import annotations

import threading

import pytest
import zmq

from protocol.bus import BusTimeout
from protocol.client import AgentClient
from services.testing import private_bus_config


def test_a_client_that_finds_no_broker_closes_its_sockets() -> None:
    with private_bus_config() as config:
        ctx = zmq.Context()
        with pytest.raises(BusTimeout) as caught:
            AgentClient(config, ctx=ctx, timeout_s=0.1)
        # The caller still holds the exception (and so the half-built client): nothing may depend on
        # garbage collection. Context.term() blocks while any socket of the context is still open.
        done = threading.Event()
        threading.Thread(target=lambda: (ctx.term(), done.set()), daemon=True).start()
        assert done.wait(5.0), "the client left sockets open on its context"
        assert "broker" in str(caught.value)
