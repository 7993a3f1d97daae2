// Hierarchical emitters (the article's closing suggestion: fewer, coarser emitters): the
// surfels of one 2^L x 2^L block of texels of one chart merged into one disk with the summed
// area, the area-weighted mean position and normal, and the area-weighted mean radiosity of
// each side, so the emitted power area * B is conserved.
#include "pbgi_records.glsl"
layout(local_size_x = 64) in;

struct ClusterRange { int first; int count; int pad0; int pad1; };
layout(std430, binding = BINDING_PBGI_CLUSTER_RANGES) readonly buffer RangeBlock { ClusterRange ranges[]; };
layout(std430, binding = BINDING_PBGI_SURFELS) readonly buffer SurfelBlock { Surfel surfels[]; };
layout(std430, binding = BINDING_PBGI_EMITTERS) writeonly buffer EmitterBlock { Surfel emitters[]; };
uniform int u_cluster_count;

void main() {
    int c = int(gl_GlobalInvocationID.x);
    if (c >= u_cluster_count) return;
    ClusterRange r = ranges[c];
    float area = 0.0;
    vec3 p = vec3(0.0), n = vec3(0.0), bf = vec3(0.0), bb = vec3(0.0);
    for (int i = r.first; i < r.first + r.count; ++i) {
        Surfel s = surfels[i];
        float a = s.position_area.w;
        area += a;
        p += a * s.position_area.xyz;
        n += a * s.normal.xyz;
        bf += a * s.radiosity_front.rgb;
        bb += a * s.radiosity_back.rgb;
    }
    float inv = area > 0.0 ? 1.0 / area : 0.0;
    float len = length(n);
    emitters[c].position_area = vec4(p * inv, area);
    emitters[c].normal = vec4(len > 0.0 ? n / len : surfels[r.first].normal.xyz, 0.0);
    emitters[c].radiosity_front = vec4(bf * inv, 0.0);
    emitters[c].radiosity_back = vec4(bb * inv, 0.0);
}
