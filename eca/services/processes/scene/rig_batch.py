"""Every followed agent's face at one instant as rig weights, in one batch: what the rig service sends to avatar
programs and the web service to the pages that draw faces themselves. The views' scenes are composed for the
instant together (agent/face/batch.py; each then forgets what no later frame needs), the faces retargeted together
(eca/agent/rig)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from eca.agent.face.batch import FaceBatch
from eca.agent.rig import Retargeter
from eca.agent.rig.frame import RigBatch
from eca.services.processes.scene.bus_scene import AgentView

# The bus message's ranges (protocol RigPose): a head turned further than a half turn, or an eye beyond 90
# degrees, is clipped there rather than refused.
HEAD_LIMIT_DEG, EYE_LIMIT_DEG = 180.0, 90.0


def compose_rig_batch(views: Sequence[AgentView], t_ns: int, retargeter: Retargeter, faces: FaceBatch) -> RigBatch:
    """The faces of `views` at master-clock time `t_ns`, composed together (`faces` keeps what stays between slots)
    and retargeted (row i: views[i]); each view's scene then forgets what no later frame needs."""
    flexors, eyes, head = faces.compose([view.scene for view in views], t_ns)
    for view in views:
        view.scene.prune(t_ns)
    np.clip(eyes, -EYE_LIMIT_DEG, EYE_LIMIT_DEG, out=eyes)
    np.clip(head, -HEAD_LIMIT_DEG, HEAD_LIMIT_DEG, out=head)
    return retargeter.retarget_many(flexors, t_ns, eyes_deg=eyes, head_deg=head)
