// Light assignment, step 3 (paper V.C): for every geometry cluster and every word of 32 VPLs,
// a bit mask of the VPLs that may light the cluster: a VPL in the cluster's own visibility
// cluster always; a VPL of another visibility cluster C when the cone from it through one of
// C's gates meets the cluster's bounding sphere (the sphere around its bounding box), whatever
// cluster lies beyond that gate ("all cones created from the combination of the VPL and a
// visibility gate", paper V.C): conservative for the gather's walk through gates, whose first
// gate is one of C's. Brute force over the VPLs, as in the paper.
#include "vpl_records.glsl"
#include "topology.glsl"
layout(local_size_x = LA_GROUP) in;
uniform int u_vpl_count;
uniform uint u_words;
uniform bool u_use_gates;

void main() {
    uint item = gl_GlobalInvocationID.x;
    if (item >= geo_cluster_count * u_words) return;
    uint g = item / u_words, word = item % u_words;
    GeoCluster gc = geo_clusters[g];
    int d = int(gc.lo.w);
    vec3 s = 0.5 * (gc.lo.xyz + gc.hi.xyz);
    float rho = 0.5 * length(gc.hi.xyz - gc.lo.xyz);
    uint mask = 0u;
    for (uint b = 0u; b < 32u; ++b) {
        int k = int(word * 32u + b);
        if (k >= u_vpl_count) break;
        int c = vpl_cluster[k];
        if (c < 0) continue;  // a VPL without flux
        if (c == d) { mask |= 1u << b; continue; }
        if (!u_use_gates) continue;
        vec3 y = vpls[k].position.xyz;
        ivec2 range = adjacency_range[c];
        for (int e = range.x; e < range.y; ++e) {
            if (cone_meets_sphere(adjacency[e].y, y, s, rho)) { mask |= 1u << b; break; }
        }
    }
    light_masks[g * u_words + word] = mask;
}
