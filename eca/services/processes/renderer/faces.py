"""Which face each agent is drawn with: a kind of the drawing seam (drawer.py: "flexor", the 2D face of the
paper, or another registered kind) or an avatar file (.glb, .gltf, .vrm). `--face` chooses for every agent of a
process; the runtime config's [faces] table chooses per agent (`ada = "head"`), so two agents of one instance
can have different faces. The default is the 2D flexor face."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from eca.services.processes.renderer.drawer import DRAWERS, FaceDrawer, make_drawer

if TYPE_CHECKING:  # choosing a face (the supervisor checks `--face`) loads no GL library
    import moderngl

DEFAULT_FACE = "flexor"
AVATAR_SUFFIXES = (".glb", ".gltf", ".vrm")
MAX_FACE_TEXT = 4096  # a kind or a path; longer is no face


def check_face(face: object, where: str) -> str:
    """A face choice as drawers take it: a registered kind, or an avatar file's absolute path. ValueError naming
    `where` (the option or the config key) for anything else."""
    if not isinstance(face, str) or not face or len(face) > MAX_FACE_TEXT:
        raise ValueError(f"{where}: a face is a kind ({', '.join(sorted(DRAWERS))}) or a .glb/.gltf/.vrm file, "
                         f"got {str(face)[:80]!r}")
    if face in DRAWERS:
        return face
    path = Path(face)
    if path.suffix.lower() in AVATAR_SUFFIXES:
        if not path.is_file():
            raise ValueError(f"{where}: no avatar file at {face!r}")
        return str(path.resolve())
    raise ValueError(f"{where}: unknown face {face!r}; faces: {', '.join(sorted(DRAWERS))}, or a .glb, .gltf or "
                     f".vrm file")


def agent_faces(config: Mapping[str, Any], agents: Sequence[str], face: str | None = None,
                where: str = "[faces]") -> list[str]:
    """The face of each of `agents`: `face` for all when given (a command line's --face), else the config's
    [faces] table (agent -> face), else the 2D face. ValueError names the option or the key."""
    if face is not None:
        return [check_face(face, "--face")] * len(agents)
    table = config.get("faces", {})
    if not isinstance(table, Mapping):
        raise ValueError(f"{where} must be a table of agent = face, got {type(table).__name__}")
    unknown = sorted(set(table) - set(agents))
    if unknown:
        raise ValueError(f"{where}: no agent {unknown[0]!r} in this instance; agents: {', '.join(agents)}")
    return [check_face(table.get(agent, DEFAULT_FACE), f"{where} {agent}") for agent in agents]


class Drawers:
    """The drawers of one GL context and picture size: one per face, made when first asked for and shared by
    the agents that have that face."""

    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        self.ctx, self.size = ctx, size
        self._made: dict[str, FaceDrawer] = {}

    def __call__(self, face: str) -> FaceDrawer:
        if face not in self._made:
            self._made[face] = make_drawer(self.ctx, self.size, face)
        return self._made[face]

    def for_faces(self, faces: Sequence[str]) -> list[FaceDrawer]:
        return [self(face) for face in faces]

    def release(self) -> None:
        for drawer in self._made.values():
            drawer.release()
        self._made.clear()
