// Light assignment, step 1: the visibility cluster of every VPL (looked up one voxel off its
// surface along its normal, the side it emits on).
#include "vpl_records.glsl"
#include "topology.glsl"
layout(local_size_x = 64) in;
uniform int u_vpl_count;

void main() {
    int k = int(gl_GlobalInvocationID.x);
    if (k >= u_vpl_count) return;
    Vpl v = vpls[k];
    vpl_cluster[k] = v.flux.rgb == vec3(0.0) ? -1 : cluster_at(v.position.xyz, v.normal.xyz);
}
