// Regular pass (Sec. 6): one draw of the whole scene. The geometry shader computes each
// triangle's area and random value (Alg. 2: u_rand xor the three vertices' v_rand), appends
// divergent triangles (area > S_bar_N) to the divergent buffer and bumps the indirect draw
// command, and splats the regular ones that Alg. 1 keeps.
#include "common.glsl"
#include "vpl_splat.glsl"

#if defined VERTEX_SHADER
in vec3 in_position;
in uint in_vrand;
out vec3 v_position;
out uint v_rand;
void main() {
    v_position = in_position;
    v_rand = in_vrand;
    gl_Position = vec4(in_position, 1.0);
}
#endif

#if defined GEOMETRY_SHADER
layout(triangles) in;
layout(triangle_strip, max_vertices = 4) out;
in vec3 v_position[];
in uint v_rand[];

#if DIVERGENT_APPEND
void store_vertex(uint o, vec3 a, vec3 e1, vec3 e2, vec2 bary, uint tri, uint vr) {
    divergent_vertices[o].position_tri = vec4(a + bary.x * e1 + bary.y * e2, uintBitsToFloat(tri));
    divergent_vertices[o].bary_rand = vec4(bary, uintBitsToFloat(vr), 0.0);
}

// m^2 equal sub-patches (m = 1 unless the top tessellation level is not enough), 3 vertices each.
void append_divergent(vec3 a, vec3 b, vec3 c, float area, uint tri, uint vr) {
    int m = max(1, int(ceil(sqrt(area * TESS_FMAX_TOP / TESS_TARGET_AREA))));
    uint need = uint(3 * m * m);
    uint base = atomicAdd(cmd_reserved, need);
    if (base + need > uint(DIVERGENT_CAPACITY)) return;  // cannot happen: capacity from the scene facts
    atomicMax(cmd_count, base + need);
    vec3 e1 = b - a, e2 = c - a;
    float s = 1.0 / float(m);
    uint o = base;
    for (int i = 0; i < m; ++i) {
        for (int j = 0; j < m - i; ++j) {
            vec2 c00 = vec2(i, j) * s, c10 = vec2(i + 1, j) * s, c01 = vec2(i, j + 1) * s;
            store_vertex(o, a, e1, e2, c00, tri, vr);
            store_vertex(o + 1u, a, e1, e2, c10, tri, vr);
            store_vertex(o + 2u, a, e1, e2, c01, tri, vr);
            o += 3u;
            if (j < m - i - 1) {
                vec2 c11 = vec2(i + 1, j + 1) * s;
                store_vertex(o, a, e1, e2, c10, tri, vr);
                store_vertex(o + 1u, a, e1, e2, c11, tri, vr);
                store_vertex(o + 2u, a, e1, e2, c01, tri, vr);
                o += 3u;
            }
        }
    }
}
#endif

void main() {
    vec3 a = v_position[0], b = v_position[1], c = v_position[2];
    float area = 0.5 * length(cross(b - a, c - a));
    uint tri = uint(gl_PrimitiveIDIn);
    uint vr = v_rand[0] ^ v_rand[1] ^ v_rand[2];
    if (area > FLC_DIVERGENT_AREA) {
#if DIVERGENT_APPEND
        append_divergent(a, b, c, area, tri, vr);
#endif
        return;
    }
    vec3 y = (a + b + c) / 3.0;
    if (u_jitter) {
        // The same jitter as `manylights` (same u_rand, same triangle index): uniform on the triangle.
        uint h = hash_u32(u_rand ^ hash_u32(tri * 2654435761u));
        float u1 = u32_to_unit(h), u2 = u32_to_unit(hash_u32(h ^ 0x9E3779B9u));
        float su = sqrt(u1);
        y = (1.0 - su) * a + su * (1.0 - u2) * b + su * u2 * c;
    }
    flc_splat_triangle(a, b, c, area, u_rand ^ vr, tri, y);
}
#endif
