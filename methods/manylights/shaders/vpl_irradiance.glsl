// Compute pass: one VPL per triangle with its shadowed direct irradiance on both sides of its
// shading normal (the shadow-map offset follows the geometric normal, as the direct pass).
#include "common.glsl"
#include "direct_lighting.glsl"
#include "vpl_triangles.glsl"
layout(local_size_x = 64) in;
uniform int u_triangle_count;
uniform uint u_rand;        // per-frame random value
uniform bool u_jitter;      // false: VPL at the centroid

void main() {
    int t = int(gl_GlobalInvocationID.x);
    if (t >= u_triangle_count) return;
    TriangleRecord tri = triangles[t];
    vec3 a = tri.v0_area.xyz, b = tri.v1.xyz, c = tri.v2.xyz;
    vec3 bary = vec3(1.0 / 3.0);
    if (u_jitter) {
        // Uniform point on the triangle: (1 - sqrt(u1), sqrt(u1)(1 - u2), sqrt(u1) u2).
        uint h = hash_u32(u_rand ^ hash_u32(uint(t) * 2654435761u));
        float u1 = u32_to_unit(h), u2 = u32_to_unit(hash_u32(h ^ 0x9E3779B9u));
        float su = sqrt(u1);
        bary = vec3(1.0 - su, su * (1.0 - u2), su * u2);
    }
    vec3 y = bary.x * a + bary.y * b + bary.z * c;
    vec3 cr = cross(b - a, c - a);
    float cr_len = length(cr);
    if (!(cr_len > 0.0)) {
        // a sliver that is degenerate in float32 (its float64 area is tiny but not 0): no normal,
        // so no emission (normalize would give NaN in every pixel it reaches); its share of the
        // sum is its area, ~1e-6 of its neighbours'
        vpls[t].position_area = vec4(y, 0.0);
        vpls[t].normal = vec4(0.0);
        vpls[t].shading_normal = vec4(0.0);
        vpls[t].radiosity_front = vec4(0.0);
        vpls[t].radiosity_back = vec4(0.0);
        return;
    }
    vec3 n = cr / cr_len;
    // Mitsuba's shading frame: the vertex normals interpolated at y, normalised. The incident
    // cosine and the side a VPL emits on are taken against it; the geometric term against n.
    vec3 ns = bary.x * tri.n0.xyz + bary.y * tri.n1.xyz + bary.z * tri.n2.xyz;
    float len = length(ns);
    ns = len > 0.0 ? ns / len : n;
    vec3 rho = triangle_albedo[t].rgb;
    vpls[t].position_area = vec4(y, tri.v0_area.w);
    vpls[t].normal = vec4(n, 0.0);
    vpls[t].shading_normal = vec4(ns, 0.0);
    vpls[t].radiosity_front = vec4(rho * direct_irradiance(y, ns, n, true), 0.0);
    vpls[t].radiosity_back = vec4(rho * direct_irradiance(y, -ns, n, true), 0.0);
}
