"""GLSL for the face: bone-blended vertices, cel or smooth shading, extruded outline quads, 2D overlays.

Software OpenGL (llvmpipe) runs every branch of a fragment shader for every pixel, so each kind of
surface gets its own small program instead of one shader that branches on the material.
"""

from __future__ import annotations

from eca.services.processes.renderer.curves import CURVE_POINTS, SEGMENTS, TUBE_POINTS
from eca.services.processes.renderer.geometry import EXTRUDED, HEAD_A, HEAD_B, HEAD_C, HEAD_N, HEAD_TAPER, MAT, N_BONES

FACE_VERTEX = """
#version 330
#define CURVES 1  // 0 for the static parts: no vertex of theirs is built from the Curves block
#define EXTRUDED __EXTRUDED__  // geometry.EXTRUDED: added to the material of an outline quad's outer corners
#define SEGMENTS __SEGMENTS__  // curves.SEGMENTS: points per tube centre line and per strip edge
#define CURVE_POINTS __CURVE_POINTS__  // curves.CURVE_POINTS
#define MAT_SKIN __MAT_SKIN__  // geometry.MAT: the head's two materials
#define MAT_HAIR __MAT_HAIR__
// The head's surface (curves._on_face): |x / (A t(y))|^N + |y / B|^N + |z / C|^N = 1, t(y) = 1 - T u^2.
const float HEAD_A = __HEAD_A__, HEAD_B = __HEAD_B__, HEAD_C = __HEAD_C__;
const float HEAD_N = __HEAD_N__, HEAD_TAPER = __HEAD_TAPER__;
const float OUTLINE_FAR = 0.999999;  // NDC depth just short of the cleared 1.0, which the test must pass
layout(std140) uniform Frame {  // written once per frame, shared by every program
    mat4 u_bones[__N_BONES__];  // rest head frame -> camera, per bone (the head's modelview times the bone)
    mat4 u_proj;
};
layout(std140) uniform Curves {  // written once per frame: the brows and the mouth (curves.curve_block)
    // Per point of each tube's centre line and each strip's edges: (x, y, lift off the head, jaw weight);
    // then per tube centre-line point: (half height, half depth, section aspect, -).
    vec4 u_curves[CURVE_POINTS + __TUBE_POINTS__];
};
uniform vec3 u_palette[10]; // per material, geometry.MATERIALS order
uniform vec3 u_light_v;     // toward the key light, camera space, unit
uniform float u_outline;    // outline width in pixels (the outline pass)
uniform vec2 u_viewport;
uniform float u_depth_bias; // pulls the wireframe pass in front of the surface it traces

in vec3 in_pos;             // a tube vertex: (centre-line point, cos, sin around the section); a strip's: (point, -, -)
in vec3 in_normal;
in vec3 in_aux;
in vec4 in_info;            // material (+ EXTRUDED, + 2 EXTRUDED for a tube, + 4 EXTRUDED for a strip), bone0,
                            // bone1, weight of bone1

out vec3 v_normal;          // camera space
out vec3 v_aux;             // eye: rest direction
out float v_ndl;            // n.l for the cel bands
flat out vec3 v_color;      // one colour per triangle (its last vertex's): no need to interpolate it

// The point (x, y) of the head's front, moved `lift` along the surface normal `n` (curves._on_face).
vec3 on_face(vec4 q, out vec3 n) {
    float u = clamp(-q.y / HEAD_B, 0.0, 1.0);
    float taper = 1.0 - HEAD_TAPER * u * u;
    float wx = HEAD_A * taper;
    float ax = abs(q.x) / wx;
    float ay = abs(q.y) / HEAD_B;
    float axn = pow(ax, HEAD_N);
    float ayn = pow(ay, HEAD_N);
    float rest = max(1.0 - axn - ayn, 1e-9);
    float zc = pow(rest, 1.0 / HEAD_N);
    float dt_dy = (u > 0.0 && u < 1.0) ? 2.0 * HEAD_TAPER * u / HEAD_B : 0.0;
    vec3 g = vec3(sign(q.x) * axn / max(ax, 1e-12) / wx,
                  sign(q.y) * ayn / max(ay, 1e-12) / HEAD_B - axn / taper * dt_dy,
                  rest / zc / HEAD_C);
    n = normalize(g);
    return vec3(q.x, q.y, HEAD_C * zc) + n * q.z;
}

void main() {
    int code = int(in_info.x + 0.5);
    vec3 pos = in_pos;
    vec3 normal = in_normal;
    float w = in_info.w;
#if CURVES
    if (code >= int(4.0 * EXTRUDED)) {
        // A vertex of the mouth's inner strips: its point on the face; the normal faces the camera.
        vec4 q = u_curves[int(in_pos.x + 0.5)];
        vec3 unused;
        pos = on_face(q, unused);
        w = q.w;
    } else if (code >= int(2.0 * EXTRUDED)) {
        // A brow or lip: a tube of elliptic section around its centre line (curves._tubes).
        int k = int(in_pos.x + 0.5);
        int j = k % SEGMENTS;
        vec4 q = u_curves[k];
        vec4 section = u_curves[CURVE_POINTS + k];
        vec3 o;
        vec3 c = on_face(q, o);
        vec3 unused;
        vec3 tangent = on_face(u_curves[j == SEGMENTS - 1 ? k : k + 1], unused)
                     - on_face(u_curves[j == 0 ? k : k - 1], unused);
        vec3 side = normalize(cross(o, tangent));
        pos = c + (in_pos.y * section.x) * side + (in_pos.z * section.y) * o;
        normal = normalize((in_pos.y * section.z) * side + in_pos.z * o);
        w = q.w;
    }
#endif
    int b0 = int(in_info.y + 0.5);
    int b1 = int(in_info.z + 0.5);
    mat4 bone = u_bones[b0] * (1.0 - w) + u_bones[b1] * w;
    vec4 p = bone * vec4(pos, 1.0);
    vec3 n = normalize(mat3(bone) * normal);
    vec4 clip = u_proj * p;
    int mat = code % int(EXTRUDED);
    if (code - mat == int(EXTRUDED) || code - mat == int(3.0 * EXTRUDED)) {
        // An outline quad's outer corner: pushed along the screen-space normal by a fixed number of
        // pixels, whatever the distance.
        vec2 dir = (u_proj * vec4(n, 0.0)).xy;
        float len = length(dir);
        if (len > 1e-6) {
            clip.xy += dir / len * (2.0 * u_outline / u_viewport) * clip.w;
        }
    }
    if (u_outline > 0.0 && (mat == MAT_SKIN || mat == MAT_HAIR)) {
        // The head's outline quads go to the back of the depth range: the head has nothing behind it,
        // so its line belongs only where nothing else was drawn. Where the head folds away from the
        // camera (the hair's ledge, the chin's blend into the jaw) an edge between a front and a back
        // face runs across the visible surface; at its own depth its quad would draw a stray line there.
        clip.z = clip.w * OUTLINE_FAR;
    }
    clip.z -= u_depth_bias * clip.w;
    gl_Position = clip;
    v_normal = n;
    v_aux = in_aux;
    v_color = u_palette[mat];
    // Lighting per vertex, interpolated: the cel bands still cut crisply, and software GL pays per
    // interpolated float on every pixel.
    v_ndl = dot(n, u_light_v);
}
"""
for _name, _value in (
    ("__EXTRUDED__", f"{EXTRUDED:.1f}"),
    ("__SEGMENTS__", str(SEGMENTS)),
    ("__CURVE_POINTS__", str(CURVE_POINTS)),
    ("__N_BONES__", str(N_BONES)),
    ("__MAT_SKIN__", str(MAT["skin"])),
    ("__MAT_HAIR__", str(MAT["hair"])),
    ("__TUBE_POINTS__", str(TUBE_POINTS)),
    ("__HEAD_A__", repr(float(HEAD_A))),
    ("__HEAD_B__", repr(float(HEAD_B))),
    ("__HEAD_C__", repr(float(HEAD_C))),
    ("__HEAD_N__", repr(float(HEAD_N))),
    ("__HEAD_TAPER__", repr(float(HEAD_TAPER))),
):
    FACE_VERTEX = FACE_VERTEX.replace(_name, _value)

_SHADE = """
uniform vec3 u_light;        // camera space, unit
uniform vec2 u_band_edges;
uniform vec3 u_band_levels;
uniform float u_ambient;
uniform float u_specular;

float cel(float ndl) {
    return ndl < u_band_edges.x ? u_band_levels.x : (ndl < u_band_edges.y ? u_band_levels.y : u_band_levels.z);
}

vec3 shade(vec3 base, vec3 n) {
    float ndl = dot(n, u_light);
#if SMOOTH
    vec3 h = normalize(u_light + vec3(0.0, 0.0, 1.0));
    return base * (u_ambient + (1.0 - u_ambient) * max(ndl, 0.0))
         + vec3(pow(max(dot(n, h), 0.0), 32.0) * u_specular);
#else
    return base * cel(ndl);
#endif
}
"""

SURFACE_FRAGMENT = (
    """
#version 330
#define SMOOTH %(smooth)d
in vec3 v_normal;
in float v_ndl;
flat in vec3 v_color;
out vec4 f_color;
"""
    + _SHADE
    + """
void main() {
#if SMOOTH
    f_color = vec4(shade(v_color, normalize(v_normal)), 1.0);
#else
    f_color = vec4(v_color * cel(v_ndl), 1.0);
#endif
}
"""
)

EYE_FRAGMENT = (
    """
#version 330
#define SMOOTH %(smooth)d
uniform vec3 u_sclera;
uniform vec3 u_iris;
uniform vec3 u_pupil;
uniform float u_cos_iris;
uniform float u_cos_iris_rim;
uniform float u_cos_pupil;
uniform vec3 u_glint;  // unit, between the key light and the viewer: where the catch-light sits
in vec3 v_normal;
in vec3 v_aux;
out vec4 f_color;
"""
    + _SHADE
    + """
void main() {
    // Iris and pupil are discs around the eye's forward pole, so they turn with the eye.
    float c = normalize(v_aux).z;
    vec3 iris = mix(u_iris * 0.55, u_iris, smoothstep(u_cos_iris, u_cos_iris_rim, c));
    vec3 base = c > u_cos_pupil ? u_pupil : (c > u_cos_iris ? iris : u_sclera);
    vec3 n = normalize(v_normal);
    vec3 color = shade(base, n);
    // A catch-light toward the key light, fixed on screen: the glint that makes cartoon eyes look alive.
    float glint = step(0.985, dot(n, u_glint));
    f_color = vec4(mix(color, vec3(1.0), glint), 1.0);
}
"""
)

FLAT_FRAGMENT = """
#version 330
uniform vec3 u_flat;
out vec4 f_color;
void main() {
    f_color = vec4(u_flat, 1.0);
}
"""

OVERLAY_VERTEX = """
#version 330
in vec2 in_pos;            // normalised device coordinates
in vec3 in_color;
out vec3 v_color;
void main() {
    gl_Position = vec4(in_pos, 0.0, 1.0);
    v_color = in_color;
}
"""

OVERLAY_FRAGMENT = """
#version 330
in vec3 v_color;
out vec4 f_color;
void main() {
    f_color = vec4(v_color, 1.0);
}
"""


def face_vertex(curves: bool) -> str:
    """FACE_VERTEX with (curves=True) or without the code that builds the brows and the mouth from the
    Curves block: the static parts, none of whose vertices is built there, get a program without it
    (measured: a few hundredths of a millisecond per frame on software GL)."""
    return FACE_VERTEX if curves else FACE_VERTEX.replace("#define CURVES 1", "#define CURVES 0", 1)


def variant(source: str, smooth: bool) -> str:
    """The cel (smooth=False) or smooth 3D-surface version of a fragment shader."""
    return source % {"smooth": int(smooth)}
