"""The whole chain across hosts (docs/deploy.md), each host a network namespace (as root; skipped otherwise): a
dialogue-manager host drives the agent of a model host over the bus (TCP + CURVE, its own key); a web host runs
`eca web` on the same bus (its own key) and draws the face; a viewer host watches it over WebRTC. The dialogue
manager's emotion command is seen by the viewer: the brows and the mouth of the face it decodes change.

The processes on the hosts are this module run as a script (`python -m tests.test_deploy_hosts ROLE ...`),
steered with files in a shared folder (one filesystem for every namespace).
"""

from __future__ import annotations

import re
import secrets
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from tests.support.bus import eca_command, running
from tests.support.netns import hosts, netns_available

pytestmark = pytest.mark.slow


def view(url: str, token: str, out: str, signals: str) -> int:
    """Viewer host: watch ada over WebRTC; save the face before and after the dialogue manager's command."""
    import asyncio

    from PIL import Image

    from tests.support.web_client import Client

    async def main() -> None:
        client = Client(url, ["ada"], token=token, video={"width": 320, "height": 240, "fps": 15})
        await client.connect()
        first = await client.frames("ada", "video", 8.0)
        assert len(first) > 20, f"{len(first)} pictures in 8 s"
        Image.fromarray(first[-1].to_ndarray(format="rgb24")).save(Path(out) / "before.png")
        print("READY", flush=True)
        while not (Path(signals) / "changed").exists():
            await client.frames("ada", "video", 0.05)  # keep the track drained while waiting
        after = await client.frames("ada", "video", 2.0)
        Image.fromarray(after[-1].to_ndarray(format="rgb24")).save(Path(out) / "after.png")
        print(f"DONE {len(first)} {len(after)}", flush=True)
        await client.pc.close()

    asyncio.run(main())
    return 0


def emote(config_path: str) -> int:
    """Dialogue-manager host: one command, acknowledged across the link."""
    from eca.protocol.client import AgentClient
    from eca.protocol.endpoints import load_bus_config

    with AgentClient(load_bus_config(config_path), agent="ada", source="dm", timeout_s=20.0) as client:
        client.wait_applied(client.set_emotion("surprised", 1.0, transition_s=0.2), timeout_s=20.0)
        print("APPLIED", flush=True)
    return 0


def main(argv: list[str]) -> int:
    role, *args = argv
    return {"view": view, "emote": emote}[role](*args)


def role_argv(role: str, *args: str) -> list[str]:
    return [sys.executable, "-m", "tests.test_deploy_hosts", role, *args]


@pytest.mark.skipif(netns_available() is not None, reason=f"{netns_available()}")
def test_a_dialogue_manager_drives_a_face_drawn_on_a_web_host_and_watched_from_a_viewer_host() -> None:
    from PIL import Image

    from tests.support.browser import band_change, head_box
    from tests.test_bus_curve import curve_setup, short_dir

    with short_dir() as tmp_path, hosts("dm", "model", "web", "viewer") as net:
        setup = curve_setup(tmp_path, host=net["model"].address, allow=("dm", "web"),
                            services=["dialogue", "gaze", "audio"])
        dm_config, web_config = setup.client("dm"), setup.client("web")
        signals = tmp_path / "signals"
        signals.mkdir()
        up = net["model"].argv(eca_command("up", "--config", str(setup.model), "--quiet", "--silent-audio"))
        with running(up) as (model_proc, model_out):
            model_out.wait_for("[up] ready in", 60.0)
            token = secrets.token_hex(16)  # a page off loopback needs one
            site = net["web"].argv(eca_command("web", "--config", str(web_config), "--web-host", net["web"].address,
                                               "--web-port", "0", "--web-token", token))
            with running(site) as (_, web_out):
                line = web_out.lines[web_out.wait_for("serving http://", 60.0)]
                match = re.search(r"(http://\S+/)", line)
                assert match and net["web"].address in match.group(1), line
                watch = role_argv("view", match.group(1).split("?")[0], token, str(tmp_path), str(signals))
                with running(net["viewer"].argv(watch)) as (viewer, view_out):
                    view_out.wait_for("READY", 60.0)
                    with running(net["dm"].argv(role_argv("emote", str(dm_config)))) as (dm, dm_out):
                        dm_out.wait_for("APPLIED", 30.0)
                        assert dm.wait(10) == 0
                    (signals / "changed").touch()  # the viewer keeps the last of the next 2 s of pictures
                    view_out.wait_for("DONE", 30.0)
                    assert viewer.wait(10) == 0, view_out.lines
            assert model_proc.poll() is None
        before = np.asarray(Image.open(tmp_path / "before.png"))
        after = np.asarray(Image.open(tmp_path / "after.png"))
        Image.fromarray(np.concatenate([before, after], axis=1)).save(Path(tempfile.gettempdir()) /
                                                                      "eca-deploy-hosts.png")  # to look at
    box = head_box(before)
    top, bottom, left, right = box
    assert bottom - top > 0.5 * before.shape[0], box  # a face, drawn on the web host
    brows = band_change(before, after, box, 0.22, 0.40)
    mouth = band_change(before, after, box, 0.62, 0.82)
    assert brows > 2.0 and mouth > 2.0, (brows, mouth)  # surprise, commanded from the dialogue manager's host


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
