"""Three agents on a real `eca up`: a turn turns the others' heads toward the speaker on the drawn face, and
the user's pause is answered with the listeners' nods, drawn on the face."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import pytest
import zmq

from eca.agent.config import load_toml
from eca.agent.gaze.backchannel import USER, Backchannel
from eca.agent.gaze.backchannel import Nod as NodAction
from eca.protocol.bus import Subscriber
from eca.protocol.client import AgentClient
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import AttentionState, FaceFrame, Message, Nod, RoleState
from tests.support.bus import eca_command, private_bus_config, running

pytestmark = pytest.mark.slow

AGENTS = ["ada", "bob", "cy"]
SEED = 14  # the first pause of the user draws nods from ada and bob (tests/test_gaze_conversation_bus.py)
NS = 1_000_000_000


@pytest.fixture
def config() -> Iterator[BusConfig]:
    with private_bus_config(services=["dialogue", "gaze", "renderer"], agents=AGENTS,
                            extra=f"[gaze]\nrate_hz = 60.0\nseed = {SEED}\n") as cfg:
        yield cfg


def receive(sub: Subscriber, done: Callable[[list[Message]], bool], timeout_s: float) -> list[Message]:
    got: list[Message] = []
    deadline = time.monotonic() + timeout_s
    while not done(got) and (left := deadline - time.monotonic()) > 0:
        r = sub.recv(left)
        if r is not None and r.message is not None:
            got.append(r.message)
    return got


def test_turns_and_pauses_move_the_drawn_heads(config: BusConfig) -> None:
    model = Backchannel(AGENTS, SEED)
    model.speaking(0, USER, True)
    model.speaking(NS, USER, False)
    nodders = {a.agent for a in model.due(3 * NS) if isinstance(a, NodAction)}
    assert nodders == {"ada", "bob"}
    argv = eca_command("up", "--config", str(config.config_path), "--instance", config.instance, "--quiet",
                       "--headless", "--size", "96x72", "--fps", "20")
    with running(argv) as (_, reader):
        reader.wait_for("[up] ready in", 60.0)
        sub = Subscriber(zmq.Context.instance(), config,
                         ["state.ada.attention", "event.ada.nod", "event.bob.nod", "event.cy.nod",
                          "stream.ada.face_frame"])
        try:
            sub.wait_ready()
            with AgentClient(config, agent="bob") as bob:
                bob.set_role("talking", speaker="bob")
                bob.expect_state(RoleState, lambda m: m.role == "talking")
            got = receive(sub, lambda m: any(isinstance(x, AttentionState) and x.person == "bob" for x in m), 10.0)
            attention = next(x for x in got if isinstance(x, AttentionState) and x.person == "bob")
            assert attention.yaw_deg < 0  # bob is drawn right of ada: to her left
            # the drawn face turns with it (the scripted head is straight ahead)
            turned = receive(sub, lambda m: any(isinstance(x, FaceFrame) and x.frame_ns > attention.t_ns
                                                + round((attention.duration_s + 0.1) * NS) for x in m), 10.0)
            frame = next(x for x in reversed(turned) if isinstance(x, FaceFrame))
            assert frame.flexors["turn"] < -0.05, frame.flexors
            with AgentClient(config, agent="bob") as bob:
                bob.set_role("listening", speaker="user")
            with AgentClient(config, agent="ada") as ada:
                ada.user_speaking(True)
                time.sleep(1.0)  # the user's speech lasts a second (the stimulus, not a wait for something)
                ada.user_speaking(False)
            got = receive(sub, lambda m: {x.agent for x in m if isinstance(x, Nod)} >= nodders, 10.0)
            nods = [x for x in got if isinstance(x, Nod)]
            assert {n.agent for n in nods} == nodders
            ada_nod = next(n for n in nods if n.agent == "ada")
            middle = ada_nod.onset_ns + round(ada_nod.duration_s / 2 * NS)
            frames = receive(sub, lambda m: any(isinstance(x, FaceFrame) and x.frame_ns > middle + NS // 2
                                                for x in m), 10.0) + got
            during = [x.flexors["nod"] for x in frames if isinstance(x, FaceFrame)
                      and abs(x.frame_ns - middle) < ada_nod.duration_s / 4 * NS]
            after = [x.flexors["nod"] for x in frames if isinstance(x, FaceFrame) and x.frame_ns > middle + NS // 2]
            assert during and after
            nod_deg = float(load_toml("flexor_units")["head"]["nod_deg"])
            # near the middle of the nod the chin is down by most of its amplitude (the idle noise aside)
            assert min(during) < max(after) - 0.6 * ada_nod.amplitude_deg / nod_deg, (during, after)
        finally:
            sub.close()
