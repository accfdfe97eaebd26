"""Materials as the drawer needs them: base colour factor and texture, alpha mode, sidedness, roughness, and VRM
MToon approximated as a toon flag with its shade colour.

- glTF: pbrMetallicRoughness' baseColorFactor (linear) and baseColorTexture; KHR_materials_unlit becomes a toon
  material whose shade is its base colour (no shading), as three-vrm draws VRM's unlit materials.
- VRM 1.0: the material's VRMC_materials_mtoon extension (shadeColorFactor, linear; default black).
- VRM 0.x: `VRM.materialProperties[i]` for materials[i], as three-vrm's 0.x importer reads it: shader
  "VRM/MToon" takes _Color (sRGB, alpha linear) and _ShadeColor (sRGB) as colours, _MainTex as the texture,
  keywordMap _ALPHABLEND_ON / _ALPHATEST_ON (with _Cutoff) as the alpha mode and _CullMode 0 as double-sided;
  "VRM/Unlit*" shaders are unlit; "VRM_USE_GLTFSHADER" keeps the glTF material.

Textures are decoded with Pillow (PNG, JPEG, WebP only), each image once, and only for materials a primitive
uses. An image's size is read from its header and checked (max_texture_pixels, and all images together
max_total_texture_pixels) before its pixels are decoded.
"""

from __future__ import annotations

import io
import re
import warnings

import numpy as np
import pygltflib as gl
from PIL import Image

from eca.services.processes.avatar.accessors import AccessorReader
from eca.services.processes.avatar.container import Container, read_uri
from eca.services.processes.avatar.errors import AvatarError, show
from eca.services.processes.avatar.fields import (
    JSON,
    as_index,
    as_object,
    get_number,
    get_numbers,
    get_object,
    get_str,
)
from eca.services.processes.avatar.limits import AvatarLimits
from eca.services.processes.avatar.meshes import Notes
from eca.services.processes.avatar.model import AlphaMode, Material, Texture

IMAGE_FORMATS = ("PNG", "JPEG", "WEBP")
DEFAULT_MATERIAL = Material(name="default", base_color=(0.8, 0.8, 0.8, 1.0))


def srgb_to_linear(value: float) -> float:
    """The gamma 2.2 decoding three-vrm applies to VRM 0.x's colours."""
    return float(max(value, 0.0) ** 2.2)


class TextureDecoder:
    """Decodes the document's images on demand, each once, within the pixel limits."""

    def __init__(self, document: gl.GLTF2, container: Container, reader: AccessorReader, limits: AvatarLimits,
                 notes: Notes) -> None:
        self.document = document
        self.container = container
        self.reader = reader
        self.limits = limits
        self.notes = notes
        self.pixels = 0
        self._images: dict[int, Texture] = {}

    def texture(self, index: int, where: str) -> Texture | None:
        """Texture `index`'s image, decoded (None when the texture has no image eca can find)."""
        source = self.document.textures[index].source
        if source is None:
            self.notes.add(f"{where}: textures[{index}] has no image eca reads")
            return None
        found = self._images.get(source)
        if found is None:
            found = self._decode(source)
            self._images[source] = found
        return found

    def _decode(self, index: int) -> Texture:
        image = self.document.images[index]
        where = f"images[{index}]"
        if image.bufferView is not None:
            data: bytes | memoryview = self.reader.view(image.bufferView)
        elif image.uri is not None:
            data = read_uri(self.container, image.uri, where, self.container.budget.left)
        else:
            raise AvatarError(f"{where} has neither a uri nor a bufferView")
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # Pillow's warnings on odd but readable files
                with Image.open(io.BytesIO(data), formats=IMAGE_FORMATS) as picture:
                    width, height = picture.size
                    pixels = width * height
                    if width < 1 or height < 1:
                        raise AvatarError(f"{where} is {width}x{height} pixels: no image")
                    if pixels > self.limits.max_texture_pixels:
                        raise AvatarError(f"{where} is {width}x{height} pixels, more than the limit of "
                                          f"{self.limits.max_texture_pixels} (max_texture_pixels)")
                    if self.pixels + pixels > self.limits.max_total_texture_pixels:
                        raise AvatarError(f"{where} ({width}x{height}) takes the images past "
                                          f"{self.limits.max_total_texture_pixels} pixels in all "
                                          "(max_total_texture_pixels)")
                    self.pixels += pixels
                    rgba = _rgba(picture)
        except AvatarError:
            raise
        except Image.DecompressionBombError as error:  # Pillow's own bound, far above ours, refused at its header
            claimed = re.search(r"\((\d+) pixels\)", str(error))
            size = f"{claimed.group(1)} pixels" if claimed else "more pixels than Pillow opens"
            raise AvatarError(f"{where} is {size} by its header, more than the limit of "
                              f"{self.limits.max_texture_pixels} (max_texture_pixels)") from None
        except Exception as error:  # noqa: BLE001 - a decoder of hostile bytes fails in many ways
            raise AvatarError(f"{where} is no PNG, JPEG or WebP image Pillow can decode: "
                              f"{show(str(error) or type(error).__name__, 100)}") from None
        rgba = np.ascontiguousarray(rgba)
        rgba.flags.writeable = False
        return Texture(rgba)


def _rgba(picture: Image.Image) -> np.ndarray:
    """A decoded image as (H, W, 4) uint8; 16- and 32-bit grey scaled down rather than clipped (Pillow's convert
    clips them to 255)."""
    if picture.mode.startswith("I"):
        grey = np.asarray(picture).astype(np.float64)
        top = 65535.0 if picture.mode.startswith("I;16") else max(float(grey.max()), 1.0)
        picture = Image.fromarray(np.clip(grey * (255.0 / top), 0, 255).astype(np.uint8))  # mode L
    return np.asarray(picture.convert("RGBA"), dtype=np.uint8)


def build_materials(document: gl.GLTF2, decoder: TextureDecoder, used: set[int], notes: Notes,
                    vrm0_properties: list[JSON] | None) -> list[Material]:
    """Material i of the document for each i (textures decoded for the `used` ones only)."""
    out = []
    for i, material in enumerate(document.materials):
        where = f"materials[{i}]"
        props = None
        if vrm0_properties is not None and i < len(vrm0_properties):
            props = as_object(vrm0_properties[i], f"extensions.VRM.materialProperties[{i}]")
        if props is not None and get_str(props, "shader", f"extensions.VRM.materialProperties[{i}]").startswith(
                ("VRM/MToon", "VRM/Unlit")):
            out.append(_vrm0_material(material, props, i, decoder if i in used else None, notes))
        else:
            out.append(_gltf_material(material, where, decoder if i in used else None))
    return out


def _gltf_material(material: gl.Material, where: str, decoder: TextureDecoder | None) -> Material:
    pbr = material.pbrMetallicRoughness
    color = tuple(float(v) for v in pbr.baseColorFactor)
    texture = None
    info = pbr.baseColorTexture
    if decoder is not None and info is not None:
        texture = decoder.texture(info.index, f"{where}.pbrMetallicRoughness.baseColorTexture")
        if info.texCoord:
            decoder.notes.add(f"{where}: its base colour texture uses TEXCOORD_{info.texCoord}; drawn with TEXCOORD_0")
    extensions = material.extensions or {}
    toon = False
    shade: tuple[float, ...] = (0.6, 0.6, 0.6)
    mtoon = extensions.get("VRMC_materials_mtoon")
    if isinstance(mtoon, dict):
        toon = True
        factor = get_numbers(mtoon, "shadeColorFactor", f"{where}.extensions.VRMC_materials_mtoon", 3)
        shade = factor if factor is not None else (0.0, 0.0, 0.0)
    elif "KHR_materials_unlit" in extensions:
        toon, shade = True, (color[0], color[1], color[2])
    return Material(
        name=material.name or where,
        base_color=(color[0], color[1], color[2], color[3]),
        texture=texture,
        alpha_mode=AlphaMode(material.alphaMode),
        alpha_cutoff=float(material.alphaCutoff),
        double_sided=bool(material.doubleSided),
        roughness=float(np.clip(pbr.roughnessFactor, 0.0, 1.0)),
        toon=toon,
        shade_color=(float(shade[0]), float(shade[1]), float(shade[2])),
    )


def _vrm0_material(material: gl.Material, props: dict[str, JSON], i: int, decoder: TextureDecoder | None,
                   notes: Notes) -> Material:
    where = f"extensions.VRM.materialProperties[{i}]"
    shader = get_str(props, "shader", where)
    vectors = get_object(props, "vectorProperties", where)
    floats = get_object(props, "floatProperties", where)
    keywords = get_object(props, "keywordMap", where)
    textures = get_object(props, "textureProperties", where)
    color = get_numbers(vectors, "_Color", f"{where}.vectorProperties", 4) or (1.0, 1.0, 1.0, 1.0)
    base = (srgb_to_linear(color[0]), srgb_to_linear(color[1]), srgb_to_linear(color[2]), float(color[3]))
    texture = None
    main = textures.get("_MainTex")
    if main is not None and decoder is not None:
        index = as_index(main, f"{where}.textureProperties._MainTex", len(decoder.document.textures), "textures")
        texture = decoder.texture(index, f"{where}.textureProperties._MainTex")
    cutoff = get_number(floats, "_Cutoff", f"{where}.floatProperties", 0.5)
    if shader == "VRM/MToon":
        blend = keywords.get("_ALPHABLEND_ON") is True
        test = keywords.get("_ALPHATEST_ON") is True
        alpha = AlphaMode.BLEND if blend else AlphaMode.MASK if test else AlphaMode.OPAQUE
        shade_raw = get_numbers(vectors, "_ShadeColor", f"{where}.vectorProperties", 4) or (0.97, 0.81, 0.86, 1.0)
        shade = (srgb_to_linear(shade_raw[0]), srgb_to_linear(shade_raw[1]), srgb_to_linear(shade_raw[2]))
        double_sided = get_number(floats, "_CullMode", f"{where}.floatProperties", 2.0) == 0.0
    else:  # VRM/UnlitTexture, UnlitCutout, UnlitTransparent, UnlitTransparentZWrite
        transparent = shader in ("VRM/UnlitTransparent", "VRM/UnlitTransparentZWrite")
        alpha = AlphaMode.BLEND if transparent else AlphaMode.MASK if shader == "VRM/UnlitCutout" else AlphaMode.OPAQUE
        shade = (base[0], base[1], base[2])
        double_sided = bool(material.doubleSided)
    return Material(
        name=material.name or f"materials[{i}]",
        base_color=base,
        texture=texture,
        alpha_mode=alpha,
        alpha_cutoff=cutoff,
        double_sided=double_sided,
        roughness=1.0,
        toon=True,
        shade_color=shade,
    )
