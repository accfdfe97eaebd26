"""`AvatarLimits`: how much of a file the loader takes before it refuses it, checked before anything follows it.

A glTF file says how big its parts are (buffers, counts, image sizes); a hostile or broken one says more than it
holds, or asks for more than a face needs. Each limit is checked against what the file claims before the loader
reads, allocates or decodes anything the claim leads to, and a refusal names the limit. The defaults take every
real avatar we know of (a VRoid or Ready Player Me export is a few MB, ~10^4-10^5 vertices, ~100 morph targets
on the face, a few 2048-px textures) with room to spare, and keep a hostile file's cost to about a second and a
few hundred MB at worst.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

MIB = 1 << 20


@dataclass(frozen=True)
class AvatarLimits:
    """Upper bounds on what one avatar file may hold; see the module docstring."""

    max_file_bytes: int = 256 * MIB  # the file itself, and every external buffer and image it names, together
    max_json_bytes: int = 64 * MIB  # the glTF JSON (a GLB's JSON chunk, or a .gltf file with its data URIs)
    max_json_depth: int = 64  # nesting of JSON objects and lists (glTF needs about 8; extras a few more)
    max_json_values: int = 4_000_000  # JSON values in all (objects, lists, strings, numbers ...)
    max_buffers: int = 256
    max_buffer_views: int = 65_536
    max_accessors: int = 65_536
    max_nodes: int = 16_384
    max_node_depth: int = 256  # levels below a root (hair and skirt chains run 30-50 deep)
    max_meshes: int = 4_096
    max_primitives: int = 4_096  # in all meshes together
    max_targets: int = 512  # morph targets per primitive ("Perfect Sync" faces carry ~110)
    max_vertices: int = 1 << 21  # per primitive (and per accessor a primitive reads)
    max_indices: int = 1 << 24  # per primitive
    max_total_vertices: int = 1 << 23  # all primitives together, counted once per use
    max_total_indices: int = 1 << 25  # all primitives together
    max_total_targets: int = 1 << 16  # morph targets of all primitives together
    max_total_target_vertices: int = 1 << 24  # sum over primitives of vertices x morph targets
    max_skins: int = 1_024
    max_joints: int = 4_096  # per skin
    max_materials: int = 4_096
    max_textures: int = 4_096
    max_images: int = 256
    max_texture_pixels: int = 4096 * 4096  # per image, from its header, before decoding it
    max_total_texture_pixels: int = 4 * 4096 * 4096  # all decoded images together
    max_expressions: int = 1_024
    max_binds: int = 4_096  # morph-target binds per expression
    max_bind_targets: int = 1 << 18  # the (bind, primitive) pairs all expressions reach together

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"AvatarLimits.{f.name} must be a positive integer, got {value!r}")


DEFAULT_LIMITS = AvatarLimits()
