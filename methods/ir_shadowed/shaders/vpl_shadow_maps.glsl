// All VPL hemicubes in one multi-draw: a command per cluster of triangles, instanced once per
// (VPL k, face f) whose frustum it may reach (clusters.py culls the rest); the vertex shader
// projects with face f's 90-degree frustum, clips to it with gl_ClipDistance and moves the
// clip-space result into the face's atlas tile (an affine map of clip space, so clipping
// and perspective interpolation stay exact). Each texel keeps the smallest distance to the
// VPL (MIN blending into R32F, no depth buffer). With PLANE_TEST (shadow_test=plane) each texel
// keeps the nearest fragment's record (distance, m) instead, by a depth test on distance / far:
// m = n / dot(n, r) is the plane of its triangle relative to the hemicube's centre (points r of
// the plane satisfy dot(m, r) = 1; m = 0 for a plane through the centre), n from the
// derivatives of the interpolated position (the triangle's own plane, not a shading normal).
// A fragment outside its own tile is discarded: a triangle clipped near the VPL (w near the near
// plane, where float rounding of x / w reaches a texel) can land a texel into the neighbouring
// tile, and its tiny distance there (often the VPL's own surface) read as a blocker at that tile's
// border row or column (open box, 1024 VPLs: 0.13% of the light lost in 13% of the pixels).
#include "hemicube.glsl"
uniform float u_near;
uniform float u_far;

#if defined VERTEX_SHADER
in vec3 in_position;
in uint in_instance;   // (VPL k, face f) = k x HEMICUBE_FACES + f: the id list at the command's baseInstance
out vec3 v_rel;
flat out ivec2 v_tile;
out float gl_ClipDistance[4];
void main() {
    int k = int(in_instance) / HEMICUBE_FACES, f = int(in_instance) % HEMICUBE_FACES;
    Vpl v = vpls[k];
    vec3 axis, right, up;
    hemicube_face(f, v.normal.xyz, axis, right, up);
    vec3 rel = in_position - hemicube_origin(v);
    float w = dot(rel, axis);
    vec4 clip = vec4(dot(rel, right), dot(rel, up), (w * (u_far + u_near) - 2.0 * u_far * u_near) / (u_far - u_near), w);
    gl_ClipDistance[0] = w - clip.x;
    gl_ClipDistance[1] = w + clip.x;
    gl_ClipDistance[2] = w - clip.y;
    gl_ClipDistance[3] = w + clip.y;
    v_tile = hemicube_tile(k, f);
    vec2 tile = vec2(v_tile);
    vec2 tiles = vec2(u_hemicube_tiles_x, u_hemicube_tiles_y);
    // ndc in [-1, 1] -> ((ndc + 1) / 2 + tile) / tiles * 2 - 1, times w
    clip.xy = (clip.xy + w * (1.0 + 2.0 * tile)) / tiles - w;
    v_rel = rel;
    gl_Position = clip;
}
#endif

#if defined FRAGMENT_SHADER
in vec3 v_rel;
flat in ivec2 v_tile;
bool outside_own_tile() { return ivec2(gl_FragCoord.xy) / u_hemicube_resolution != v_tile; }
#if PLANE_TEST
layout(location = 0) out vec4 out_record;
void main() {
    float distance = length(v_rel);
    vec3 n = cross(dFdx(v_rel), dFdy(v_rel));   // derivatives before the discard (uniform control flow)
    float c = dot(n, v_rel);
    if (outside_own_tile()) discard;
    out_record = vec4(distance, abs(c) > 0.0 ? n / c : vec3(0.0));
    gl_FragDepth = distance / u_far;
}
#else
layout(location = 0) out float out_distance;
void main() {
    if (outside_own_tile()) discard;
    out_distance = length(v_rel);
}
#endif
#endif
