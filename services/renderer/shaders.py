"""GLSL for the face: bone-blended vertices, cel or smooth shading, extruded outline quads, 2D overlays.

Software OpenGL (llvmpipe) runs every branch of a fragment shader for every pixel, so each kind of
surface gets its own small program instead of one shader that branches on the material.
"""

from __future__ import annotations

from services.renderer.mesh import EXTRUDED, N_BONES, SEGMENTS, TUBE_POINTS

FACE_VERTEX = """
#version 330
#define EXTRUDED __EXTRUDED__  // mesh.EXTRUDED: added to the material of an outline quad's outer corners
#define SEGMENTS __SEGMENTS__  // mesh.SEGMENTS: centre-line points per tube
layout(std140) uniform Frame {  // written once per frame, shared by every program
    mat4 u_bones[__N_BONES__];  // rest head frame -> camera, per bone (the head's modelview times the bone)
    mat4 u_proj;
};
layout(std140) uniform Tubes {  // written once per frame: the brows and lips
    // Per tube centre-line point (mesh.tube_curves): (centre, half height), (surface normal, half depth),
    // (jaw weight, section aspect, -, -).
    vec4 u_curves[3 * __TUBE_POINTS__];
};
uniform vec3 u_palette[10]; // per material, mesh.MATERIALS order
uniform vec3 u_light_v;     // toward the key light, camera space, unit
uniform float u_outline;    // outline width in pixels (the outline pass)
uniform vec2 u_viewport;
uniform float u_depth_bias; // pulls the wireframe pass in front of the surface it traces

in vec3 in_pos;             // a tube vertex: (centre-line point, cos, sin around the section)
in vec3 in_normal;
in vec3 in_aux;
in vec4 in_info;            // material (+ EXTRUDED, + 2 EXTRUDED for a tube), bone0, bone1, weight of bone1

out vec3 v_normal;          // camera space
out vec3 v_aux;             // eye: rest direction
out float v_ndl;            // n.l for the cel bands
flat out vec3 v_color;      // one colour per triangle (its last vertex's): no need to interpolate it

void main() {
    int code = int(in_info.x + 0.5);
    vec3 pos = in_pos;
    vec3 normal = in_normal;
    float w = in_info.w;
    if (code >= int(2.0 * EXTRUDED)) {
        // A brow or lip: a tube of elliptic section around its centre line (mesh._tubes).
        int k = int(in_pos.x + 0.5);
        int j = k % SEGMENTS;
        vec4 c = u_curves[3 * k];
        vec4 o = u_curves[3 * k + 1];
        vec4 e = u_curves[3 * k + 2];
        vec3 tangent = u_curves[3 * (j == SEGMENTS - 1 ? k : k + 1)].xyz - u_curves[3 * (j == 0 ? k : k - 1)].xyz;
        vec3 side = normalize(cross(o.xyz, tangent));
        pos = c.xyz + (in_pos.y * c.w) * side + (in_pos.z * o.w) * o.xyz;
        normal = normalize((in_pos.y * e.y) * side + in_pos.z * o.xyz);
        w = e.x;
    }
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
    ("__N_BONES__", str(N_BONES)),
    ("__TUBE_POINTS__", str(TUBE_POINTS)),
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


def variant(source: str, smooth: bool) -> str:
    """The cel (smooth=False) or smooth 3D-surface version of a fragment shader."""
    return source % {"smooth": int(smooth)}
