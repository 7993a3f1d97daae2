// One DrawElementsIndirect command per cluster (clusters.py): its triangles, instanced once per
// hemicube face that kept it, the faces' ids packed from baseInstance on (an exclusive prefix sum
// of the per-cluster counts, in cluster order; one invocation: a few thousand clusters). Each
// cluster's second slot becomes the next free place of its run for the scattering cull.
#include "clusters.glsl"
layout(local_size_x = 1) in;
void main() {
    uint offset = 0u;
    for (int c = 0; c < u_cluster_count; ++c) {
        uint n = cluster_counts[c].x;
        uint at = 5u * uint(c);
        cluster_commands[at + 0u] = 3u * clusters[c].range.x;
        cluster_commands[at + 1u] = n;
        cluster_commands[at + 2u] = 3u * clusters[c].range.y;
        cluster_commands[at + 3u] = 0u;
        cluster_commands[at + 4u] = offset;
        cluster_counts[c].y = offset;
        offset += n;
    }
}
