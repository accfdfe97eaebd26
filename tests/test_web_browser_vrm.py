"""A VRM drawn by the page itself (three-vrm): the default head as a VRM 1.0 and as a VRM 0.x (stored facing -Z, as
0.x models are; tests/support/vrm.py) looks in the browser as the .glb does, at rest and with an emotion: the server
turns each avatar's face into its own morph weights and joint turns, and the page puts them in place, a 0.x model
turned as three-vrm turns it.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from eca.protocol.client import AgentClient
from eca.services.processes.avatar.loader import DEFAULT_HEAD
from eca.services.processes.dialogue import DialogueService
from eca.services.processes.web.options import WebOptions
from eca.services.processes.web.service import WebService
from tests.support.browser import browser_available, canvas_pixels, chromium, head_box, wait_for
from tests.support.bus import BrokerThread, ServiceThread, private_bus_config
from tests.support.vrm import vrm0_file, vrm1_file

pytestmark = [pytest.mark.slow, pytest.mark.skipif(browser_available() is not None, reason=str(browser_available())),
              pytest.mark.skipif(not DEFAULT_HEAD.exists(), reason="the default head is not baked")]


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("vrm")
    return {"glb": DEFAULT_HEAD, "vrm1": vrm1_file(tmp), "vrm0": vrm0_file(tmp)}


def drawn_by_page(face: Path, emotion: str) -> tuple[np.ndarray, dict[str, Any]]:
    """What a page shows of the agent with `face` and `emotion` (its description too)."""
    with private_bus_config(services=["dialogue"]) as config, BrokerThread(config), \
            ServiceThread(DialogueService(config)), AgentClient(config) as client:
        service = WebService(config, WebOptions(port=0, width=320, height=240, face=str(face), draw="browser"))
        with ServiceThread(service), chromium() as driver:
            client.wait_applied(client.set_emotion(emotion, transition_s=0.05), 10.0)
            driver.get(f"http://127.0.0.1:{service.port}/?mic=0&width=320&height=240")
            driver.find_element("id", "connect").click()
            wait_for(driver, "const f = window.eca.drawn.ada; return f ? f.stats.received : 0", 30.0,
                     "the page drawing the avatar", lambda n: n >= 10)
            time.sleep(0.5)  # past the first frames (the behaviour under test is the face shown)
            found = driver.execute_script("const f = window.eca.drawn.ada; "
                                          "return [f.targets.filter(Boolean).length, f.joints.filter(Boolean).length, "
                                          "f.d.format, !!f.vrm, f.d.primitives.filter((p) => p.targets).length, "
                                          "f.d.joints.length]")
            return canvas_pixels(driver), {"targets": found[0], "joints": found[1], "format": found[2],
                                           "vrm": found[3], "described_targets": found[4], "described_joints": found[5]}


@pytest.mark.parametrize("emotion", ["natural", "surprised"])
def test_a_vrm_drawn_by_the_page_looks_as_the_glb_does(files: dict[str, Path], emotion: str) -> None:
    shown = {kind: drawn_by_page(path, emotion) for kind, path in files.items()}
    glb, glb_found = shown["glb"]
    assert glb_found["format"] == "gltf" and not glb_found["vrm"]
    assert shown["vrm1"][1]["format"] == "vrm1" and shown["vrm0"][1]["format"] == "vrm0"
    assert all(found["vrm"] for kind, (_, found) in shown.items() if kind != "glb")  # three-vrm loaded them
    box = head_box(glb)
    top, bottom, left, right = box
    for kind in ("vrm1", "vrm0"):
        pixels, found = shown[kind]
        # every primitive and joint the server drives is found in the page's scene (a 0.x's eyes turn by shapes)
        assert found["targets"] == found["described_targets"] == glb_found["targets"], (kind, found)
        assert found["joints"] == found["described_joints"] == (4 if kind == "vrm1" else 2), (kind, found)
        assert np.abs(np.array(head_box(pixels)) - np.array(box)).max() <= 3, (kind, head_box(pixels), box)
        diff = np.abs(pixels[top:bottom, left:right].astype(int) - glb[top:bottom, left:right].astype(int))
        # the idle motion of separate runs moves a few edges; a model turned the wrong way, or a face part left
        # undriven, changes most of the head
        assert diff.mean() < 12.0 and (diff.max(axis=2) > 40).mean() < 0.12, (kind, diff.mean(),
                                                                            (diff.max(axis=2) > 40).mean())
