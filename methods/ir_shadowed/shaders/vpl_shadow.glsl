// Visibility of a VPL from a receiver through the VPL's hemicube: the receiver x is moved along
// its geometric normal (turned towards the VPL) by `u_normal_offset` texel footprints, more at
// grazing angles (as the shared shadow maps), then compared with the stored nearest distance
// plus one texel footprint. With PLANE_TEST (shadow_test=plane) the texel's blocker also blocks
// when the segment centre -> receiver crosses that blocker's plane before the receiver
// (dot(m, rel) > 1), the crossing no nearer than the stored point minus a texel footprint (the
// texel's own surface): a receiver just past a zero-thickness wall, within the one-footprint
// tolerance of the distance test, is behind the wall's plane.
#ifndef VPL_SHADOW_GLSL
#define VPL_SHADOW_GLSL
#include "hemicube.glsl"
uniform sampler2D u_hemicube_atlas;
uniform float u_normal_offset;

float vpl_visibility(int k, Vpl v, vec3 x, vec3 n_geo) {
    vec3 y = hemicube_origin(v);
    vec3 to_vpl = y - x;
    float dist = length(to_vpl);
    vec3 wi = to_vpl / dist;
    float texel = 2.0 * dist / float(u_hemicube_resolution);  // texel footprint at the receiver
    vec3 n = dot(n_geo, wi) < 0.0 ? -n_geo : n_geo;
    float cos_r = clamp(dot(n, wi), 0.0, 1.0);
    float sin_r = sqrt(max(1.0 - cos_r * cos_r, 0.0));
    vec3 q = x + n * (u_normal_offset * texel * (0.5 + 1.5 * sin_r));
    vec3 rel = q - y;
    vec2 uv;
    int f = hemicube_lookup(v.normal.xyz, rel, uv);
    if (f < 0) return 1.0;
    ivec2 texel_xy = clamp(ivec2((uv * 0.5 + 0.5) * float(u_hemicube_resolution)), ivec2(0),
                           ivec2(u_hemicube_resolution - 1));
    vec4 record = texelFetch(u_hemicube_atlas, hemicube_tile(k, f) * u_hemicube_resolution + texel_xy, 0);
    float stored = record.r;
    float len = length(rel);
    if (len > stored + texel) return 0.0;
#if PLANE_TEST
    float along = dot(record.yzw, rel);   // > 1: the plane is crossed before the receiver, at len / along
    if (along > 1.0 + PLANE_TOLERANCE && len / along >= stored - texel) return 0.0;
#endif
    return 1.0;
}

#endif
