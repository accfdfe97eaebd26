"""The Python client on its own: what it leaves behind when it cannot reach a broker."""

from __future__ import annotations

import threading

import pytest
import zmq

from eca.protocol.bus import BusTimeout
from eca.protocol.client import AgentClient
from tests.support.bus import private_bus_config


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


def test_the_client_s_command_methods_take_the_command_s_fields() -> None:
    """Each command has a client method named after its type whose parameters are its fields: adding a field
    to a command and not to the client (or the other way round) fails here."""
    import dataclasses
    import inspect

    from eca.protocol.messages import ALL_MESSAGES, ENVELOPE_FIELDS

    methods = {"user_speech": "user_speaking", "speech_chunk": "say_stream"}
    # what a method deliberately leaves to another: a streamed say is say_stream's; a chunk's index, pcm and
    # last come from the chunks it is given
    left_to_others = {"say": {"streamed"}, "speech_chunk": {"index", "pcm", "last", "request_id"}}
    for cls in (c for c in ALL_MESSAGES if c.CATEGORY == "cmd"):
        method = getattr(AgentClient, methods.get(cls.TYPE, cls.TYPE), None)
        assert method is not None, f"AgentClient has no method for {cls.TYPE}"
        params = set(inspect.signature(method).parameters) - {"self"}
        fields = {f.name for f in dataclasses.fields(cls)} - ENVELOPE_FIELDS - left_to_others.get(cls.TYPE, set())
        assert fields <= params, (cls.TYPE, fields - params)
