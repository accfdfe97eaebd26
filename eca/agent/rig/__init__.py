"""The composed face retargeted onto the rigs the world uses: ARKit blendshapes, Oculus visemes, VRM presets.

- names: the three vocabularies in canonical order and every spelling (`arkit_names`, `viseme_names`,
  `vrm_names`, lookups by any spelling);
- frame: `RigFrame` (one face) and `RigBatch` (many);
- mapping: flexors onto weights, row by row (`FlexorMap`); config: configs/rig.toml (`RigConfig`);
- lookat: eye angles as ARKit eyeLook weights and VRM 1.0 lookAt range maps, both ways;
- visemes: the 15 visemes and VRM's five vowels from the five mouth weights;
- retarget: `Retargeter`, a `ComposedFace` (or N flexor vectors) in, rig weights out.

Pure numpy and stdlib, like all of eca.agent: it knows nothing of the bus or of any sender.
"""

from eca.agent.rig.config import RigConfig, load_rig_config
from eca.agent.rig.frame import RigBatch, RigFrame
from eca.agent.rig.names import (
    ARKIT_NAMES,
    VISEME_NAMES,
    VRM0_NAMES,
    VRM_NAMES,
    arkit_index,
    arkit_names,
    canonical_arkit_name,
    viseme_index,
    viseme_names,
    vrm_index,
    vrm_names,
)
from eca.agent.rig.retarget import Retargeter

__all__ = [
    "ARKIT_NAMES",
    "VISEME_NAMES",
    "VRM0_NAMES",
    "VRM_NAMES",
    "RigBatch",
    "RigConfig",
    "RigFrame",
    "Retargeter",
    "arkit_index",
    "arkit_names",
    "canonical_arkit_name",
    "load_rig_config",
    "viseme_index",
    "viseme_names",
    "vrm_index",
    "vrm_names",
]
