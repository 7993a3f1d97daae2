// The emitter hierarchy (the article's closing suggestion against O(n^2): a quadtree of the
// surfels): one level of nodes per dispatch, from the leaves up (hierarchy.py). A leaf copies
// its texel's surfel; an internal node merges its children (j = i + 1, skip[j], ... while
// j < skip[i]) into one disk: summed area, area-weighted mean position, normal and radiosity
// of each side, so the emitted power area * B is conserved. Also per node, for the gather:
// normal.w = bounding radius (children's centres and radii), radiosity_front.w = the leaves'
// area-weighted mean area, radiosity_back.w = 1 when the node is flat (every leaf with the
// node's normal, on its plane), else 0.
#include "pbgi_records.glsl"
layout(local_size_x = 64) in;

layout(std430, binding = BINDING_PBGI_SURFELS) readonly buffer SurfelBlock { Surfel surfels[]; };
layout(std430, binding = BINDING_PBGI_EMITTERS) buffer NodeBlock { Surfel nodes[]; };
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
        vec3 an = abs(s.normal.xyz);
        float axis_cos = max(max(an.x, an.y), max(an.z, 0.57735027));
        s.normal.w = 0.70710678 * u_texel_m / axis_cos;
        s.radiosity_front.w = s.position_area.w;
        s.radiosity_back.w = 1.0;
        nodes[i] = s;
        return;
    }
    float area = 0.0;
    vec3 p = vec3(0.0), n = vec3(0.0), bf = vec3(0.0), bb = vec3(0.0);
    float leaf_area = 0.0;
    for (int j = i + 1; j < link.x; j = links[j].x) {
        Surfel c = nodes[j];
        float a = c.position_area.w;
        area += a;
        leaf_area += a * c.radiosity_front.w;
        p += a * c.position_area.xyz;
        n += a * c.normal.xyz;
        bf += a * c.radiosity_front.rgb;
        bb += a * c.radiosity_back.rgb;
    }
    float inv = area > 0.0 ? 1.0 / area : 0.0;
    p *= inv;
    float len = length(n);
    n = len > 0.0 ? n / len : nodes[i + 1].normal.xyz;
    float radius = 0.0;
    bool flat_ = true;
    for (int j = i + 1; j < link.x; j = links[j].x) {
        Surfel c = nodes[j];
        radius = max(radius, distance(c.position_area.xyz, p) + c.normal.w);
        flat_ = flat_ && c.radiosity_back.w > 0.5 && dot(c.normal.xyz, n) >= 1.0 - FLAT_COSINE_TOLERANCE;
    }
    for (int j = i + 1; j < link.x; j = links[j].x)
        flat_ = flat_ && abs(dot(nodes[j].position_area.xyz - p, n)) <= FLAT_DISTANCE_TOLERANCE * radius;
    nodes[i].position_area = vec4(p, area);
    nodes[i].normal = vec4(n, radius);
    nodes[i].radiosity_front = vec4(bf * inv, leaf_area * inv);
    nodes[i].radiosity_back = vec4(bb * inv, flat_ ? 1.0 : 0.0);
}
