// Light assignment, step 2: the indirect dispatch size of the per-(cluster, 32-VPL word) pass,
// from the number of geometry clusters found this frame.
#include "topology.glsl"
layout(local_size_x = 1) in;
uniform uint u_words;

void main() {
    uint items = geo_cluster_count * u_words;
    dispatch_args[0] = (items + uint(LA_GROUP) - 1u) / uint(LA_GROUP);
    dispatch_args[1] = 1u;
    dispatch_args[2] = 1u;
}
