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
#include "receivers.glsl"

uniform uint u_rand;           // per (sub-)frame random value of the level draw (Alg. 2)
uniform uint u_rand_tile;      // independent stream: the interleaved-sampling tile of a VPL
uniform uint u_rand_jitter;    // independent stream: the VPL position (same as `manylights`)
uniform bool u_jitter;         // progressive mode: VPL jittered uniformly over its triangle
uniform float u_weight;        // 4^L tiles / progressive frames
uniform float u_eps;           // d_i >= eps in H (eq. 5)

// Divergent triangles, appended by the regular pass as patches of 3 vertices each (pre-split
// into m^2 equal sub-patches when even the top tessellation level would leave divergent pieces).
struct DivergentVertex {
    vec4 position_tri;  // xyz position (re-centred), w triangle index (uint bits)
    vec4 bary_rand;     // xy barycentric (beta, gamma) in the parent triangle, z xor of the parent's v_rand (uint bits)
    vec4 normal;        // xyz the parent's shading normal interpolated at this vertex (not normalised)
};
layout(std430, binding = BINDING_DIVERGENT_VERTICES) buffer DivergentBlock { DivergentVertex divergent_vertices[]; };
// DrawArraysIndirect command (5 uint32 as moderngl's render_indirect reads) + reservation counter.
layout(std430, binding = BINDING_DIVERGENT_COMMAND) buffer DivergentCommand {
    uint cmd_count; uint cmd_instances; uint cmd_first; uint cmd_base_instance; uint cmd_pad; uint cmd_reserved;
};

// Shadowed direct irradiance on both sides of a surface with unit geometric normal n and unit
// shading normal ns (oriented into n's hemisphere), as direct_irradiance(p, ns, n, true) and
// direct_irradiance(p, -ns, -n, true): the incident cosine against the shading normal (as
// Mitsuba and `manylights`), the shadow-map offset along the geometric side; one light
// evaluation and one shadow lookup per light, since a light reaches one side.
void direct_irradiance_two_sided(vec3 p, vec3 n, vec3 ns, out vec3 front, out vec3 back) {
    front = vec3(0.0);
    back = vec3(0.0);
    for (int i = 0; i < u_light_count; ++i) {
        vec3 wi; float dist;
        vec3 incident = light_incident(i, p, wi, dist);
        float c = dot(ns, wi);
        if (c == 0.0 || all(equal(incident, vec3(0.0)))) continue;
        vec3 side = c > 0.0 ? n : -n;
        vec3 e = incident * abs(c) * shadow_visibility(i, p, side);
        if (c > 0.0) front += e; else back += e;
    }
}

// Conservative: false only when no light can reach any point of the triangle abc (every light
// a spot whose cone misses the triangle's bounding sphere: spot_falloff is 0 beyond the cutoff).
// Point and directional lights reach every triangle not seen edge-on (surfaces are two-sided).
bool flc_patch_may_be_lit(vec3 a, vec3 b, vec3 c) {
    vec3 centre = (a + b + c) * (1.0 / 3.0);
    float r = sqrt(max(dot(a - centre, a - centre), max(dot(b - centre, b - centre), dot(c - centre, c - centre))));
    r = r * (1.0 + 1.0e-3) + 1.0e-6;
    for (int i = 0; i < u_light_count; ++i) {
        if (light_kind(i) != LIGHT_SPOT) return true;
        Light L = lights[i];
        vec3 v = centre - L.position_kind.xyz;
        float dist = length(v);
        if (dist <= r) return true;
        // angle between the axis and the centre, minus the sphere's angular radius, against the cutoff
        float cos_phi = dot(v, L.direction_cos_cutoff.xyz) / dist;
        float phi = atan(sqrt(max(1.0 - cos_phi * cos_phi, 0.0)), cos_phi);
        float alpha = asin(min(r / dist, 1.0));
        if (phi - alpha < L.angles_layers.x + 1.0e-3) return true;
    }
    return false;
}

#if defined GEOMETRY_SHADER
uniform mat4 u_view;           // re-centred world -> view space (the camera looks down -z)
uniform vec2 u_proj_scale;     // P[0][0], P[1][1] of the symmetric perspective projection
uniform float u_near;          // near plane distance

// NDC bound of the projection of a sphere (centre c_world, radius r): the tangent lines from the
// eye in the x-z and y-z planes (Mara & McGuire 2013, "2D polyhedral bounds of a clipped,
// perspective-projected 3D sphere"), merged into lo / hi. Returns 0 when the sphere lies behind
// the near plane, 2 when it crosses it (the caller then takes the whole screen), 1 otherwise.
int sphere_ndc_bound(vec3 c_world, float r, inout vec2 lo, inout vec2 hi) {
    vec3 c = (u_view * vec4(c_world, 1.0)).xyz;
    if (c.z - r >= -u_near) return 0;
    if (c.z + r >= -u_near) return 2;
    for (int axis = 0; axis < 2; ++axis) {
        vec2 cc = vec2(c[axis], c.z);
        float len = length(cc);
        vec2 v = vec2(sqrt(max(dot(cc, cc) - r * r, 0.0)), r) / len;   // cos, sin of the tangent angle
        vec2 b0 = v.x * vec2(v.x * cc.x + v.y * cc.y, -v.y * cc.x + v.x * cc.y);
        vec2 b1 = v.x * vec2(v.x * cc.x - v.y * cc.y, v.y * cc.x + v.x * cc.y);
        float s0 = u_proj_scale[axis] * b0.x / -b0.y, s1 = u_proj_scale[axis] * b1.x / -b1.y;
        lo[axis] = min(lo[axis], min(s0, s1));
        hi[axis] = max(hi[axis], max(s0, s1));
    }
    return 1;
}

flat out vec3 g_y;
flat out vec3 g_n;
flat out vec3 g_ns;
flat out vec3 g_front;      // rho E on the side +ns (ns oriented into n's hemisphere)
flat out vec3 g_back;       // rho E on the side -ns
flat out float g_weight;    // S_k * tiles / frames
flat out int g_level;
flat out float g_rdisc;     // radius of the disc of area S_k the VPL stands for (0 with FLC_NEAR_MODE 0)

// Alg. 1 + eq. 6 + splat. `key` is the (sub-)triangle's xor of per-vertex random values (Alg. 2,
// without u_rand), y the VPL centre, ns_raw the shading normal interpolated at y.
void flc_splat_triangle(vec3 a, vec3 b, vec3 c, float area, uint key, uint tri, vec3 y, vec3 ns_raw) {
    uint h = hash_u32(u_rand ^ key);   // REGULARRAND / DIVERGENTRAND of Alg. 2
    int level = flc_level(unit_from_u32(h), area);
    if (level < 0) return;
    vec3 n = normalize(cross(b - a, c - a));
    float ns_len = length(ns_raw);
    vec3 ns = ns_len > 0.0 ? ns_raw / ns_len : n;
    if (dot(ns, n) < 0.0) ns = -ns;
    vec3 rho = triangle_albedo[tri].rgb;
    vec3 front, back;
    direct_irradiance_two_sided(y, n, ns, front, back);
    front *= rho;
    back *= rho;
    if (all(equal(front + back, vec3(0.0)))) return;  // an unlit VPL adds nothing

    // Screen-space bound of the support {x : |x - y| / |<n, (x - y)/|x - y|>| <= D}: the two
    // balls of diameter D tangent to the triangle's plane at y (two-sided emission), only the
    // ball on the lit side when the other side is dark; each ball's exact projected bound.
    float support = flc_support(level);
    bool full = support < 0.0;
    vec2 lo = vec2(1.0e30), hi = vec2(-1.0e30);
    if (!full) {
        float r_ball = 0.5 * support;
        bool front_lit = any(greaterThan(front, vec3(0.0))), back_lit = any(greaterThan(back, vec3(0.0)));
        // one ball only when flat shaded: otherwise the side of ns that picks the radiosity
        // (fragment stage) and the side of n that bounds the ball differ in a thin wedge
        if (dot(ns, n) < 0.999999) front_lit = back_lit = true;
        int visible = 0;
        for (int side = 0; side < 2; ++side) {
            if (side == 0 ? !front_lit : !back_lit) continue;
            int b = sphere_ndc_bound(y + (side == 0 ? n : -n) * r_ball, r_ball, lo, hi);
            if (b == 2) full = true;
            visible += b;
        }
        if (visible == 0) return;   // the lit balls are behind the camera
    }
    if (full) { lo = vec2(-1.0); hi = vec2(1.0); }
    lo = max(lo, vec2(-1.0));
    hi = min(hi, vec2(1.0));
    if (any(greaterThanEqual(lo, hi))) return;
    ivec2 p0 = clamp(ivec2(floor((lo * 0.5 + 0.5) * vec2(u_screen))), ivec2(0), u_screen);
    ivec2 p1 = clamp(ivec2(ceil((hi * 0.5 + 0.5) * vec2(u_screen))), ivec2(0), u_screen);  // exclusive

    // Interleaved sampling: one random tile; tile pixel i stands for full-resolution pixel phase + P i.
    int P = u_tiles_per_axis;
    uint tile = hash_u32(u_rand_tile ^ key) % uint(P * P);
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
        g_ns = ns;
        g_front = front;
        g_back = back;
        g_weight = flc_s[level] * u_weight;
        g_level = level;
#if FLC_NEAR_MODE > 0
        g_rdisc = sqrt(flc_s[level] * INV_PI);
#else
        g_rdisc = 0.0;
#endif
        gl_Position = vec4(corners[v], 0.0, 1.0);
        EmitVertex();
    }
    EndPrimitive();
}
#endif

#if defined FRAGMENT_SHADER
uniform usampler2D u_receivers;   // deinterleaved receivers (deinterleave.glsl), the tiled layout
flat in vec3 g_y;
flat in vec3 g_n;
flat in vec3 g_ns;
flat in vec3 g_front;
flat in vec3 g_back;
flat in float g_weight;
flat in int g_level;
flat in float g_rdisc;
layout(location = 0) out vec4 out_sum;
void main() {
    uvec4 receiver = texelFetch(u_receivers, ivec2(gl_FragCoord.xy), 0);
    if (receiver.w == RECEIVER_NONE) discard;  // no surface, or past the screen's edge
    vec3 nx = decode_receiver_normal(receiver.w);
    vec3 v = g_y - uintBitsToFloat(receiver.xyz);   // x -> y
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
    // the side of the shading normal x is on picks the radiosity (Mitsuba's twosided diffuse, as
    // `manylights`); the geometric term's cosine is against the face normal
    vec3 radiosity = dot(g_ns, w) < 0.0 ? g_front : g_back;
    // d_i^2 of eq. 5 (near_field, method.py): |x - y|^2 + r^2, the disc element's form factor
    // S / (pi d^2 + S) (FLC_NEAR_MODE 2); max(r, |x - y|)^2 (1); max(eps, |x - y|)^2 (0, the paper)
#if FLC_NEAR_MODE == 2
    float d2 = max(u_eps * u_eps, dist * dist + g_rdisc * g_rdisc);
#else
    float dc = max(max(u_eps, g_rdisc), dist);
    float d2 = dc * dc;
#endif
    // rho_t E 3/(2 pi) c (eq. 6) * cos_x c / d_i^2 (eq. 5 without rho_x / pi) * S_k f^k (eq. 10)
    out_sum = vec4(radiosity * (1.5 * INV_PI * c * c * cos_x / d2 * f * g_weight), 0.0);
}
#endif

#endif
