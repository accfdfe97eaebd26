"""The frames of the faces that pages draw themselves: at each frame slot, every such agent's face composed (the
same live scene the server's drawing composes), retargeted in one batch (agent/rig) and packed for its avatar
(browser_face.py). No GL and no video encoding: a frame of the default head is about 0.4 kB.

Each frame carries its time on the sender's NTP clock, the clock the voice track's RTCP sender reports speak
(aiortc stamps them from the wall clock when a packet leaves, and each voice packet leaves at its time on the
master clock): the page compares it with the time its audio receiver says it is playing now, and shows the
voice's part of a frame (the mouth) when its sound is heard.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path

from eca.agent.clock import Clock
from eca.agent.face.batch import FaceBatch
from eca.agent.rig import Retargeter
from eca.services.processes.scene.bus_scene import AgentView
from eca.services.processes.scene.rig_batch import compose_rig_batch
from eca.services.processes.web.browser_face import NTP_UNIX_OFFSET_MS, BrowserFace


def avatar_file(face: str) -> Path | None:
    """The avatar file a face choice (renderer/faces.py) draws, or None for a face only the server draws (the 2D
    flexor face)."""
    if face == "head":
        from eca.services.processes.avatar.loader import DEFAULT_HEAD  # pygltflib and PIL load only with an avatar

        return DEFAULT_HEAD
    path = Path(face)
    return path if path.suffix.lower() in (".glb", ".gltf", ".vrm") else None


def next_due_ns(due_ns: int, frame_ns: int, fps: float) -> int | None:
    """A reader at its own rate `fps` (a page, a Janus mountpoint) takes the slot at `frame_ns` when its next frame
    is due by then (`due_ns`): then when the one after is due, else None. Its own grid, a frame per period on
    average, whatever the slots' rate (they come at the fastest any reader asked)."""
    if frame_ns < due_ns:
        return None
    period_ns = int(1e9 / fps)
    return max(due_ns + period_ns, frame_ns + period_ns // 2)


class FaceFrames:
    """The browser-drawn faces of a web service's agents: their avatars (loaded once per file) and frames."""

    def __init__(self, faces: dict[str, str], size: tuple[int, int], clock: Clock) -> None:
        self.clock = clock
        self.size = size
        self.files = {agent: f for agent, face in faces.items() if (f := avatar_file(face)) is not None}
        self._by_file: dict[Path, BrowserFace] = {}
        self.slots = {agent: i for i, agent in enumerate(faces)}
        self._retargeter: Retargeter | None = None
        self._faces = FaceBatch()  # the agents composed together at each slot
        self.seq = 0
        self.sent = 0

    def prepare(self) -> None:
        """Load every avatar and work out what pages are told of it, before the service is ready: a page's offer
        and the first frames then cost no file read nor measuring (a second or more on a loaded machine)."""
        if self._retargeter is None and self.files:
            self._retargeter = Retargeter()
        for agent in self.files:
            self.face(agent).description(self.slots[agent], "")

    def drawable(self, agent: str) -> bool:
        """Whether a page can draw this agent (its face is an avatar file)."""
        return agent in self.files

    def face(self, agent: str) -> BrowserFace:
        """The agent's avatar as pages draw it (loaded on first use, shared by the agents with the same file)."""
        path = self.files[agent]
        if path not in self._by_file:
            from eca.services.processes.avatar.loader import load_avatar

            self._by_file[path] = BrowserFace(load_avatar(path), self.size)
        return self._by_file[path]

    def description(self, agent: str, url: str) -> dict[str, object]:
        return self.face(agent).description(self.slots[agent], url)

    def add(self, agent: str, face: str) -> None:
        """An agent created at run time."""
        if agent not in self.slots:  # the smallest free slot: slots stay small however many come and go
            used = set(self.slots.values())
            self.slots[agent] = next(i for i in range(len(used) + 1) if i not in used)
        path = avatar_file(face)
        if path is not None:
            self.files[agent] = path

    def remove(self, agent: str) -> None:
        self.files.pop(agent, None)
        self.slots.pop(agent, None)

    def make(self, views: Sequence[AgentView], t_ns: int, sounding: Callable[[str, int], bool]) -> dict[str, bytes]:
        """The frame at master-clock time `t_ns` of each of `views` (agents with an avatar face)."""
        if not views:
            return {}
        if self._retargeter is None:
            self._retargeter = Retargeter()
        batch = compose_rig_batch(views, t_ns, self._retargeter, self._faces)
        wall_offset_ns = time.time_ns() - self.clock.now_ns()
        time_ms = (t_ns + wall_offset_ns) / 1e6 + NTP_UNIX_OFFSET_MS
        self.seq += 1
        by_face: dict[Path, list[int]] = {}  # the agents of each avatar, packed together
        for i, view in enumerate(views):
            by_face.setdefault(self.files[view.agent], []).append(i)
        out: dict[str, bytes] = {}
        for rows in by_face.values():
            agents = [views[i].agent for i in rows]
            # the voice sounds then: an utterance of the lip-sync plays at t (its keys and clock anchors come ahead
            # of the sound), or the voice's own samples there are loud (they come only some 40 ms ahead)
            voiced = [self._faces.voiced[i] or sounding(agent, t_ns) for i, agent in zip(rows, agents, strict=True)]
            frames = self.face(agents[0]).pack_many(batch, rows, [self.slots[a] for a in agents], self.seq, time_ms,
                                                    voiced, mark=t_ns % 1_000_000_000 == 0)
            out.update(zip(agents, frames, strict=True))
        self.sent += len(out)
        return {view.agent: out[view.agent] for view in views}
