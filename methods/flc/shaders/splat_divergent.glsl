// Divergent pass (Sec. 6): the patches appended by the regular pass, drawn with an indirect
// command (no CPU read-back), tessellated until every piece is regular (area <= S_bar_N), each
// piece's random value from the noise texture at its vertices' barycentric coordinates in the
// original triangle (Alg. 2, Fig. 8), then splatted as in the regular pass.
#include "common.glsl"
#include "vpl_splat.glsl"
uniform usampler2D u_noise;  // NOISE_SIZE^2 uint32, from the seed

#if defined VERTEX_SHADER
out vec3 v_position;
out vec3 v_normal;
out vec2 v_bary;
out uint v_tri;
out uint v_rand;
void main() {
    DivergentVertex dv = divergent_vertices[gl_VertexID];
    v_position = dv.position_tri.xyz;
    v_normal = dv.normal.xyz;
    v_tri = floatBitsToUint(dv.position_tri.w);
    v_bary = dv.bary_rand.xy;
    v_rand = floatBitsToUint(dv.bary_rand.z);
    gl_Position = vec4(v_position, 1.0);
}
#endif

#if defined TESS_CONTROL_SHADER
layout(vertices = 3) out;
in vec3 v_position[];
in vec3 v_normal[];
in vec2 v_bary[];
in uint v_tri[];
in uint v_rand[];
out vec3 tc_position[];
out vec3 tc_normal[];
out vec2 tc_bary[];
patch out uint tc_tri;
patch out uint tc_rand;
const float tess_fmax[TESS_MAX_LEVEL] = TESS_FMAX;
void main() {
    tc_position[gl_InvocationID] = v_position[gl_InvocationID];
    tc_normal[gl_InvocationID] = v_normal[gl_InvocationID];
    tc_bary[gl_InvocationID] = v_bary[gl_InvocationID];
    if (gl_InvocationID == 0) {
        float area = 0.5 * length(cross(v_position[1] - v_position[0], v_position[2] - v_position[0]));
        // smallest uniform level whose largest piece (measured on this tessellator) is regular
        int n = 1;
        while (n < TESS_MAX_LEVEL && area * tess_fmax[n - 1] > TESS_TARGET_AREA) ++n;
        float level = float(n);
        gl_TessLevelOuter[0] = level;
        gl_TessLevelOuter[1] = level;
        gl_TessLevelOuter[2] = level;
        gl_TessLevelInner[0] = level;
        tc_tri = v_tri[0];
        tc_rand = v_rand[0];
    }
}
#endif

#if defined TESS_EVALUATION_SHADER
layout(triangles, equal_spacing, ccw) in;
in vec3 tc_position[];
in vec3 tc_normal[];
in vec2 tc_bary[];
patch in uint tc_tri;
patch in uint tc_rand;
out vec3 te_position;
out vec3 te_normal;
out uint te_noise;
out uint te_tri;
out uint te_rand;
void main() {
    vec3 t = gl_TessCoord;
    te_position = t.x * tc_position[0] + t.y * tc_position[1] + t.z * tc_position[2];
    te_normal = t.x * tc_normal[0] + t.y * tc_normal[1] + t.z * tc_normal[2];
    vec2 bary = t.x * tc_bary[0] + t.y * tc_bary[1] + t.z * tc_bary[2];
    ivec2 texel = clamp(ivec2(round(bary * float(NOISE_SIZE - 1))), ivec2(0), ivec2(NOISE_SIZE - 1));
    te_noise = texelFetch(u_noise, texel, 0).r;  // v_rand_tess (Alg. 2)
    te_tri = tc_tri;
    te_rand = tc_rand;
    gl_Position = vec4(te_position, 1.0);
}
#endif

#if defined GEOMETRY_SHADER
layout(triangles) in;
layout(triangle_strip, max_vertices = 4) out;
in vec3 te_position[];
in vec3 te_normal[];
in uint te_noise[];
in uint te_tri[];
in uint te_rand[];
void main() {
    vec3 a = te_position[0], b = te_position[1], c = te_position[2];
    float area = 0.5 * length(cross(b - a, c - a));
    // DIVERGENTRAND (Alg. 2) without u_rand: the base triangle's v_rand xor the three v_rand_tess
    uint key = te_rand[0] ^ te_noise[0] ^ te_noise[1] ^ te_noise[2];
    vec3 bary = vec3(1.0 / 3.0);
    if (u_jitter) {  // its own stream (u_rand_jitter), independent of the level and tile draws
        uint h = hash_u32(u_rand_jitter ^ hash_u32(key));
        float u1 = u32_to_unit(h), u2 = u32_to_unit(hash_u32(h ^ 0x9E3779B9u));
        float su = sqrt(u1);
        bary = vec3(1.0 - su, su * (1.0 - u2), su * u2);
    }
    vec3 y = bary.x * a + bary.y * b + bary.z * c;
    vec3 ns = bary.x * te_normal[0] + bary.y * te_normal[1] + bary.z * te_normal[2];
    flc_splat_triangle(a, b, c, area, key, te_tri[0], y, ns);
}
#endif
