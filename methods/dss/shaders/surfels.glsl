// Surfel generation (Deep Screen Space, Sec. 3): every triangle of the scene, visible or not,
// goes through the tessellator as a 3-vertex patch. The control stage picks levels from the
// (sub-)triangle's edge lengths and area so that sub-triangles have about the target area
// (uniform density in object space; level 1 = the whole triangle: refine, never decimate).
// The geometry stage turns each sub-triangle into one surfel at its centroid with its exact
// area and the shadowed direct light reaching both sides of its shading normal (B = rho E per
// side), E averaged over the 4^IRRADIANCE_SPLITS centroids of the sub-triangle's regular
// subdivision (a quadrature of the sub-triangle's mean irradiance: a point sample at the
// centroid alone misjudges a sub-triangle a spot's cone edge crosses). The shading normal is
// the vertex normals interpolated at each point (Mitsuba's shading frame); the incident
// cosine is taken against it, the shadow-map offset along the geometric normal.
// Triangles needing more than MAX_TESS_LEVEL are pre-split on the CPU into K x K sub-patches
// of the regular subdivision (one patch record per sub-triangle q < K^2).
// COUNT_ONLY: just count the surfels (prepare() sizes the surfel buffer with it).
#include "common.glsl"
#if !COUNT_ONLY
#include "direct_lighting.glsl"
#endif
#include "dss_common.glsl"

// normal.w: the triangle's key (an integer < 2^24, exact in float32; method.py triangle_keys);
// n_i: vertex normals
struct DssTriangle { vec4 v0; vec4 v1; vec4 v2; vec4 normal; vec4 n0; vec4 n1; vec4 n2; };
layout(std430, binding = BINDING_DSS_TRIANGLES) readonly buffer DssTriangleBlock { DssTriangle dss_triangles[]; };
layout(std430, binding = BINDING_DSS_PATCHES) readonly buffer DssPatchBlock { uvec4 dss_patches[]; };  // triangle, K, q, 0

uniform float u_target_area;   // a (m^2)
uniform float u_edge_length;   // edge of a sub-triangle of area a in the tessellator's pattern (m)
uniform uint u_capacity;       // surfel records the buffer holds

#if defined VERTEX_SHADER
out vec3 v_position;
out vec3 v_normal;   // vertex normals interpolated at the patch corner (not normalised: linear)
flat out uint v_triangle;
flat out uint v_patch;

// Barycentric coordinates in (a, b, c) of corner `corner` of sub-triangle q of the regular
// K x K subdivision: row r holds the r + 1 upright triangles with lattice a + b = r and the r
// inverted ones with a + b = r - 1.
vec3 sub_triangle_corner(uint K, uint q, uint corner) {
    uint r = uint(sqrt(float(q)));
    while (r * r > q) r--;
    while ((r + 1u) * (r + 1u) <= q) r++;
    uint col = q - r * r;
    uvec2 ij;
    if (col <= r) {
        uvec2 base = uvec2(r - col, col);
        ij = corner == 0u ? base : corner == 1u ? base + uvec2(1u, 0u) : base + uvec2(0u, 1u);
    } else {
        uint j = col - r - 1u;
        uvec2 base = uvec2(r - 1u - j, j);
        ij = corner == 0u ? base + uvec2(1u, 0u) : corner == 1u ? base + uvec2(1u, 1u) : base + uvec2(0u, 1u);
    }
    float inv_k = 1.0 / float(K);
    vec2 uv = vec2(ij) * inv_k;
    return vec3(1.0 - uv.x - uv.y, uv.x, uv.y);
}

void main() {
    uint p = uint(gl_VertexID) / 3u, corner = uint(gl_VertexID) % 3u;
    uvec4 rec = dss_patches[p];
    DssTriangle tri = dss_triangles[rec.x];
    if (rec.y == 1u) {
        v_position = corner == 0u ? tri.v0.xyz : corner == 1u ? tri.v1.xyz : tri.v2.xyz;
        v_normal = corner == 0u ? tri.n0.xyz : corner == 1u ? tri.n1.xyz : tri.n2.xyz;
    } else {
        vec3 w = sub_triangle_corner(rec.y, rec.z, corner);
        v_position = w.x * tri.v0.xyz + w.y * tri.v1.xyz + w.z * tri.v2.xyz;
        v_normal = w.x * tri.n0.xyz + w.y * tri.n1.xyz + w.z * tri.n2.xyz;
    }
    v_triangle = rec.x;
    v_patch = p;
}
#endif

#if defined TESS_CONTROL_SHADER
layout(vertices = 3) out;
in vec3 v_position[];
in vec3 v_normal[];
flat in uint v_triangle[];
flat in uint v_patch[];
out vec3 c_position[];
out vec3 c_normal[];
patch out uint c_triangle;
patch out uint c_patch;

float edge_level(vec3 p, vec3 q) {
    return clamp(round(length(q - p) / u_edge_length), 1.0, float(MAX_TESS_LEVEL));
}

void main() {
    c_position[gl_InvocationID] = v_position[gl_InvocationID];
    c_normal[gl_InvocationID] = v_normal[gl_InvocationID];
    if (gl_InvocationID == 0) {
        vec3 p0 = v_position[0], p1 = v_position[1], p2 = v_position[2];
        float area = 0.5 * length(cross(p1 - p0, p2 - p0));
        // outer level i belongs to the edge opposite corner i
        gl_TessLevelOuter[0] = edge_level(p1, p2);
        gl_TessLevelOuter[1] = edge_level(p2, p0);
        gl_TessLevelOuter[2] = edge_level(p0, p1);
        // inner level n gives about TRIANGLES_PER_LEVEL_SQ n^2 sub-triangles
        gl_TessLevelInner[0] = clamp(round(sqrt(area / (TRIANGLES_PER_LEVEL_SQ * u_target_area))),
                                     1.0, float(MAX_TESS_LEVEL));
        c_triangle = v_triangle[0];
        c_patch = v_patch[0];
    }
}
#endif

#if defined TESS_EVALUATION_SHADER
layout(triangles, equal_spacing, ccw) in;
in vec3 c_position[];
in vec3 c_normal[];
patch in uint c_triangle;
patch in uint c_patch;
out vec3 e_position;
out vec3 e_normal;
out vec3 e_coord;
flat out uint e_triangle;
flat out uint e_patch;
void main() {
    vec3 u = gl_TessCoord;
    e_position = u.x * c_position[0] + u.y * c_position[1] + u.z * c_position[2];
    e_normal = u.x * c_normal[0] + u.y * c_normal[1] + u.z * c_normal[2];
    e_coord = u;
    e_triangle = c_triangle;
    e_patch = c_patch;
    gl_Position = vec4(0.0, 0.0, 0.0, 1.0);
}
#endif

#if defined GEOMETRY_SHADER
layout(triangles) in;
layout(points, max_vertices = 1) out;   // nothing is rasterised: surfels go to the SSBO
in vec3 e_position[];
in vec3 e_normal[];
in vec3 e_coord[];
flat in uint e_triangle[];
flat in uint e_patch[];
void main() {
    uint index = atomicAdd(surfel_count, 1u);
#if !COUNT_ONLY
    if (index >= u_capacity) return;
    uint t = e_triangle[0];
    vec3 y = (e_position[0] + e_position[1] + e_position[2]) / 3.0;
    float area = 0.5 * length(cross(e_position[1] - e_position[0], e_position[2] - e_position[0]));
    vec3 n = dss_triangles[t].normal.xyz;
    vec3 rho = triangle_albedo[t].rgb;
    // mean irradiance over the centroids of the n x n subdivision (n = 2^IRRADIANCE_SPLITS):
    // upright cell (i, j), i + j < n, at ((i, j) + 1/3) / n; inverted (i + j < n - 1) at + 2/3
    const int splits = 1 << IRRADIANCE_SPLITS;
    vec3 front = vec3(0.0), back = vec3(0.0);
    for (int k = 0; k < splits * splits; ++k) {
        int i = k / splits, j = k % splits;
        vec2 uv;
        if (i + j < splits) uv = (vec2(i, j) + 1.0 / 3.0) / float(splits);
        else uv = (vec2(splits - 1 - i, splits - 1 - j) + 2.0 / 3.0) / float(splits);   // i + j >= n: inverted cell
        vec3 w = vec3(1.0 - uv.x - uv.y, uv.x, uv.y);
        vec3 p = w.x * e_position[0] + w.y * e_position[1] + w.z * e_position[2];
        vec3 ns = w.x * e_normal[0] + w.y * e_normal[1] + w.z * e_normal[2];
        float len = length(ns);
        ns = len > 0.0 ? ns / len : n;
        front += direct_irradiance(p, ns, n, true);
        back += direct_irradiance(p, -ns, n, true);
    }
    float inv_count = 1.0 / float(splits * splits);
    front *= rho * inv_count;
    back *= rho * inv_count;
    vec3 ns = e_normal[0] + e_normal[1] + e_normal[2];
    float len = length(ns);
    ns = len > 0.0 ? ns / len : n;
    float lf = luminance(front), lb = luminance(back);
    atomicMax(max_luminance_bits, floatBitsToUint(max(max(lf, lb), 0.0)));
    // independent of the order the GPU emits surfels in, so the sub-buffer choice is deterministic,
    // and of the triangle's index: the triangle's key (normal.w, from its centroid relative to the
    // scene, set in prepare), its sub-patch q and the sub-triangle's tessellation coordinates
    vec3 cc = (e_coord[0] + e_coord[1] + e_coord[2]) / 3.0;
    uint triangle_key = uint(dss_triangles[t].normal.w);
    uint key = hash_u32(triangle_key * 2654435761u ^ hash_u32(dss_patches[e_patch[0]].z ^
                        hash_u32(floatBitsToUint(cc.x) ^ hash_u32(floatBitsToUint(cc.y)))));
#if EXACT_CONTACT
    // the albedo in the spare w's: the splat's contact radiosity (rule (5)) is rho E at the contact
    surfels[index] = Surfel(vec4(y, area), n, key, vec4(front, lf), vec4(back, lb), vec4(ns, rho.r),
                            vec4(e_position[0] - y, rho.g), vec4(e_position[1] - y, rho.b));
#else
    surfels[index] = Surfel(vec4(y, area), n, key, vec4(front, lf), vec4(back, lb), vec4(ns, 0.0));
#endif
#endif
}
#endif
