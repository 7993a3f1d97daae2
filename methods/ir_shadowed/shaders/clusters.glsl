// Triangle clusters (clusters.py): the scene's triangles in Morton order, CLUSTER_TRIANGLES a
// cluster, each with a bounding sphere. The culling pass counts per cluster the hemicube faces
// (instances) that keep it; the command pass gives each cluster an instanced draw command whose
// faces' ids the culling pass, run again, packs from its baseInstance on.
#ifndef CLUSTERS_GLSL
#define CLUSTERS_GLSL
struct Cluster {
    vec4 sphere;        // xyz centre (re-centred scene coordinates), w radius (padded)
    uvec4 range;        // x triangle count, y first triangle, zw unused
};
layout(std430, binding = BINDING_CLUSTERS) readonly buffer ClusterBlock { Cluster clusters[]; };
layout(std430, binding = BINDING_CLUSTER_COUNTS) buffer CountBlock { uvec2 cluster_counts[]; };  // (faces, next slot)
layout(std430, binding = BINDING_CLUSTER_COMMANDS) buffer CommandBlock { uint cluster_commands[]; };
layout(std430, binding = BINDING_CLUSTER_INSTANCES) buffer InstanceBlock { uint cluster_instances[]; };
uniform int u_cluster_count;
#endif
