"""The bus across hosts (docs/protocol.md §15), in network namespaces as hosts (as root; skipped otherwise).

A model host runs `eca up` (broker, dialogue, audio) with its broker on TCP + CURVE bound to its own address; a
dialogue-manager host drives its agent over that link with its own key. A client with an unknown key gets
nothing through. The dialogue manager's link is cut for 5 s while a say plays and commands are sent, then
healed: the client says the link went down within the heartbeat timeout, the say ends exactly once, every state
a subscriber on the model host saw never went back in time, the state read back everywhere is the last commanded,
and a host that joins after the heal has it at once.

The processes on each host are this module run as a script (`python -m tests.test_bus_across_hosts ROLE ...`);
the test steers them with files in a shared folder (one filesystem for every namespace) and reads their lines.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import pytest

from tests.support.bus import eca_command, running
from tests.support.netns import hosts, netns_available

pytestmark = pytest.mark.slow

CUT_S = 5.0  # the partition's length (the one fixed wait: it is the stimulus)
NS = 1_000_000_000


# --- the processes on the hosts -------------------------------------------------------------------


def record_states(config_path: str, out: str) -> int:
    """Model host: print every state message and every speech ending as a JSON line, as it arrives."""
    import zmq

    from eca.protocol.bus import Subscriber
    from eca.protocol.endpoints import load_bus_config
    from eca.protocol.messages import TERMINAL_SPEECH_EVENTS

    config = load_bus_config(config_path)
    sub = Subscriber(zmq.Context.instance(), config, ["state.", "event.ada.speech_"])
    early = sub.wait_ready(20.0)
    print("READY", flush=True)
    with open(out, "a") as fh:
        for got in early:
            if got.message is not None:
                fh.write(json.dumps({"topic": got.topic, "t_ns": got.message.t_ns, "early": True}) + "\n")
        while True:
            got = sub.recv(1.0)
            if got is None or got.message is None:
                continue
            m = got.message
            line = {"topic": got.topic, "t_ns": m.t_ns, "seq": m.seq, "source": m.source,
                    "at_ns": time.monotonic_ns()}
            if m.TYPE == "emotion":
                line["emotion"] = [m.name, m.intensity]  # type: ignore[attr-defined]
            if isinstance(m, TERMINAL_SPEECH_EVENTS):
                line["ended"] = m.request_id  # type: ignore[attr-defined]
            fh.write(json.dumps(line) + "\n")
            fh.flush()


def rogue(config_path: str) -> int:
    """Dialogue-manager host, with a key the broker does not know: tries to listen, sends blind."""
    import zmq

    from eca.protocol.bus import BusTimeout, Publisher, Subscriber
    from eca.protocol.endpoints import load_bus_config
    from eca.protocol.messages import SetEmotion

    config = load_bus_config(config_path)
    ctx = zmq.Context()
    sub = Subscriber(ctx, config, [""])
    try:
        sub.wait_ready(3.0)
        print("ROGUE GOT IN", flush=True)
    except BusTimeout as exc:
        print(f"ROGUE REFUSED {exc}", flush=True)
    pub = Publisher(ctx, config, "rogue")
    for i in range(10):
        pub.publish(SetEmotion(agent="ada", request_id=f"rogue-{i}", name="frightened", intensity=1.0))
    time.sleep(0.5)  # a window for anything to come through: the claim is that nothing does
    print(f"ROGUE SAW {len(sub.drain())}", flush=True)
    return 0


def drive(config_path: str, signals: str) -> int:
    """Dialogue-manager host: say, then (told of the cut) notice the link down, command blind, and after the
    heal wait for the say's end and the last command's acknowledgement."""
    import numpy as np

    from eca.protocol.client import AgentClient
    from eca.protocol.endpoints import load_bus_config
    from eca.protocol.messages import Say

    config = load_bus_config(config_path)
    flags = Path(signals)

    def wait_flag(name: str) -> None:
        while not (flags / name).exists():
            time.sleep(0.02)

    t = np.arange(int(3.0 * 16_000)) / 16_000
    pcm = (0.2 * np.sin(2 * np.pi * 220 * t) * 32767).astype("<i2").tobytes()
    with AgentClient(config, agent="ada", source="dm", timeout_s=20.0) as client:
        client.wait_applied(client.set_emotion("happy", 0.8, transition_s=0.0), timeout_s=20.0)
        say = client.send(Say(agent="ada", request_id="say-across", pcm=pcm, sample_rate=16_000))
        client.wait_applied(say, timeout_s=20.0)
        print("SAID", flush=True)
        wait_flag("cut")
        cut = time.monotonic()
        while client.link_up():
            time.sleep(0.02)
        print(f"LINK DOWN after {time.monotonic() - cut:.2f} s", flush=True)
        client.set_emotion("surprised", 0.3, transition_s=0.0)  # blind: queued until the heal, or lost
        last = client.set_emotion("angry", 0.6, transition_s=0.0)
        print("SENT", flush=True)
        wait_flag("healed")
        healed = time.monotonic()
        client.wait_applied(last, timeout_s=30.0)  # sent again until acknowledged (once applied)
        while not client.link_up() and time.monotonic() - healed < 10.0:
            time.sleep(0.02)  # each socket reconnects on its own: the heartbeats' may come a moment later
        print(f"LINK {'UP' if client.link_up() else 'DOWN'} after {time.monotonic() - healed:.2f} s", flush=True)
        ended = client.wait_for_speech("say-across", timeout_s=30.0)
        print(f"ENDED {ended.TYPE}", flush=True)
        emotion = client.state["emotion"]
        print(f"STATE {emotion.name} {emotion.intensity}", flush=True)  # type: ignore[attr-defined]
    # a host that joins now has the current state at once: the broker's snapshot
    with AgentClient(config, agent="ada", source="late", timeout_s=20.0) as late:
        emotion = late.state["emotion"]
        print(f"LATE {emotion.name} {emotion.intensity}", flush=True)  # type: ignore[attr-defined]
    return 0


def main(argv: list[str]) -> int:
    role, *args = argv
    return {"record": record_states, "rogue": rogue, "drive": drive}[role](*args)


# --- the test ---------------------------------------------------------------------------------------


def role_argv(role: str, *args: str) -> list[str]:
    return [sys.executable, "-m", "tests.test_bus_across_hosts", role, *args]


@pytest.mark.skipif(netns_available() is not None, reason=f"{netns_available()}")
def test_a_dialogue_manager_across_a_partition_gets_the_last_state_and_one_ending() -> None:
    from tests.test_bus_curve import curve_setup, short_dir

    with short_dir() as tmp_path, hosts("dm", "model") as net:
        dm_host, model_host = net["dm"], net["model"]
        setup = curve_setup(tmp_path, host=model_host.address, services=["dialogue", "audio"])
        dm_config, rogue_config = setup.client("dm"), setup.client("rogue")
        signals = tmp_path / "signals"
        signals.mkdir()
        states = tmp_path / "states.jsonl"
        up = model_host.argv(eca_command("up", "--config", str(setup.model), "--quiet"))
        with running(up) as (proc, up_out):
            up_out.wait_for("[up] ready in", 60.0)
            with running(model_host.argv(role_argv("record", str(setup.model), str(states)))) as (_, rec_out):
                rec_out.wait_for("READY", 20.0)
                # an unknown key: refused, and what it sends blind never applied
                with running(dm_host.argv(role_argv("rogue", str(rogue_config)))) as (rogue_proc, rogue_out):
                    rogue_out.wait_for("ROGUE SAW", 20.0)
                    assert rogue_proc.wait(10) == 0
                assert any("ROGUE REFUSED" in line and "refused this host's key" in line for line in rogue_out.lines)
                assert "ROGUE SAW 0" in rogue_out.lines
                with running(dm_host.argv(role_argv("drive", str(dm_config), str(signals)))) as (drv, out):
                    out.wait_for("SAID", 40.0)
                    dm_host.cut()
                    cut_at = time.monotonic_ns()
                    (signals / "cut").touch()
                    try:
                        out.wait_for("SENT", 10.0)
                        time.sleep(max(0.0, CUT_S - (time.monotonic_ns() - cut_at) / NS))
                    finally:
                        dm_host.heal()
                    healed_at = time.monotonic_ns()
                    (signals / "healed").touch()
                    out.wait_for("LATE", 60.0)
                    assert drv.wait(10) == 0, out.lines
                lines = list(out.lines)
            assert proc.poll() is None, "eca up stopped"
        up_lines = list(up_out.lines)
        recorded = states.read_text()
    down = next(line for line in lines if line.startswith("LINK DOWN after"))
    # the client said so within the heartbeat timeout (1.5 s) of the broker's last beat (4 Hz), plus its polling
    assert float(down.split()[3]) <= 1.5 + 0.25 + 0.3, lines
    up_again = next(line for line in lines if line.startswith("LINK UP after"))
    assert float(up_again.split()[3]) <= 3.0, lines  # a connect retried every second, not TCP's back-off
    assert "ENDED speech_finished" in lines, lines
    assert "STATE angry 0.6" in lines and "LATE angry 0.6" in lines, lines
    records = [json.loads(line) for line in recorded.splitlines()]
    # every state the model host saw, during the partition and after the heal: never back in time per topic
    last: dict[str, int] = {}
    for r in records:
        if r["topic"].startswith("state."):
            assert r["t_ns"] >= last.get(r["topic"], 0), (r, last.get(r["topic"]))
            last[r["topic"]] = r["t_ns"]
    emotions = [r["emotion"] for r in records if "emotion" in r]
    assert emotions[-1] == ["angry", 0.6]
    assert ["frightened", 1.0] not in emotions  # the rogue's command was never applied
    after_heal = [e for r in records if "emotion" in r and r["at_ns"] > healed_at for e in [r["emotion"]]]
    # after the heal, nothing older than the last commanded came back as current
    assert after_heal and after_heal[-1] == ["angry", 0.6]
    assert all(e in (["surprised", 0.3], ["angry", 0.6]) for e in after_heal), after_heal
    ended = [r["ended"] for r in records if "ended" in r]
    assert ended == ["say-across"], ended  # the say ended exactly once
    assert any("unauthorized" in line or "refused a CURVE handshake" in line for line in up_lines), up_lines[-20:]


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
