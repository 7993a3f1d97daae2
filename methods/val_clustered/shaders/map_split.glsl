// The (VAL, triangle) pairs of a chunk (see map_pairs.glsl), one invocation each (x: triangle,
// y: VAL). On a software rasteriser every drawn primitive costs a fixed set-up (binning, edge
// equations) whatever its size, and most pairs are far smaller than a map texel (at 128^2,
// half of big_floor's 250 k pairs cover no texel centre at all). So a pair that needs no
// tessellation and whose image's bounding box holds at most SPLAT_MAX_TEXELS texel centres of
// the tile is rasterised here: each texel centre inside the projected triangle (the chord
// triangle of the untessellated draw, edges included) where the draw's clip distances would
// keep it receives the exact distance along the texel's direction to the triangle's plane,
// beyond the ignore radius, by an atomic minimum into the splat image (float bits: positive
// floats order as uints), merged into the atlas afterwards (map_merge.glsl). The other
// survivors are listed for the draws: pairs whose projected edges must be split from the back
// of the pair buffer (paraboloid_depth_tess.glsl), the rest (large, or with a corner near the
// VAL's antipode, whose image is unbounded) from the front (paraboloid_depth.glsl). Dropped:
// pairs of an empty VAL (no VPL maps to it: nothing reads its map), triangles entirely behind
// the VAL's plane, inside its ignore radius (the three corners inside the ball: convexity) or
// seen edge-on. The list lengths (x 3 vertices) are the `count`s of two DrawArraysIndirect
// commands (5 uints apart, moderngl's stride), reset before the pass. The order of the listed
// pairs varies from run to run, the maps do not: every path keeps the minimum distance.
#include "map_pairs.glsl"
layout(local_size_x = 64) in;
layout(std430, binding = BINDING_MAP_COMMANDS) buffer MapCommands { uint map_commands[]; };
layout(r32ui, binding = 0) uniform coherent uimage2D u_splat;
uniform uint u_chunk_triangles;   // triangles in this chunk
uniform int u_tiles_x;
uniform int u_resolution;

void list_pair(int j, uint triangle, bool tessellated) {
    uint k = atomicAdd(map_commands[tessellated ? 5 : 0], 3u) / 3u;
    map_pairs[tessellated ? u_pair_capacity - 1u - k : k] = encode_pair(j, triangle);
}

float edge_side(vec2 a, vec2 b, vec2 p) { return (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x); }

void main() {
    uint local_triangle = gl_GlobalInvocationID.x;
    int j = u_val_first + int(gl_WorkGroupID.y);
    Val c = vals[j];
    if (local_triangle >= u_chunk_triangles || c.position.w <= 0.0) return;
    uint triangle = u_first_triangle + local_triangle;
    vec3 t, b;
    orthonormal_basis(c.normal.xyz, t, b);
    vec3 r0 = corner_in_val_frame(triangle, 0u, c, t, b);
    vec3 r1 = corner_in_val_frame(triangle, 1u, c, t, b);
    vec3 r2 = corner_in_val_frame(triangle, 2u, c, t, b);
    float ignore = ignore_radius(c);
    if (max(r0.z, max(r1.z, r2.z)) <= 0.0) return;                                   // behind
    if (max(length(r0), max(length(r1), length(r2))) < ignore) return;                // inside
    vec3 plane;
    if (!val_plane(r0, r1, r2, plane)) return;                                       // edge-on
    float level = max(edge_level(r1, r2), max(edge_level(r2, r0), edge_level(r0, r1)));
    if (level > 1.0) { list_pair(j, triangle, true); return; }
    // paraboloid uv of the corners in texel units of the tile (a corner far behind the VAL's
    // plane projects towards infinity: such a pair is drawn and clipped by GL)
    float res = float(u_resolution);
    vec3 d0 = normalize(r0), d1 = normalize(r1), d2 = normalize(r2);
    if (min(d0.z, min(d1.z, d2.z)) <= SPLAT_MIN_COS - 1.0) { list_pair(j, triangle, false); return; }
    vec2 p0 = (d0.xy / (1.0 + d0.z) + 1.0) * 0.5 * res;
    vec2 p1 = (d1.xy / (1.0 + d1.z) + 1.0) * 0.5 * res;
    vec2 p2 = (d2.xy / (1.0 + d2.z) + 1.0) * 0.5 * res;
    // texel centres i + 0.5 inside the bounding box and the tile (the draw's clip distances 0-3)
    ivec2 lo = max(ivec2(ceil(min(p0, min(p1, p2)) - 0.5)), ivec2(0));
    ivec2 hi = min(ivec2(floor(max(p0, max(p1, p2)) - 0.5)), ivec2(u_resolution - 1));
    ivec2 n = hi - lo + 1;
    if (n.x <= 0 || n.y <= 0) return;                                                // no texel centre
    if (n.x * n.y > SPLAT_MAX_TEXELS) { list_pair(j, triangle, false); return; }
    float area = edge_side(p0, p1, p2);
    if (area == 0.0) return;                                                         // covers no area
    ivec2 tile = ivec2(j % u_tiles_x, j / u_tiles_x) * u_resolution;
    for (int k = 0; k < n.x * n.y; ++k) {
        ivec2 texel = lo + ivec2(k % n.x, k / n.x);
        vec2 q = vec2(texel) + 0.5;
        // barycentric coordinates of the texel centre in the projected (chord) triangle
        vec3 w = vec3(edge_side(p1, p2, q), edge_side(p2, p0, q), edge_side(p0, p1, q)) / area;
        if (min(w.x, min(w.y, w.z)) < 0.0) continue;
        // the draw's clip distance 4, dir.z interpolated across the image: behind the VAL's plane
        if (dot(w, vec3(d0.z, d1.z, d2.z)) < 0.0) continue;
        vec2 uv = q / res * 2.0 - 1.0;   // as the fragment stage: the inverse paraboloid projection
        float uu = dot(uv, uv);
        vec3 dir = vec3(2.0 * uv, 1.0 - uu) / (1.0 + uu);
        float inv_dist = dot(plane, dir);
        if (inv_dist <= 0.0) continue;
        float dist = 1.0 / inv_dist;
        if (dist < ignore) continue;
        imageAtomicMin(u_splat, tile + texel, floatBitsToUint(dist));
    }
}
