// Regular pass (Sec. 6): one draw of the whole scene. The geometry shader computes each
// triangle's area and random value (Alg. 2: u_rand xor the three vertices' v_rand), appends
// divergent triangles (area > S_bar_N) to the divergent buffer and bumps the indirect draw
// command, and splats the regular ones that Alg. 1 keeps. With REGULAR_SELECTED the draw holds
// only the triangles select_regular.glsl kept, in scene order, and kept_triangles[] gives each
// one's scene index (gl_PrimitiveIDIn counts the kept ones).
#include "common.glsl"
#include "vpl_splat.glsl"

#if defined VERTEX_SHADER
in vec3 in_position;
in vec3 in_normal;
in uint in_vrand;
out vec3 v_position;
out vec3 v_normal;
out uint v_rand;
void main() {
    v_position = in_position;
    v_normal = in_normal;
    v_rand = in_vrand;
    gl_Position = vec4(in_position, 1.0);
}
#endif

#if defined GEOMETRY_SHADER
layout(triangles) in;
layout(triangle_strip, max_vertices = 4) out;
in vec3 v_position[];
in vec3 v_normal[];
in uint v_rand[];

vec3 shading_normal(vec3 bary) {  // interpolated vertex normals (normalised by the caller)
    return bary.x * v_normal[0] + bary.y * v_normal[1] + bary.z * v_normal[2];
}

#if REGULAR_SELECTED
layout(std430, binding = BINDING_KEPT_TRIANGLES) readonly buffer KeptTriangles { uint kept_triangles[]; };
#endif

#if DIVERGENT_APPEND
void store_vertex(uint o, vec3 a, vec3 e1, vec3 e2, vec2 bary, uint tri, uint vr) {
    divergent_vertices[o].position_tri = vec4(a + bary.x * e1 + bary.y * e2, uintBitsToFloat(tri));
    divergent_vertices[o].bary_rand = vec4(bary, uintBitsToFloat(vr), 0.0);
    divergent_vertices[o].normal = vec4(shading_normal(vec3(1.0 - bary.x - bary.y, bary)), 0.0);
}

// m^2 equal sub-patches (each small enough for tessellation level TESS_SUB_LEVEL), 3 vertices
// each; only the sub-patches a light can reach (flc_patch_may_be_lit) are appended: the others
// hold only VPLs of zero power, which add nothing (dropping them keeps the estimate unbiased).
// One loop and one call site of the test (llvmpipe runs every GS invocation through the whole
// compiled shader: a larger append path slows the regular pass of every triangle).
void append_divergent(vec3 a, vec3 b, vec3 c, float area, uint tri, uint vr) {
    int m = max(1, int(ceil(sqrt(area * TESS_FMAX_SUB / TESS_TARGET_AREA))));
    vec3 e1 = b - a, e2 = c - a;
    float s = 1.0 / float(m);
    for (int i = 0; i < m; ++i) {
        for (int j = 0; j < m - i; ++j) {
            for (int t = 0; t < 2; ++t) {   // the upright sub-triangle, then the inverted one
                if (t == 1 && j >= m - i - 1) break;
                vec2 p0 = vec2(i + t, j) * s, p1 = vec2(i + 1, j + t) * s, p2 = vec2(i, j + 1) * s;
                if (!flc_patch_may_be_lit(a + p0.x * e1 + p0.y * e2, a + p1.x * e1 + p1.y * e2, a + p2.x * e1 + p2.y * e2))
                    continue;
                uint o = atomicAdd(cmd_reserved, 3u);
                if (o + 3u > uint(DIVERGENT_CAPACITY)) return;  // cannot happen: capacity from the scene facts
                atomicMax(cmd_count, o + 3u);
                store_vertex(o, a, e1, e2, p0, tri, vr);
                store_vertex(o + 1u, a, e1, e2, p1, tri, vr);
                store_vertex(o + 2u, a, e1, e2, p2, tri, vr);
            }
        }
    }
}
#endif

void main() {
    vec3 a = v_position[0], b = v_position[1], c = v_position[2];
    float area = 0.5 * length(cross(b - a, c - a));
#if REGULAR_SELECTED
    uint tri = kept_triangles[gl_PrimitiveIDIn];
#else
    uint tri = uint(gl_PrimitiveIDIn);
#endif
    uint vr = v_rand[0] ^ v_rand[1] ^ v_rand[2];
    if (area > FLC_DIVERGENT_AREA) {
#if DIVERGENT_APPEND
        append_divergent(a, b, c, area, tri, vr);
#endif
        return;
    }
    vec3 bary = vec3(1.0 / 3.0);
    if (u_jitter) {
        // The same jitter as `manylights` (same stream value, same triangle index): uniform on the triangle.
        uint h = hash_u32(u_rand_jitter ^ hash_u32(tri * 2654435761u));
        float u1 = u32_to_unit(h), u2 = u32_to_unit(hash_u32(h ^ 0x9E3779B9u));
        float su = sqrt(u1);
        bary = vec3(1.0 - su, su * (1.0 - u2), su * u2);
    }
    vec3 y = bary.x * a + bary.y * b + bary.z * c;
    flc_splat_triangle(a, b, c, area, vr, tri, y, shading_normal(bary));
}
#endif
