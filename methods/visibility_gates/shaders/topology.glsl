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
uniform float u_gate_scale;         // gate size multiplier (1: the opening's polygon, or the paper's disk)

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

struct Gate {
    vec4 centre_radius;  // xyz polygon centre, w radius of the ball holding the polygon (before u_gate_scale)
    vec4 normal;         // xyz unit normal (along the skeleton), w number of edges (exact float)
    vec4 axis_u;         // xyz unit axis u in the gate's plane (v = normal x u)
    ivec4 sides;         // x: cluster on the -normal side, y: on the +normal side
    vec4 edges[MAX_GATE_EDGES];  // half-planes m.(q.u, q.v) <= offset: xy = m, z = offset (before u_gate_scale)
};
layout(std430, binding = BINDING_GATES) readonly buffer GateBlock { Gate gates[]; };

// Visibility cluster of a surface point: looked up one voxel off the surface along n (the side
// the point is seen from / emits to), so a wall's two faces find the rooms on their two sides.
// In a voxel a gate's plane cuts (the gate's own, or its wall's beside it; grid value
// -(gate + 2)) the side of the gate's plane decides between the gate's two clusters.
int cluster_at(vec3 p, vec3 n) {
    vec3 q = p + n * u_grid_pitch;
    ivec3 v = clamp(ivec3(floor((q - u_grid_origin) / u_grid_pitch)), ivec3(0), u_grid_dims - 1);
    int c = texelFetch(u_cluster_grid, v, 0).r;
    if (c < -1) {  // topology.cluster_grid
        int g = -c - 2;
        c = dot(q - gates[g].centre_radius.xyz, gates[g].normal.xyz) >= 0.0 ? gates[g].sides.y : gates[g].sides.x;
    }
    return c;
}

// Where the segment y -> x crosses gate g's polygon: its parameter t in (0, 1), or -1.
float gate_crossing(int g, vec3 y, vec3 x) {
    vec3 c = gates[g].centre_radius.xyz;
    vec3 n = gates[g].normal.xyz, u = gates[g].axis_u.xyz;
    float sy = dot(y - c, n), sx = dot(x - c, n);
    if (sy * sx >= 0.0 || u_gate_scale <= 0.0) return -1.0;  // both on one side (or on the plane); no gate
    float t = sy / (sy - sx);
    vec3 q = y + t * (x - y) - c;
    vec2 p = vec2(dot(q, u), dot(q, cross(n, u)));
    int edges = int(gates[g].normal.w);
    for (int i = 0; i < edges; ++i) {
        vec4 e = gates[g].edges[i];
        if (dot(e.xy, p) > e.z * u_gate_scale) return -1.0;
    }
    return t;
}

// Exact test of the fragment shader: does light from y (cluster c) reach x (cluster d != c)
// through the gates? The segment leaves each cluster through the first of its gates it crosses
// (smallest t beyond the previous crossing) into the cluster beyond, for at most GATE_HOPS
// gates; x is lit when that walk enters d.
bool reaches_through_gates(int c, int d, vec3 y, vec3 x) {
    int k = c;
    float t_prev = 0.0;
    for (int hop = 0; hop < GATE_HOPS; ++hop) {
        float t_best = 2.0;
        int next = -1;
        ivec2 range = adjacency_range[k];
        for (int e = range.x; e < range.y; ++e) {
            float t = gate_crossing(adjacency[e].y, y, x);
            if (t > t_prev && t < t_best) { t_best = t; next = adjacency[e].x; }
        }
        if (next < 0) return false;
        if (next == d) return true;
        k = next;
        t_prev = t_best;
    }
    return false;
}

// Conservative test of the light assignment: can the cone from y through gate g meet the sphere
// (s, rho)? The polygon lies in the ball B(c, r), whose tangent cone from y has
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
