"""Every followed agent's face at one instant as rig weights, in one batch: what the rig service sends to avatar
programs and the web service to the pages that draw faces themselves. Each view's scene is composed for the
instant (and forgets what no later frame needs), the faces retargeted together (eca/agent/rig)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from eca.agent.rig import Retargeter
from eca.agent.rig.frame import RigBatch
from eca.services.processes.scene.bus_scene import AgentView

# The bus message's ranges (protocol RigPose): a head turned further than a half turn, or an eye beyond 90
# degrees, is clipped there rather than refused.
HEAD_LIMIT_DEG, EYE_LIMIT_DEG = 180.0, 90.0


def compose_rig_batch(views: Sequence[AgentView], t_ns: int, retargeter: Retargeter) -> RigBatch:
    """The faces of `views` at master-clock time `t_ns`, retargeted (row i: views[i]); each view keeps its face."""
    faces = []
    for view in views:
        face = view.scene.compose(t_ns)
        view.scene.prune(t_ns)
        view.face = face
        faces.append(face)
    flexors = np.stack([face.frame.values for face in faces])
    eyes = np.array([[f.left_eye.yaw_deg, f.left_eye.pitch_deg, f.right_eye.yaw_deg, f.right_eye.pitch_deg]
                     for f in faces])
    head = np.array([[f.head_yaw_deg, f.head_pitch_deg, f.head_roll_deg] for f in faces])
    np.clip(eyes, -EYE_LIMIT_DEG, EYE_LIMIT_DEG, out=eyes)
    np.clip(head, -HEAD_LIMIT_DEG, HEAD_LIMIT_DEG, out=head)
    return retargeter.retarget_many(flexors, t_ns, eyes_deg=eyes, head_deg=head)
