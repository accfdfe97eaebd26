"""The 3D face: a glTF/VRM avatar (eca/services/processes/avatar/model.py) drawn as a `FaceDrawer`.

- drawer.py: `HeadDrawer`, the FaceDrawer (retarget, drive with avatar/drive.py, draw, multisample, overlays);
- gpu.py: an avatar uploaded once (vertices, morph deltas in float textures, textures, programs);
- shaders.py: morph targets and skinning once per vertex (transform feedback), face lighting and the toon step;
- skeleton.py: joint transforms with the face's joints moved, the skinning palette;
- order.py: the opaque primitives' drawing order, what lies in front first;
- camera.py: the "full" and "upper" framings measured on the avatar;
- lighting.py: key, fill and rim lights, skin and material parameters;
- overlay.py: the pupil marks and gaze trail;
- sample.py: a procedural head for tests, benchmarks and a first look.
"""

from eca.services.processes.renderer.head.drawer import DEFAULT_HEAD, HeadDrawer
from eca.services.processes.renderer.head.sample import sample_avatar

__all__ = ["DEFAULT_HEAD", "HeadDrawer", "sample_avatar"]
