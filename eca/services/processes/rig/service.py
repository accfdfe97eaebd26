"""The rig service: each followed agent's face, retargeted, at every frame slot, on the bus and out to the
receivers people run (`eca rig`, `eca up --rig-vmc ... --rig-livelink ...`).

One thin loop: follow the agents' scenes from the bus (scene/bus_scene.py, as the renderer and the web service
do, without GL), and at each slot of a FrameSchedule at the rig rate (frames at k/rate of the master clock)
compose every agent's face for the slot's time (agent/face/scene.py), retarget the faces in one batch
(agent/rig), publish each as `stream.<agent>.rig` (protocol RigPose) and send it to its VMC receiver and to the
Live Link source (vmc.py, livelink.py) over non-blocking UDP (udp.py). A commanded change (role, emotion, head,
eye mode) that arrives between two slots is sent at once, by taking the next slot early (never sooner than
EARLY_GAP of a period after the last frame, so the rate stays the schedule's).

Following every agent of the instance (no [rig] agents named), it follows the agents created at run time too
(state.*.agents): each is published on the bus and, as a subject of its own, sent to the Live Link source; VMC
streams stay those of the configured agents (one receiver port each, fixed when the service starts).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from typing import Any

from eca.agent.face.batch import FaceBatch
from eca.agent.rig import Retargeter
from eca.protocol.endpoints import BusConfig
from eca.protocol.messages import AgentsState, Heartbeat, RigPose
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
from eca.services.processes.scene.rig_batch import compose_rig_batch
from eca.services.processes.scene.schedule import FrameSchedule

EARLY_GAP = 0.25  # a commanded change is sent this share of a period after the last frame at the soonest
_MAX_WAIT_S = 0.1


class RigService(Service):
    name = "rig"

    def __init__(self, config: BusConfig, rig_plan: RigPlan | None = None, **kwargs: Any) -> None:
        super().__init__(config, **kwargs)
        self.plan = rig_plan if rig_plan is not None else plan(RigOptions(), config.agents)
        self.agent_ids = self.plan.agents
        # every agent of the instance (none named): the created ones too, as they come and go
        self.scenes = BusScenes(self, self.agent_ids, follow=not self.plan.options.agents)
        if self.scenes.follow:
            self.scenes.on_agents = self._on_agents
        self.retargeter = Retargeter.load()
        self.faces = FaceBatch()  # the followed agents composed together at each slot
        options = self.plan.options
        self.vmc = {a: VmcPacker(options.vmc_names, options.vmc_neck_share)
                    for a in self.agent_ids[:len(self.plan.vmc)]}
        self.vmc_targets = dict(zip(self.agent_ids, self.plan.vmc, strict=False))
        self.livelink: dict[str, LiveLinkPacker] = {}
        if self.plan.livelink is not None:
            for agent in self.agent_ids:
                self._add_livelink(agent)
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

    def _add_livelink(self, agent: str) -> None:
        self.livelink[agent] = LiveLinkPacker(agent, device_id(self.config.instance, agent), self.plan.options.rate_hz)

    def _on_agents(self, msg: AgentsState) -> None:
        """The scenes followed the list; a created agent gets (and a removed one loses) its Live Link subject."""
        drawn = set(self.scenes.by_agent)
        for agent in [a for a in self.livelink if a not in drawn]:
            del self.livelink[agent]
        if self.plan.livelink is not None:
            for agent in drawn - set(self.livelink):
                self._add_livelink(agent)

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
        self.log.info("agents %s%s at %g Hz: stream.<agent>.rig on the bus%s", ", ".join(self.agent_ids),
                      " and those created at run time" if self.scenes.follow else "",
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
        batch = compose_rig_batch(self.scenes.views, frame_ns, self.retargeter, self.faces)
        head, eyes = batch.head_deg, batch.eyes_deg
        time_s = (frame_ns - self.started_ns) / 1e9
        livelink = self.plan.livelink
        for i, view in enumerate(self.scenes.views):
            agent = view.agent
            arkit, vrm = batch.arkit[i], batch.vrm[i]
            self.publish(RigPose(agent=agent, frame_ns=frame_ns, arkit=arkit.tolist(), head_deg=head[i].tolist(),
                                 eyes_deg=eyes[i].tolist(), visemes=batch.visemes[i].tolist(), vrm=vrm.tolist()))
            vmc = self.vmc.get(agent)
            if vmc is not None:
                target = self.vmc_targets[agent]
                self._senders[target.family].send(vmc.pack(arkit, vrm, head[i], eyes[i], time_s), target.sockaddr)
            packer = self.livelink.get(agent)
            if livelink is not None and packer is not None:
                self._senders[livelink.family].send(packer.pack(frame_ns, arkit, head[i], eyes[i]), livelink.sockaddr)
        self.frames += 1
        self._last_frame_ns = frame_ns

    def heartbeat(self) -> Heartbeat:
        beat = super().heartbeat()
        # datagrams the senders dropped count with the slots skipped
        return dataclasses.replace(beat, dropped=beat.dropped + sum(s.dropped for s in self._senders.values()))
