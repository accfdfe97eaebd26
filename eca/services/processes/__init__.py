"""The long-running processes: each a thin loop from the bus into agent/ models and back.

`python -m eca.services.processes.run NAME` starts one (`run.py`): `broker.py`, `dialogue.py`, `gaze.py`, `audio/`,
`renderer/` and `web/`. What they share: `runtime.py` (the `Service` loop: bus sockets, heartbeats, bad input
reported), `liveness.py` (heartbeats straight to the supervisor), `heap.py` (a flood's memory goes back) and
`state_snapshot.py` (the dialogue state on disk). Nothing here imports from services/tools/.
"""
