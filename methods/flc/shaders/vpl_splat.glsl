// Shared by the regular and the divergent splatting programs: the geometry-shader function that
// turns one (sub-)triangle into at most one VPL (Alg. 1 level, eq. 6 radiance) and emits a quad
// over the screen-space bound of its support in one interleaved-sampling tile, and the fragment
// stage that evaluates H(t, x, n_x) S_k f^k(d(t, x)) (eq. 5, 10, 14) at the GBuffer pixel.
// The receiver's rho_x / pi is applied after the blur (resolve.glsl).
#ifndef FLC_VPL_SPLAT_GLSL
#define FLC_VPL_SPLAT_GLSL
#include "common.glsl"
#include "shadow.glsl"
#include "partition.glsl"

uniform mat4 u_view_proj;
uniform uint u_rand;           // per (sub-)frame random value (Alg. 2)
uniform bool u_jitter;         // progressive mode: VPL jittered uniformly over its triangle
uniform ivec2 u_screen;        // full-resolution W, H
uniform int u_tiles_per_axis;  // 2^L: 4^L interleaved tiles
uniform ivec2 u_tile_size;     // one tile's pixels (ceil(W / 2^L), ceil(H / 2^L))
uniform float u_weight;        // 4^L tiles / progressive frames
uniform float u_eps;           // d_i = max(eps, |x - y|) in H

// Divergent triangles, appended by the regular pass as patches of 3 vertices each (pre-split
// into m^2 equal sub-patches when even the top tessellation level would leave divergent pieces).
struct DivergentVertex {
    vec4 position_tri;  // xyz position (re-centred), w triangle index (uint bits)
    vec4 bary_rand;     // xy barycentric (beta, gamma) in the parent triangle, z xor of the parent's v_rand (uint bits)
};
layout(std430, binding = BINDING_DIVERGENT_VERTICES) buffer DivergentBlock { DivergentVertex divergent_vertices[]; };
// DrawArraysIndirect command (5 uint32 as moderngl's render_indirect reads) + reservation counter.
layout(std430, binding = BINDING_DIVERGENT_COMMAND) buffer DivergentCommand {
    uint cmd_count; uint cmd_instances; uint cmd_first; uint cmd_base_instance; uint cmd_pad; uint cmd_reserved;
};

float unit_from_u32(uint h) { return float(h) * (1.0 / 4294967296.0); }  // [0, 1], exact for small values

// Shadowed direct irradiance on both sides of a surface with unit normal n, as
// direct_irradiance(p, n, n, true) and direct_irradiance(p, -n, -n, true) (what `manylights`
// computes), with one light evaluation and one shadow lookup per light: a light reaches one side.
void direct_irradiance_two_sided(vec3 p, vec3 n, out vec3 front, out vec3 back) {
    front = vec3(0.0);
    back = vec3(0.0);
    for (int i = 0; i < u_light_count; ++i) {
        vec3 wi; float dist;
        vec3 incident = light_incident(i, p, wi, dist);
        float c = dot(n, wi);
        if (c == 0.0 || all(equal(incident, vec3(0.0)))) continue;
        vec3 side = c > 0.0 ? n : -n;
        vec3 e = incident * abs(c) * shadow_visibility(i, p, side);
        if (c > 0.0) front += e; else back += e;
    }
}

#if defined GEOMETRY_SHADER
flat out vec3 g_y;
flat out vec3 g_n;
flat out vec3 g_front;      // rho E on the side +n
flat out vec3 g_back;       // rho E on the side -n
flat out float g_weight;    // S_k * tiles / frames
flat out int g_level;

// Alg. 1 + eq. 6 + splat. `r` is the (sub-)triangle's random value (Alg. 2), y the VPL centre.
void flc_splat_triangle(vec3 a, vec3 b, vec3 c, float area, uint r, uint tri, vec3 y) {
    uint h = hash_u32(r);
    int level = flc_level(unit_from_u32(h), area);
    if (level < 0) return;
    vec3 n = normalize(cross(b - a, c - a));
    vec3 rho = triangle_albedo[tri].rgb;
    vec3 front, back;
    direct_irradiance_two_sided(y, n, front, back);
    front *= rho;
    back *= rho;
    if (all(equal(front + back, vec3(0.0)))) return;  // an unlit VPL adds nothing

    // Screen-space bound of the support {x : |x - y| / |<n, (x - y)/|x - y|>| <= D}: the two
    // balls of diameter D tangent to the triangle's plane at y (two-sided emission).
    float support = flc_support(level);
    bool full = support < 0.0;
    vec2 lo = vec2(1.0e30), hi = vec2(-1.0e30);
    if (!full) {
        float r_ball = 0.5 * support;
        vec3 ext = abs(n) * r_ball + vec3(r_ball);
        // corners of the box y +- ext in clip space: M y +- M_x ext.x +- M_y ext.y +- M_z ext.z
        vec4 centre = u_view_proj * vec4(y, 1.0);
        vec4 ax = u_view_proj[0] * ext.x, ay = u_view_proj[1] * ext.y, az = u_view_proj[2] * ext.z;
        int behind = 0;
        for (int i = 0; i < 8; ++i) {
            vec4 clip = centre + ((i & 1) != 0 ? ax : -ax) + ((i & 2) != 0 ? ay : -ay) + ((i & 4) != 0 ? az : -az);
            if (clip.w <= 0.0) { ++behind; continue; }
            vec2 ndc = clip.xy / clip.w;
            lo = min(lo, ndc);
            hi = max(hi, ndc);
        }
        if (behind == 8) return;
        if (behind > 0) full = true;
    }
    if (full) { lo = vec2(-1.0); hi = vec2(1.0); }
    lo = max(lo, vec2(-1.0));
    hi = min(hi, vec2(1.0));
    if (any(greaterThanEqual(lo, hi))) return;
    ivec2 p0 = clamp(ivec2(floor((lo * 0.5 + 0.5) * vec2(u_screen))), ivec2(0), u_screen);
    ivec2 p1 = clamp(ivec2(ceil((hi * 0.5 + 0.5) * vec2(u_screen))), ivec2(0), u_screen);  // exclusive

    // Interleaved sampling: one random tile; tile pixel i stands for full-resolution pixel phase + P i.
    int P = u_tiles_per_axis;
    uint tile = hash_u32(h ^ 0x85EBCA6Bu) % uint(P * P);
    ivec2 phase = ivec2(int(tile) % P, int(tile) / P);
    ivec2 i0 = (p0 - phase + (P - 1)) / P;                           // ceil, numerator >= 0
    ivec2 i1 = ivec2(floor(vec2(p1 - 1 - phase) / float(P)));        // floor
    i1 = min(i1, u_tile_size - 1);
    if (any(greaterThan(i0, i1))) return;
    vec2 target = vec2(u_tile_size * P);
    vec2 q0 = (vec2(phase * u_tile_size + i0) / target) * 2.0 - 1.0;
    vec2 q1 = (vec2(phase * u_tile_size + i1 + 1) / target) * 2.0 - 1.0;

    vec2 corners[4] = vec2[4](vec2(q0.x, q0.y), vec2(q1.x, q0.y), vec2(q0.x, q1.y), vec2(q1.x, q1.y));
    for (int v = 0; v < 4; ++v) {
        g_y = y;
        g_n = n;
        g_front = front;
        g_back = back;
        g_weight = flc_s[level] * u_weight;
        g_level = level;
        gl_Position = vec4(corners[v], 0.0, 1.0);
        EmitVertex();
    }
    EndPrimitive();
}
#endif

#if defined FRAGMENT_SHADER
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_normal;
flat in vec3 g_y;
flat in vec3 g_n;
flat in vec3 g_front;
flat in vec3 g_back;
flat in float g_weight;
flat in int g_level;
layout(location = 0) out vec4 out_sum;
void main() {
    ivec2 q = ivec2(gl_FragCoord.xy);
    ivec2 phase = q / u_tile_size;
    ivec2 px = phase + u_tiles_per_axis * (q - phase * u_tile_size);
    if (any(greaterThanEqual(px, u_screen))) discard;
    vec4 p = texelFetch(u_gbuffer_position, px, 0);
    if (p.w == 0.0) discard;
    vec3 nx = texelFetch(u_gbuffer_normal, px, 0).xyz;
    vec3 v = g_y - p.xyz;                       // x -> y
    float dist = length(v);
    if (dist <= 0.0) discard;
    vec3 w = v / dist;
    float cos_x = dot(nx, w);
    if (cos_x <= 0.0) discard;
    float cos_y = -dot(g_n, w);                 // y -> x against the VPL normal
    float c = abs(cos_y);
    if (c <= 0.0) discard;
    float f = flc_partition(g_level, dist / c); // eq. 14: d = |x - y| / <n_t, (x - y)/|x - y|>
    if (f <= 0.0) discard;
    vec3 radiosity = cos_y > 0.0 ? g_front : g_back;
    float dc = max(u_eps, dist);
    // rho_t E 3/(2 pi) c (eq. 6) * cos_x c / d_i^2 (eq. 5 without rho_x / pi) * S_k f^k (eq. 10)
    out_sum = vec4(radiosity * (1.5 * INV_PI * c * c * cos_x / (dc * dc) * f * g_weight), 0.0);
}
#endif

#endif
