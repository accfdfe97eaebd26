"""The live face without GL: from the bus to each agent's live scene (bus_scene.py: what a process that shows
the live face subscribes to, and how each message becomes a scene call) and when each frame is composed and
shown (schedule.py). The renderer, the web service and the pipecat face draw what these compose."""
