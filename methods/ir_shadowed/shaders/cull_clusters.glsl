// Which triangle clusters each hemicube face sees: invocation (cluster c, instance i = VPL k x
// HEMICUBE_FACES + face f) keeps cluster c for face f when its bounding sphere is not wholly
// outside one of the face's four side planes (w = |x|, w = |y| in the face's frame, the planes
// vpl_shadow_maps.glsl clips with). A kept pair is counted for cluster c (u_scatter 0), then, once
// the commands hold each cluster's run of ids, i is written into c's run (u_scatter 1; both runs
// take the same test, clusters.glsl). A cluster outside a plane has every vertex outside it, so
// each of its triangles would be clipped away whole: the atlas is the one drawing every triangle
// into every face gives, at a fraction of the draws.
#include "hemicube.glsl"
#include "clusters.glsl"

layout(local_size_x = CULL_GROUP) in;
uniform int u_scatter;

void main() {
    int c = int(gl_GlobalInvocationID.x);
    int instance = int(gl_WorkGroupID.y);
    if (c >= u_cluster_count) return;
    int k = instance / HEMICUBE_FACES, f = instance % HEMICUBE_FACES;
    Vpl v = vpls[k];
    vec3 axis, right, up;
    hemicube_face(f, v.normal.xyz, axis, right, up);
    Cluster cl = clusters[c];
    vec3 rel = cl.sphere.xyz - hemicube_origin(v);
    float w = dot(rel, axis), x = dot(rel, right), y = dot(rel, up);
    // signed distance to the plane w = x is (w - x) / sqrt(2): outside when below -radius
    float reach = 1.41421357 * cl.sphere.w;
    if (w - x < -reach || w + x < -reach || w - y < -reach || w + y < -reach) return;
    if (u_scatter == 0) atomicAdd(cluster_counts[c].x, 1u);
    else cluster_instances[atomicAdd(cluster_counts[c].y, 1u)] = uint(instance);
}
