// Identification of unique geometry clusters (clustered shading, Olsson et al. 2012, local
// sort): one work group per TILE x TILE screen tile. Each view sample's key is its depth slice
// (exponential in view depth) and its visibility cluster, so all samples of a geometry cluster
// share one visibility cluster (the paper's added constraint). The keys are sorted in shared
// memory (bitonic), the unique ones counted (prefix sum), given global indices with one
// atomicAdd per tile, and each unique key's bounding box computed from its sorted run.
#include "topology.glsl"
layout(local_size_x = TILE * TILE) in;
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_normal;
uniform ivec2 u_size;
uniform vec3 u_eye;
uniform vec3 u_forward;
uniform float u_slice_near;        // view depth where slice 0 ends
uniform float u_slice_log_scale;   // DEPTH_SLICES / log(far / near)

const uint INVALID_KEY = 0xFFFFFFFFu;
shared uint keys[TILE * TILE];
shared uint pixels[TILE * TILE];
shared uint ranks[TILE * TILE];
shared uint base_index;

void main() {
    uint l = gl_LocalInvocationID.x;
    ivec2 px = ivec2(gl_WorkGroupID.xy) * TILE + ivec2(int(l) % TILE, int(l) / TILE);
    uint key = INVALID_KEY;
    if (px.x < u_size.x && px.y < u_size.y) {
        vec4 p = texelFetch(u_gbuffer_position, px, 0);
        if (p.w != 0.0) {
            int vc = cluster_at(p.xyz, texelFetch(u_gbuffer_normal, px, 0).xyz);
            float depth = max(dot(p.xyz - u_eye, u_forward), u_slice_near);
            int slice = clamp(int(floor(log(depth / u_slice_near) * u_slice_log_scale)), 0, DEPTH_SLICES - 1);
            key = (uint(slice) << CLUSTER_BITS) | uint(vc);
        }
    }
    keys[l] = key;
    pixels[l] = l;
    barrier();
    // bitonic sort of (key, pixel) pairs, ascending
    for (uint size = 2u; size <= uint(TILE * TILE); size <<= 1) {
        for (uint stride = size >> 1; stride > 0u; stride >>= 1) {
            uint partner = l ^ stride;
            uint k0 = keys[l], p0 = pixels[l], k1 = keys[partner], p1 = pixels[partner];
            barrier();
            if (partner != l) {
                bool ascending = (l & size) == 0u;
                bool lower = l < partner;
                bool greater = k0 > k1 || (k0 == k1 && p0 > p1);
                bool take = (lower == ascending) ? greater : !greater;
                if (take) { keys[l] = k1; pixels[l] = p1; }
            }
            barrier();
        }
    }
    uint k = keys[l];
    bool first = k != INVALID_KEY && (l == 0u || keys[l - 1u] != k);
    ranks[l] = first ? 1u : 0u;
    barrier();
    for (uint offset = 1u; offset < uint(TILE * TILE); offset <<= 1) {
        uint add = l >= offset ? ranks[l - offset] : 0u;
        barrier();
        ranks[l] += add;
        barrier();
    }
    if (l == 0u) {
        uint unique_count = ranks[TILE * TILE - 1];
        base_index = unique_count > 0u ? atomicAdd(geo_cluster_count, unique_count) : 0u;
    }
    barrier();
    uint own = pixels[l];
    ivec2 own_px = ivec2(gl_WorkGroupID.xy) * TILE + ivec2(int(own) % TILE, int(own) / TILE);
    int id = k != INVALID_KEY ? int(base_index + ranks[l] - 1u) : -1;
    if (own_px.x < u_size.x && own_px.y < u_size.y) pixel_cluster[own_px.y * u_size.x + own_px.x] = id;
    if (first) {
        vec3 lo = vec3(3.0e38), hi = vec3(-3.0e38);
        for (uint j = l; j < uint(TILE * TILE) && keys[j] == k; ++j) {
            uint q = pixels[j];
            vec3 x = texelFetch(u_gbuffer_position, ivec2(gl_WorkGroupID.xy) * TILE + ivec2(int(q) % TILE, int(q) / TILE), 0).xyz;
            lo = min(lo, x);
            hi = max(hi, x);
        }
        geo_clusters[id].lo = vec4(lo, float(k & ((1u << CLUSTER_BITS) - 1u)));
        geo_clusters[id].hi = vec4(hi, 0.0);
    }
}
