// The emitter hierarchy (the article's closing suggestion against O(n^2): a tree of the
// surfels, here one octree over every texel of the scene under one root per normal class,
// hierarchy.py): one level of nodes per dispatch, from the leaves up. A leaf is its texel's
// surfel; an internal node merges its children (j = i + 1, skip[j], ... while j < skip[i]).
//
// What a node must reproduce: its leaves send towards a far receiver in direction w the power
//     P(w) = sum_i a_i [B_front,i max(n_i.w, 0) + B_back,i max(-n_i.w, 0)]
//          = w . D + sum_i |n_i.w| a_i (B_front,i + B_back,i) / 2,
//     D = sum_i a_i (B_front,i - B_back,i) / 2 n_i      (max(x, 0) = (x + |x|) / 2)
// and when every n_i.w has the same sign the last sum is |w . S|, S = sum_i a_i (B_front,i +
// B_back,i) / 2 n_i. D and S (one 3-vector per colour) are sums over the leaves: a node adds
// its children's, exactly (the emitted power is conserved, and for a flat node P(w) is the
// disk a B |cos_e| of its summed area and mean radiosity). The sign condition holds for every
// w on a flat node, and on a curved one for the directions further from its plane than its
// normals' spread (within a normal class, at most 55 degrees); where it fails, |w . S|
// undercounts (by twice the power of the leaves facing w the other way), and refine_ratio -> 0
// makes it exact (a disk of the mean normal, the first version, overcounts the directions all
// its leaves face by sum a / |sum a n| on a curved node). Also per node: the area-weighted
// centroid, the summed area, a bounding radius (children's centres and radii), the leaves'
// area-weighted mean area (the near-field term of the transfer), and a flag "flat" (every
// leaf with the node's normal and on its plane).
#include "pbgi_records.glsl"
layout(local_size_x = 64) in;

layout(std430, binding = BINDING_PBGI_SURFELS) readonly buffer SurfelBlock { Surfel surfels[]; };
layout(std430, binding = BINDING_PBGI_EMITTERS) buffer NodeBlock { EmitterNode nodes[]; };
layout(std430, binding = BINDING_PBGI_NODE_LINKS) readonly buffer LinkBlock { ivec2 links[]; };   // (skip, first leaf)
layout(std430, binding = BINDING_PBGI_LEVEL_NODES) readonly buffer LevelBlock { int level_nodes[]; };
uniform int u_first;
uniform int u_count;
uniform float u_texel_m;   // texel side in metres on the chart planes (1 / texels per metre)

void main() {
    int k = int(gl_GlobalInvocationID.x);
    if (k >= u_count) return;
    int i = level_nodes[u_first + k];
    ivec2 link = links[i];
    if (link.x == i + 1) {
        // a texel: its piece of surface lies in the texel square, stretched by 1/|n_axis| on tilted faces
        Surfel s = surfels[link.y];
        vec3 n = s.normal.xyz;
        vec3 an = abs(n);
        float axis_cos = max(max(an.x, an.y), max(an.z, 0.57735027));
        float a = s.position_area.w;
        nodes[i].position_area = s.position_area;
        nodes[i].axis_radius = vec4(n, 0.70710678 * u_texel_m / axis_cos);
        nodes[i].shape = vec4(a, 1.0, 0.0, 0.0);
        for (int c = 0; c < 3; ++c) {
            nodes[i].flux_odd[c] = vec4(0.5 * a * (s.radiosity_front[c] - s.radiosity_back[c]) * n, 0.0);
            nodes[i].flux_even[c] = vec4(0.5 * a * (s.radiosity_front[c] + s.radiosity_back[c]) * n, 0.0);
        }
        return;
    }
    float area = 0.0, leaf_area = 0.0;
    vec3 p = vec3(0.0), n = vec3(0.0);
    vec3 odd[3] = vec3[3](vec3(0.0), vec3(0.0), vec3(0.0));
    vec3 even[3] = vec3[3](vec3(0.0), vec3(0.0), vec3(0.0));
    for (int j = i + 1; j < link.x; j = links[j].x) {
        float a = nodes[j].position_area.w;
        area += a;
        leaf_area += a * nodes[j].shape.x;
        p += a * nodes[j].position_area.xyz;
        n += a * nodes[j].axis_radius.xyz;
        for (int c = 0; c < 3; ++c) {
            odd[c] += nodes[j].flux_odd[c].xyz;
            even[c] += nodes[j].flux_even[c].xyz;
        }
    }
    float inv = area > 0.0 ? 1.0 / area : 0.0;
    p *= inv;
    float len = length(n);
    n = len > 0.0 ? n / len : nodes[i + 1].axis_radius.xyz;
    float radius = 0.0;
    bool flat_ = true;
    for (int j = i + 1; j < link.x; j = links[j].x) {
        vec4 c = nodes[j].axis_radius;
        float cosine = dot(c.xyz, n);
        radius = max(radius, distance(nodes[j].position_area.xyz, p) + c.w);
        flat_ = flat_ && nodes[j].shape.y > 0.5 && cosine >= 1.0 - FLAT_COSINE_TOLERANCE;
    }
    for (int j = i + 1; j < link.x; j = links[j].x)
        flat_ = flat_ && abs(dot(nodes[j].position_area.xyz - p, n)) <= FLAT_DISTANCE_TOLERANCE * radius;
    nodes[i].position_area = vec4(p, area);
    nodes[i].axis_radius = vec4(n, radius);
    nodes[i].shape = vec4(leaf_area * inv, flat_ ? 1.0 : 0.0, 0.0, 0.0);
    for (int c = 0; c < 3; ++c) {
        nodes[i].flux_odd[c] = vec4(odd[c], 0.0);
        nodes[i].flux_even[c] = vec4(even[c], 0.0);
    }
}
