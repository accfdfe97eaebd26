"""The rig service: each agent's composed face, retargeted (eca/agent/rig), out to the receivers people run.

- options.py: the settings (config [rig], `eca rig ...`, `eca up --rig-...`), checked before anything starts;
- vmc.py: the VMC protocol's OSC bundle (VSeeFace, Warudo, VMagicMirror, EVMC4U, VMC4B ...);
- livelink.py: the Live Link Face packet (Unreal's Apple ARKit Live Link source);
- udp.py: a non-blocking UDP sender that drops what would block;
- service.py: the loop: follow the agents on the bus, compose and retarget every frame slot, publish
  `stream.<agent>.rig`, send.

No GL: the face is composed (scene/), never drawn.
"""
