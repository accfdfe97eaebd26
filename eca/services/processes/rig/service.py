"""The rig service: each followed agent's face, retargeted, at every frame slot, on the bus and out to the
receivers people run (`eca rig`, `eca up --rig-vmc ... --rig-livelink ...`).

One thin loop: follow the agents' scenes from the bus (scene/bus_scene.py, as the renderer and the web service
do, without GL), and at each slot of a FrameSchedule at the rig rate (frames at k/rate of the master clock)
compose every agent's face for the slot's time (agent/face/scene.py), retarget the faces in one batch
(agent/rig), publish each as `stream.<agent>.rig` (protocol RigPose) and send it to its VMC receiver and to the
Live Link source (vmc.py, livelink.py) over non-blocking UDP (udp.py). A commanded change (role, emotion, head,
eye mode) that arrives between two slots is sent at once, by taking the next slot early (never sooner than
EARLY_GAP of a period after the last frame, so the rate stays the schedule's).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from typing import Any

import numpy as np

from eca.agent.rig import Retargeter
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import Heartbeat, RigPose
from eca.services.processes.rig.livelink import LiveLinkPacker, device_id
from eca.services.processes.rig.options import (
    RigOptions,
    RigOptionsError,
    RigPlan,
    add_arguments,
    flag_names,
    given,
    options_from,
    plan,
)
from eca.services.processes.rig.udp import UdpSender
from eca.services.processes.rig.vmc import VmcPacker
from eca.services.processes.runtime import Service, parse_service_args
from eca.services.processes.scene.bus_scene import BusScenes
from eca.services.processes.scene.schedule import FrameSchedule

EARLY_GAP = 0.25  # a commanded change is sent this share of a period after the last frame at the soonest
_MAX_WAIT_S = 0.1
# The bus message's ranges (protocol RigPose): a head turned further than a half turn, or an eye beyond 90
# degrees, is clipped there rather than refused.
_HEAD_LIMIT, _EYE_LIMIT = 180.0, 90.0


class RigService(Service):
    name = "rig"

    def __init__(self, config: BusConfig, rig_plan: RigPlan | None = None, **kwargs: Any) -> None:
        super().__init__(config, **kwargs)
        self.plan = rig_plan if rig_plan is not None else plan(RigOptions(), config.agents)
        self.agent_ids = self.plan.agents
        self.scenes = BusScenes(self, self.agent_ids)
        self.retargeter = Retargeter.load()
        options = self.plan.options
        self.vmc = [VmcPacker(options.vmc_names, options.vmc_neck_share) for _ in self.plan.vmc]
        self.livelink = [LiveLinkPacker(a, device_id(config.instance, a), options.rate_hz) for a in self.agent_ids] \
            if self.plan.livelink is not None else []
        self._senders: dict[int, UdpSender] = {}  # one socket per address family
        self.schedule: FrameSchedule | None = None
        self.frames = 0  # frames composed and sent
        self._last_frame_ns = -(1 << 62)

    @classmethod
    def from_args(cls, config: BusConfig, argv: list[str], **kwargs: Any) -> RigService:
        parser = argparse.ArgumentParser(prog="python -m eca.services.processes.run rig", add_help=False,
                                         exit_on_error=False)
        add_arguments(parser)
        args = parse_service_args("rig", argv, parser)
        try:
            cli = given(args)
            options = options_from(dict(config.raw.get("rig", {})), cli)
            return cls(config, plan(options, config.agents, flag_names(cli)), **kwargs)
        except RigOptionsError as exc:
            print(f"[rig] ERROR {exc}", file=sys.stderr)
            raise SystemExit(2) from None

    def subscriptions(self) -> list[str]:
        return self.scenes.subscriptions()

    # --- start and stop -------------------------------------------------------------------------

    def setup(self) -> None:
        targets = [*self.plan.vmc, *([self.plan.livelink] if self.plan.livelink else [])]
        for target in targets:
            if target.family not in self._senders:
                self._senders[target.family] = UdpSender(target.family)
        self.schedule = FrameSchedule(self.clock, self.plan.options.rate_hz, t0_ns=0)
        out = [f"VMC to {', '.join(t.label for t in self.plan.vmc)} ({'+'.join(self.plan.options.vmc_names)})"
               if self.plan.vmc else "",
               f"Live Link to {self.plan.livelink.label}" if self.plan.livelink else ""]
        self.log.info("agents %s at %g Hz: stream.<agent>.rig on the bus%s", ", ".join(self.agent_ids),
                      self.plan.options.rate_hz, "".join(f"; {o}" for o in out if o))

    def teardown(self) -> None:
        dropped = sum(s.dropped for s in self._senders.values())
        if self.frames:
            reasons = {s.last_error for s in self._senders.values() if s.last_error}
            self.log.info("sent %d frames (%d slots skipped, %d datagrams dropped%s)", self.frames,
                          self.schedule.dropped if self.schedule else 0, dropped,
                          f": {'; '.join(sorted(reasons))}" if reasons else "")
        for sender in self._senders.values():
            sender.close()
        self._senders.clear()

    # --- the loop -------------------------------------------------------------------------------

    def run_once(self) -> None:
        assert self.sub is not None and self.schedule is not None
        now = self.clock.now_ns()
        self.beat_if_due(now)
        schedule = self.schedule
        if now >= self._next_frame_ns(schedule):
            self.scenes.drain()
            early = now < schedule.due_ns
            self.scenes.commanded = False  # this frame shows it
            self.send_frame(now if early else schedule.due_ns)
            self.dropped += schedule.advance()
        else:
            due = min(self._next_frame_ns(schedule), self._next_beat_ns)
            wait_s = max(0.0, min(_MAX_WAIT_S, (due - now) / 1e9))
            if self.sub.socket.poll(math.ceil(wait_s * 1000)):
                self.scenes.drain()  # a commanded change is seen now, and sent as soon as EARLY_GAP allows
        self._check_parent()

    def _next_frame_ns(self, schedule: FrameSchedule) -> int:
        if self.scenes.commanded:
            return schedule.early_due_ns(self._last_frame_ns, EARLY_GAP)
        return schedule.due_ns

    def send_frame(self, frame_ns: int) -> None:
        """Compose every agent's face for `frame_ns`, retarget them together, publish and send them."""
        faces = []
        for view in self.scenes.views:
            face = view.scene.compose(frame_ns)
            view.scene.prune(frame_ns)
            view.face = face
            faces.append(face)
        flexors = np.stack([face.frame.values for face in faces])
        eyes = np.array([[f.left_eye.yaw_deg, f.left_eye.pitch_deg, f.right_eye.yaw_deg, f.right_eye.pitch_deg]
                         for f in faces])
        head = np.array([[f.head_yaw_deg, f.head_pitch_deg, f.head_roll_deg] for f in faces])
        np.clip(eyes, -_EYE_LIMIT, _EYE_LIMIT, out=eyes)
        np.clip(head, -_HEAD_LIMIT, _HEAD_LIMIT, out=head)
        batch = self.retargeter.retarget_many(flexors, frame_ns, eyes_deg=eyes, head_deg=head)
        time_s = (frame_ns - self.started_ns) / 1e9
        livelink = self.plan.livelink
        for i, agent in enumerate(self.agent_ids):
            arkit, vrm = batch.arkit[i], batch.vrm[i]
            self.publish(RigPose(agent=agent, frame_ns=frame_ns, arkit=arkit.tolist(), head_deg=head[i].tolist(),
                                 eyes_deg=eyes[i].tolist(), visemes=batch.visemes[i].tolist(), vrm=vrm.tolist()))
            if self.vmc:
                target = self.plan.vmc[i]
                self._senders[target.family].send(self.vmc[i].pack(arkit, vrm, head[i], eyes[i], time_s),
                                                  target.sockaddr)
            if livelink is not None:
                self._senders[livelink.family].send(self.livelink[i].pack(frame_ns, arkit, head[i], eyes[i]),
                                                    livelink.sockaddr)
        self.frames += 1
        self._last_frame_ns = frame_ns

    def heartbeat(self) -> Heartbeat:
        beat = super().heartbeat()
        # datagrams the senders dropped count with the slots skipped
        return dataclasses.replace(beat, dropped=beat.dropped + sum(s.dropped for s in self._senders.values()))
