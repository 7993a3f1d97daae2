// Cluster split by visibility (issue #23, opt-in `split_clusters` > 0; a correction to the
// paper's Sec. 5, see the method's manual). After the maps of the paper's M VALs are drawn, VPL i
// stays in its VAL C(i) if that VAL's map origin sees it: the hard test of val_visibility.glsl
// with the VPL standing in for the receiver (moved off its surface the same way, at least twice
// the origin's lift); a VPL facing away from the origin or behind its plane is not seen.
// Otherwise (SPLIT_REASSIGN) it goes to the nearest VAL under the paper's distance whose origin
// sees it (counted in assign_stats[0]); if none does (or without SPLIT_REASSIGN) it becomes an
// orphan (vpl_cluster = -1 - C(i), counted in assign_stats[1]), and the orphans are clustered
// again, by the same k-means, into spare VALs, each with a map of its own: a cluster across a
// wall is split into its two sides instead of lighting one room with the other's visibility.
// RECOUNT = 1: VPL counts of every VAL under the final mapping (counts zeroed before);
// RECOUNT = 2: copied into the VAL records (the VPL count in position.w).
#include "val_records.glsl"
layout(local_size_x = 64) in;
layout(std430, binding = BINDING_ASSIGN_STATS) buffer AssignStats { uint assign_stats[]; };
uniform int u_vpl_count;

#if RECOUNT == 1
void main() {
    int k = int(gl_GlobalInvocationID.x);
    if (k < u_vpl_count && vpls[k].flux.rgb != vec3(0.0) && vpl_cluster[k] >= 0)
        atomicAdd(val_vpl_count[vpl_cluster[k]], 1u);
}
#elif RECOUNT == 2
void main() {
    int j = int(gl_GlobalInvocationID.x);
    if (j < u_cluster_count) vals[j].position.w = float(val_vpl_count[j]);
}
#else
uniform sampler2D u_depth_atlas;
uniform int u_tiles_x;
uniform int u_resolution;
uniform float u_normal_offset;

bool origin_sees(int j, vec3 x, vec3 n) {
    Val c = vals[j];
    vec3 o = val_origin(c);
    vec3 to_val = o - x;
    float dist = length(to_val);
    if (dist <= 0.0) return true;
    vec3 wi = to_val / dist;
    float cos_r = dot(n, wi);
    if (cos_r <= 0.0) return false;                 // the VPL sends no light towards the origin
    float cos0;
    paraboloid_uv(c, -to_val, cos0);
    float texel = dist * 2.0 * (1.0 + max(cos0, 0.0)) / float(u_resolution);
    float sin_r = sqrt(max(1.0 - cos_r * cos_r, 0.0));
    // (at least twice the origin's lift: the medoid VPL itself is seen)
    vec3 q = x + n * max(u_normal_offset * texel * (0.5 + 1.5 * sin_r), 2.0 * u_val_lift);
    vec3 rel = q - o;
    float cos_theta;
    vec2 uv = paraboloid_uv(c, rel, cos_theta);
    if (cos_theta <= 0.0) return false;             // behind the VAL's plane: outside its map
    ivec2 tile = ivec2(j % u_tiles_x, j / u_tiles_x);
    ivec2 t = clamp(ivec2((uv * 0.5 + 0.5) * float(u_resolution)), ivec2(0), ivec2(u_resolution - 1));
    float stored = texelFetch(u_depth_atlas, tile * u_resolution + t, 0).r;
    return length(rel) <= stored + texel;
}

void main() {
    int k = int(gl_GlobalInvocationID.x);
    if (k >= u_vpl_count) return;
    Vpl v = vpls[k];
    if (v.flux.rgb == vec3(0.0)) return;            // joins no cluster (unlit Halton texel)
    int c0 = vpl_cluster[k];
    vec3 p = v.position.xyz, n = v.normal.xyz;
    if (c0 < 0 || origin_sees(c0, p, n)) return;
#if SPLIT_REASSIGN
    // first the nearest VAL (the paper's distance) whose origin sees it
    int best = -1;
    float best_d = 3.0e38;
    for (int j = 0; j < u_val_end; ++j) {
        if (j == c0 || vals[j].position.w <= 0.0) continue;   // an empty VAL has no map
        float d = cluster_distance(p, n, vals[j]);
        if (d < best_d && origin_sees(j, p, n)) { best_d = d; best = j; }
    }
    if (best >= 0) {
        vpl_cluster[k] = best;
        atomicAdd(assign_stats[0], 1u);
        return;
    }
#endif
    vpl_cluster[k] = -1 - c0;
    atomicAdd(assign_stats[1], 1u);
}
#endif
