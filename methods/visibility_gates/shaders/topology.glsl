// Visibility Gates topology on the GPU: the voxel -> visibility cluster grid, the gates, the
// cluster adjacency (which gates join cluster C to its neighbours), the VPLs' clusters, the
// geometry clusters of clustered shading and their VPL masks. Coordinates are re-centred
// world coordinates (GpuScene.origin), like the GBuffer's.
#ifndef VG_TOPOLOGY_GLSL
#define VG_TOPOLOGY_GLSL

uniform isampler3D u_cluster_grid;  // visibility cluster of every voxel
uniform vec3 u_grid_origin;         // corner of voxel (0, 0, 0)
uniform float u_grid_pitch;         // voxel edge
uniform ivec3 u_grid_dims;
uniform float u_gate_scale;         // gate radius multiplier (1: the paper's min of the two maximal balls)

struct Gate {
    vec4 centre_radius;  // xyz disk centre, w radius (before u_gate_scale)
    vec4 normal;         // xyz unit disk normal (along the segmented skeleton edge)
};
layout(std430, binding = BINDING_GATES) readonly buffer GateBlock { Gate gates[]; };
// cluster C's neighbours: entries [adjacency_range[C].x, adjacency_range[C].y) of adjacency,
// each (neighbour cluster D, gate index): one entry per gate, in both directions
layout(std430, binding = BINDING_ADJ_RANGES) readonly buffer AdjRangeBlock { ivec2 adjacency_range[]; };
layout(std430, binding = BINDING_ADJ_ENTRIES) readonly buffer AdjEntryBlock { ivec2 adjacency[]; };
layout(std430, binding = BINDING_VPL_CLUSTER) buffer VplClusterBlock { int vpl_cluster[]; };

struct GeoCluster {
    vec4 lo;  // bounding box of the cluster's view samples; w = visibility cluster (exact float)
    vec4 hi;
};
layout(std430, binding = BINDING_GEO_CLUSTERS) buffer GeoClusterBlock { GeoCluster geo_clusters[]; };
layout(std430, binding = BINDING_PIXEL_CLUSTER) buffer PixelClusterBlock { int pixel_cluster[]; };
layout(std430, binding = BINDING_CLUSTER_COUNT) buffer ClusterCountBlock { uint geo_cluster_count; uint dispatch_args[3]; };
layout(std430, binding = BINDING_LIGHT_MASKS) buffer LightMaskBlock { uint light_masks[]; };

// Visibility cluster of a surface point: looked up one voxel off the surface along n (the side
// the point is seen from / emits to), so a wall's two faces find the rooms on their two sides.
int cluster_at(vec3 p, vec3 n) {
    vec3 q = (p + n * u_grid_pitch - u_grid_origin) / u_grid_pitch;
    ivec3 v = clamp(ivec3(floor(q)), ivec3(0), u_grid_dims - 1);
    return texelFetch(u_cluster_grid, v, 0).r;
}

// Exact test of the fragment shader: does the segment y -> x cross gate g's disk?
bool segment_crosses_gate(int g, vec3 y, vec3 x) {
    vec3 c = gates[g].centre_radius.xyz;
    float r = gates[g].centre_radius.w * u_gate_scale;
    vec3 n = gates[g].normal.xyz;
    float sy = dot(y - c, n), sx = dot(x - c, n);
    if (sy * sx >= 0.0) return false;  // both on one side (or on the plane)
    float t = sy / (sy - sx);
    vec3 q = y + t * (x - y) - c;
    return dot(q, q) <= r * r;
}

// Conservative test of the light assignment: can the cone from y through gate g's disk meet
// the sphere (s, rho)? The disk lies in the ball B(c, r), whose tangent cone from y has
// half-angle asin(r / |c - y|); a sphere meets that cone iff its centre is within the cone
// widened by asin(rho / |s - y|). The sphere must also reach the far side of the gate plane.
bool cone_meets_sphere(int g, vec3 y, vec3 s, float rho) {
    vec3 c = gates[g].centre_radius.xyz;
    float r = gates[g].centre_radius.w * u_gate_scale;
    vec3 n = gates[g].normal.xyz;
    float sy = dot(y - c, n), ss = dot(s - c, n);
    if (sy == 0.0 || (sy * ss > 0.0 && abs(ss) > rho)) return false;
    vec3 to_gate = c - y, to_sphere = s - y;
    float dg = length(to_gate), ds = length(to_sphere);
    if (dg <= r || ds <= rho) return true;
    float cos_phi = clamp(dot(to_gate, to_sphere) / (dg * ds), -1.0, 1.0);
    return acos(cos_phi) <= asin(r / dg) + asin(rho / ds);
}

#endif
