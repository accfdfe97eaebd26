"""Which face each agent is drawn with (eca/services/processes/renderer/faces.py): `--face` for all, the config's
[faces] table per agent, checked with messages that name the option or the key; a stage draws each agent with
its own drawer."""

from __future__ import annotations

import subprocess
from collections import deque
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from eca.agent.face.composed import ComposedFace
from eca.agent.face.scene import LiveScene
from eca.services.processes.renderer import DRAWERS, Stage
from eca.services.processes.renderer.faces import Drawers, agent_faces, check_face
from eca.services.processes.scene.bus_scene import AgentView
from eca.services.tools.child_processes import eca_command, subprocess_env


def test_a_face_is_a_known_kind_or_an_avatar_file(tmp_path: Path) -> None:
    assert check_face("flexor", "--face") == "flexor"
    avatar = tmp_path / "ada.glb"
    avatar.write_bytes(b"glTF")
    assert check_face(str(avatar), "--face") == str(avatar.resolve())
    with pytest.raises(ValueError, match=r"--face: unknown face 'egg'; faces: .*flexor.*\.glb, \.gltf or \.vrm"):
        check_face("egg", "--face")
    with pytest.raises(ValueError, match=r"--face: no avatar file at '.*missing\.vrm'"):
        check_face(str(tmp_path / "missing.vrm"), "--face")
    with pytest.raises(ValueError, match=r"\[faces\] ada: a face is a kind"):
        check_face(3, "[faces] ada")
    with pytest.raises(ValueError, match="a face is a kind"):
        check_face("x" * 5000, "--face")


def test_the_config_chooses_per_agent_and_the_command_line_for_all(tmp_path: Path) -> None:
    avatar = tmp_path / "bob.vrm"
    avatar.write_bytes(b"glTF")
    config = {"faces": {"bob": str(avatar)}}
    assert agent_faces(config, ["ada", "bob"]) == ["flexor", str(avatar.resolve())]
    assert agent_faces(config, ["ada", "bob"], "flexor") == ["flexor", "flexor"]
    assert agent_faces({}, ["ada"]) == ["flexor"]
    with pytest.raises(ValueError, match=r"\[faces\]: no agent 'cy' in this instance; agents: ada, bob"):
        agent_faces({"faces": {"cy": "flexor"}}, ["ada", "bob"])
    with pytest.raises(ValueError, match=r"\[faces\] ada: unknown face 'egg'"):
        agent_faces({"faces": {"ada": "egg"}}, ["ada"])
    with pytest.raises(ValueError, match=r"\[faces\] must be a table"):
        agent_faces({"faces": "flexor"}, ["ada"])


class RecordingDrawer:
    """A drawer that notes what it was asked to draw (no GL)."""

    size = (64, 48)

    def __init__(self, ctx: Any, size: tuple[int, int]) -> None:
        self.drawn: list[tuple[ComposedFace, tuple[int, int, int, int]]] = []

    def draw(self, face: ComposedFace, target: Any = None, **_: Any) -> Any:
        self.drawn.append((face, target.viewport))
        return target

    def release(self) -> None:
        pass


def test_a_stage_draws_each_agent_with_its_own_face(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(DRAWERS, "recording", RecordingDrawer)
    faces = agent_faces({"faces": {"bob": "recording"}}, ["ada", "bob", "cy"], None)
    assert faces == ["flexor", "recording", "flexor"]
    monkeypatch.setitem(DRAWERS, "flexor", RecordingDrawer)  # no GL in this test: the 2D face records too
    drawers = Drawers(ctx=None, size=(64, 48))  # type: ignore[arg-type]
    made = drawers.for_faces(faces)
    assert made[0] is made[2] and made[0] is not made[1]  # one drawer per face, shared by its agents
    views = [AgentView(agent, LiveScene(idle_noise=False), deque()) for agent in ("ada", "bob", "cy")]
    stage = Stage(made, views, fps=10.0)
    target = SimpleNamespace(viewport=(0, 0, 300, 100), scissor=None)
    stage.draw(stage.compose(0), target)  # type: ignore[arg-type]
    assert [viewport for _, viewport in made[1].drawn] == [(100, 0, 100, 100)]  # bob, in the middle
    assert [viewport for _, viewport in made[0].drawn] == [(0, 0, 100, 100), (200, 0, 100, 100)]
    with pytest.raises(ValueError, match="2 drawers for 3 agents"):
        Stage(made[:2], views, fps=10.0)


@pytest.mark.parametrize("argv", [["up", "--face", "nope.glb", "--seconds", "1"], ["snapshot", "--face", "egg", "-o",
                                                                                   "x.png"]])
def test_a_bad_face_on_the_command_line_is_one_line_and_exit_2(argv: list[str], tmp_path: Path) -> None:
    done = subprocess.run(eca_command(*argv), capture_output=True, text=True, env=subprocess_env(), cwd=tmp_path,
                          timeout=60)
    assert done.returncode == 2, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and "--face" in done.stderr, done.stderr
    assert not (tmp_path / "x.png").exists()


@pytest.mark.gl
def test_two_agents_of_one_instance_drawn_with_a_2d_and_a_3d_face() -> None:
    """One stage, two drawers on one context: the paper's 2D face on the left, eca's 3D head on the right, each
    in its own half, and each half what its drawer draws alone."""
    import numpy as np

    from eca.services.processes.renderer import OffscreenCanvas, read_rgb

    canvas = OffscreenCanvas((320, 120))
    try:
        drawers = Drawers(canvas.ctx, (160, 120))
        faces = agent_faces({"faces": {"bob": "head"}}, ["ada", "bob"])
        views = [AgentView(agent, LiveScene(idle_noise=False), deque()) for agent in ("ada", "bob")]
        stage = Stage(drawers.for_faces(faces), views, fps=10.0)
        composed = stage.compose(0)
        stage.draw(composed, canvas.screen)
        both = read_rgb(canvas.screen).astype(int)
        alone = []
        for face, made in zip(composed, drawers.for_faces(faces), strict=True):
            alone.append(read_rgb(made.draw(face)).astype(int))  # the drawer's own target, the panel's size
    finally:
        drawers.release()
        canvas.close()
    left, right = both[:, :160], both[:, 160:]
    assert left.std() > 10 and right.std() > 10  # a face in each half
    assert np.abs(left - alone[0]).mean() < 2.0 and np.abs(right - alone[1]).mean() < 2.0
    assert np.abs(left - right).mean() > 10  # two different faces
