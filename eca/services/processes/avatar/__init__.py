"""3D avatars as data: glTF 2.0 and VRM 0.x/1.0 files loaded into an `Avatar` (model.py) and driven from rig frames.
No GL here: the drawer is eca/services/processes/renderer/head/.

- `loader.load_avatar(path, limits=DEFAULT_LIMITS) -> Avatar`: .glb/.vrm, or .gltf with its buffers and images
  beside it; refuses what it cannot take (a broken or hostile file, a face that cannot blink, look or speak) with
  one `errors.AvatarError` naming the file and what is wrong, checked before anything follows the file's claims
  (`limits.AvatarLimits`).
- `drive.AvatarDriver(avatar).drive(rig_frame) -> AvatarPose`: the morph weights of every primitive and the turns
  of the head, neck, jaw and eye joints for one eca rig frame (eca/agent/rig/frame.py).

The modules in the order a file goes through them: container.py (GLB chunks, JSON), document.py (the glTF
document, checked), skeleton.py (the node tree), vrm.py (VRM 0.x/1.0), accessors.py and meshes.py (the binary
data), materials.py (colours, textures, MToon), shapes.py (morph-target names), capabilities.py (what the face
can show). Nothing is imported here, so the drawer's `from ...avatar.model import Avatar` stays light.
"""
