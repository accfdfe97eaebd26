"""GLSL of the 3D head, in two passes per frame.

1. Deform (`DEFORM`, transform feedback, no pixels): each vertex of a morphed or skinned primitive once, its
   morph targets blended and its joints skinned, into a buffer of model-frame positions and normals. Software GL
   (llvmpipe) shades a vertex again for every batch of triangles that uses it, and a morph target is a texture
   fetch per vertex: doing it once per vertex is several times cheaper than doing it in the drawing pass.
2. Draw (`DRAW_VERTEX`, `FRAGMENT`): the deformed (or rigid) vertices to the camera, lit per vertex; the pixel
   multiplies its base colour by that light.

Morph targets: each primitive's deltas lie in one RGBA float texture, target after target, each vertex's at texel
target * V + vertex, in rows of 2^DELTA_SHIFT texels: the position's delta in RGB, the normal's packed into the bits
of A (9 bits an axis, gpu.pack_normals), so a target costs one fetch per vertex. Per frame only the targets whose
weight is not zero are passed, as (target, weight) pairs, so the loop is as long as the number of shapes in use,
not the number the avatar has (52 or more). gl_VertexID is the vertex's index.

Light: computed in linear RGB (lighting.py's rig: wrapped key, fill, hemispheric ambient, rim) per vertex and
encoded there with a 2.2 power; the pixel multiplies it by its base colour as stored (sRGB texels and the
encoded base colour factor). A power law turns a product into the product of the powers, so the picture is the
encoding of linear base colour times linear light, without a per-pixel power or sRGB decode, which software GL
pays for on every pixel. (The light is interpolated across a triangle in its encoded form: on a head of thousands
of vertices that is invisible.) Toon materials interpolate n.l instead and take the two-tone step per pixel;
glossy ones (an eye's cornea) add a per-pixel highlight.

Each combination a primitive needs (morphs, skinning, texture, alpha mask, toon, two sides, gloss) is its own
small program built from these sources with #defines: llvmpipe runs both sides of every branch.
"""

from __future__ import annotations

DEFORM = """
#version 330
#define MORPHS __MORPHS__              // the most (target, weight) pairs a frame passes (0: no targets)
#define MORPH_NORMALS __MORPH_NORMALS__
#define SKINNED __SKINNED__
#define JOINTS __JOINTS__
#define DELTA_SHIFT __DELTA_SHIFT__        // the delta texture is 1 << DELTA_SHIFT texels wide

#if SKINNED
layout(std140) uniform Joints { mat4 u_joints[JOINTS]; };  // model from bind pose, per joint (skin palette)
in vec4 in_joints;
in vec4 in_weights;
#endif
#if MORPHS
uniform sampler2D u_deltas;
uniform int u_vertices;  // the primitive's vertex count
uniform int u_active;    // how many (target, weight) pairs follow
uniform vec2 u_morph[MORPHS];
uniform float u_normal_scale;  // the packed normal deltas' range: +- this
// A power of two wide, so the row and column are a shift and a mask: SIMD has no integer division.
ivec2 texel(int i) { return ivec2(i & ((1 << DELTA_SHIFT) - 1), i >> DELTA_SHIFT); }
#endif

in vec3 in_pos;
in vec3 in_normal;
out vec3 out_pos;
out vec3 out_normal;

void main() {
    vec3 pos = in_pos;
    vec3 nrm = in_normal;
#if MORPHS
    for (int k = 0; k < u_active; ++k) {
        vec4 delta = texelFetch(u_deltas, texel(int(u_morph[k].x) * u_vertices + gl_VertexID), 0);
        float w = u_morph[k].y;
        pos += w * delta.xyz;
#if MORPH_NORMALS
        uint bits = floatBitsToUint(delta.w);  // 9 bits per axis (gpu.pack_normals)
        vec3 q = vec3(uvec3(bits, bits >> 9u, bits >> 18u) & 511u) / 511.0;
        nrm += w * (q * 2.0 - 1.0) * u_normal_scale;
#endif
    }
#endif
#if SKINNED
    mat4 skin = in_weights.x * u_joints[int(in_joints.x)] + in_weights.y * u_joints[int(in_joints.y)]
              + in_weights.z * u_joints[int(in_joints.z)] + in_weights.w * u_joints[int(in_joints.w)];
    pos = (skin * vec4(pos, 1.0)).xyz;
    nrm = mat3(skin) * nrm;  // joints turn and move; a uniform scale only lengthens it (normalised later)
#endif
    out_pos = pos;
    out_normal = nrm;
}
"""

DRAW_VERTEX = """
#version 330
#define TOON __TOON__
#define DOUBLE_SIDED __DOUBLE_SIDED__
#define GLOSSY __GLOSSY__

uniform mat4 u_modelview;    // camera from the vertices' frame (model, or a rigid primitive's node): rigid
uniform mat4 u_proj;
uniform float u_wrap;        // how far diffuse light wraps past the terminator (0: Lambert)
uniform vec3 u_wrap_tint;    // per channel: red wraps furthest, as light scattered under skin does
// The face's lights, camera space (x right, y up, z toward the camera); directions point toward the light.
uniform vec3 u_key_dir;
uniform vec3 u_key;
uniform vec3 u_fill_dir;
uniform vec3 u_fill;
uniform vec3 u_rim_dir;
uniform vec3 u_rim;
uniform vec3 u_sky;          // ambient from above
uniform vec3 u_ground;       // ambient from below
uniform float u_exposure;

in vec3 in_pos;
in vec3 in_normal;
in vec2 in_uv;

out vec2 v_uv;
out vec3 v_light;            // encoded (power 1 / 2.2) light on the front side
#if DOUBLE_SIDED
out vec3 v_light_back;       // ... and on the back side
#endif
#if TOON
out float v_ndl;             // n.l of the key light, for the per-pixel step
#endif
#if GLOSSY
out vec3 v_normal;
out vec3 v_pos;
#endif

vec3 encode(vec3 linear) { return pow(max(linear * u_exposure, 0.0), vec3(1.0 / 2.2)); }

vec3 light(vec3 n, vec3 v) {
    float edge = 1.0 - max(dot(n, v), 0.0);
    vec3 rim = u_rim * (edge * edge * edge) * clamp(dot(n, u_rim_dir) + 0.6, 0.0, 1.0);
#if TOON
    return u_key + 0.5 * u_sky + rim;  // the step between the two tones is the pixel's (FRAGMENT)
#else
    vec3 w = u_wrap * u_wrap_tint;
    vec3 key = clamp((vec3(dot(n, u_key_dir)) + w) / (1.0 + w), 0.0, 1.0);
    float fill = clamp((dot(n, u_fill_dir) + u_wrap) / (1.0 + u_wrap), 0.0, 1.0);
    vec3 ambient = mix(u_ground, u_sky, 0.5 + 0.5 * n.y);
    return key * u_key + fill * u_fill + ambient + rim;
#endif
}

void main() {
    vec4 cam = u_modelview * vec4(in_pos, 1.0);
    vec3 n = normalize(mat3(u_modelview) * in_normal);
    vec3 v = normalize(-cam.xyz);
    v_uv = in_uv;
    v_light = encode(light(n, v));
#if DOUBLE_SIDED
    v_light_back = encode(light(-n, v));
#endif
#if TOON
    v_ndl = dot(n, u_key_dir);
#endif
#if GLOSSY
    v_normal = n;
    v_pos = cam.xyz;
#endif
    gl_Position = u_proj * cam;
}
"""

FRAGMENT = """
#version 330
#define TEXTURED __TEXTURED__
#define MASK __MASK__
#define BLEND __BLEND__
#define TOON __TOON__
#define DOUBLE_SIDED __DOUBLE_SIDED__
#define GLOSSY __GLOSSY__

uniform vec4 u_base;         // base colour factor: RGB encoded (power 1 / 2.2), alpha as is
uniform sampler2D u_tex;     // base colour texture, sRGB as stored
uniform float u_cutoff;      // alpha mask cut-off
uniform vec3 u_shade;        // toon: the shade tone (encoded), times the base colour
uniform float u_ramp;        // toon: the half-width of the step between the two tones
uniform vec3 u_key_dir;
uniform vec3 u_key_encoded;  // the key light's colour, encoded
uniform float u_gloss;       // glossy: the highlight's strength
uniform float u_shininess;   // glossy: its Blinn-Phong exponent

in vec2 v_uv;
in vec3 v_light;
#if DOUBLE_SIDED
in vec3 v_light_back;
#endif
#if TOON
in float v_ndl;
#endif
#if GLOSSY
in vec3 v_normal;
in vec3 v_pos;
#endif
out vec4 f_color;

void main() {
    vec4 base = u_base;
#if TEXTURED
    base *= texture(u_tex, v_uv);
#endif
#if MASK
    if (base.a < u_cutoff) discard;
#endif
#if !BLEND
    base.a = 1.0;  // glTF: an opaque or masked material's alpha is no coverage
#endif
#if DOUBLE_SIDED
    vec3 light = gl_FrontFacing ? v_light : v_light_back;
#else
    vec3 light = v_light;
#endif
#if TOON
#if DOUBLE_SIDED
    float ndl = gl_FrontFacing ? v_ndl : -v_ndl;
#else
    float ndl = v_ndl;
#endif
    light *= mix(u_shade, vec3(1.0), smoothstep(-u_ramp, u_ramp, ndl));  // MToon's two tones
#endif
    // Premultiplied by coverage (the drawer blends with ONE, ONE_MINUS_SRC_ALPHA): a clear cornea covers
    // little of the eye, but its highlight is reflected light, as bright as it is whatever the coverage.
    vec3 color = base.rgb * light * base.a;
#if GLOSSY
    vec3 n = normalize(v_normal);
    vec3 h = normalize(u_key_dir + normalize(-v_pos));
    color += u_gloss * pow(max(dot(n, h), 0.0), u_shininess) * u_key_encoded;
#endif
    f_color = vec4(color, base.a);
}
"""

# The multisampled picture, resolved into a texture, drawn into the target's viewport (a stage's panel).
COMPOSITE_VERTEX = """
#version 330
const vec2 corners[3] = vec2[3](vec2(-1.0, -1.0), vec2(3.0, -1.0), vec2(-1.0, 3.0));
void main() { gl_Position = vec4(corners[gl_VertexID], 0.0, 1.0); }
"""

COMPOSITE_FRAGMENT = """
#version 330
uniform sampler2D u_picture;
uniform ivec2 u_origin;  // the viewport's lower-left corner in the target
out vec4 f_color;
void main() { f_color = vec4(texelFetch(u_picture, ivec2(gl_FragCoord.xy) - u_origin, 0).rgb, 1.0); }
"""

# The wireframe toggle: the triangles' edges in one colour over the surface, pulled a little toward the camera.
WIRE_VERTEX = """
#version 330
uniform mat4 u_model;
uniform mat4 u_view;
uniform mat4 u_proj;
uniform float u_depth_bias;  // NDC depth: in front of the surface it traces
in vec3 in_pos;
void main() {
    gl_Position = u_proj * (u_view * (u_model * vec4(in_pos, 1.0)));
    gl_Position.z -= u_depth_bias * gl_Position.w;
}
"""

WIRE_FRAGMENT = """
#version 330
uniform vec3 u_color;
out vec4 f_color;
void main() { f_color = vec4(u_color, 1.0); }
"""

# Marks over the picture (the pupils' centres, the gaze trail): 2D triangles in NDC, one colour each.
OVERLAY_VERTEX = """
#version 330
in vec2 in_pos;
in vec3 in_color;
out vec3 v_color;
void main() { v_color = in_color; gl_Position = vec4(in_pos, 0.0, 1.0); }
"""

OVERLAY_FRAGMENT = """
#version 330
in vec3 v_color;
out vec4 f_color;
void main() { f_color = vec4(v_color, 1.0); }
"""


def _define(source: str, **values: int | bool) -> str:
    for name, value in values.items():
        source = source.replace(f"__{name.upper()}__", str(int(value)))
    return source


def deform_source(morphs: int, morph_normals: bool, skinned: bool, joints: int, delta_shift: int) -> str:
    """The deform pass for a primitive: `morphs` the most (target, weight) pairs a frame passes (0: none), its
    delta texture 1 << delta_shift texels wide."""
    return _define(DEFORM, morphs=morphs, morph_normals=morph_normals, skinned=skinned, joints=max(1, joints),
                   delta_shift=delta_shift)


def draw_sources(textured: bool, mask: bool, blend: bool, toon: bool, double_sided: bool,
                 glossy: bool) -> tuple[str, str]:
    """(vertex, fragment) shaders drawing a material."""
    flags = {"textured": textured, "mask": mask, "blend": blend, "toon": toon, "double_sided": double_sided,
             "glossy": glossy}
    return _define(DRAW_VERTEX, **flags), _define(FRAGMENT, **flags)
