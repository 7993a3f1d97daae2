// Compute pass: one VPL per triangle with its shadowed direct irradiance on both sides.
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
    vec3 y = (a + b + c) / 3.0;
    if (u_jitter) {
        // Uniform point on the triangle: (1 - sqrt(u1), sqrt(u1)(1 - u2), sqrt(u1) u2).
        uint h = hash_u32(u_rand ^ hash_u32(uint(t) * 2654435761u));
        float u1 = u32_to_unit(h), u2 = u32_to_unit(hash_u32(h ^ 0x9E3779B9u));
        float su = sqrt(u1);
        y = (1.0 - su) * a + su * (1.0 - u2) * b + su * u2 * c;
    }
    vec3 n = normalize(cross(b - a, c - a));
    vec3 rho = triangle_albedo[t].rgb;
    vpls[t].position_area = vec4(y, tri.v0_area.w);
    vpls[t].normal = vec4(n, 0.0);
    vpls[t].radiosity_front = vec4(rho * direct_irradiance(y, n, n, true), 0.0);
    vpls[t].radiosity_back = vec4(rho * direct_irradiance(y, -n, -n, true), 0.0);
}
