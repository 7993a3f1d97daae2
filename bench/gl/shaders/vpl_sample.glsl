// CDF pass 4: draw u_vpl_count VPLs from the RSM texels with probability q_i / Q (the integer
// weights of rsm_cdf_blocks.glsl, Q their total), stratified: VPL k takes u in [k, k+1) / N.
// VPL k carries flux_i / (N q_i / Q), so the sum over VPLs is an unbiased estimate of the sum
// over all RSM texels (the one-bounce flux the RSM holds). u is a 53-bit double so that
// floor(u Q) is uniform over 0..Q-1 to ~1e-6 relative even for Q near 2^32.
#include "common.glsl"
#include "vpl_records.glsl"
layout(local_size_x = 64) in;
uniform sampler2D u_rsm_position;
uniform sampler2D u_rsm_normal;
uniform sampler2D u_rsm_flux;
uniform uint u_block_count;
uniform int u_vpl_count;
uniform uint u_rand;
layout(std430, binding = BINDING_RSM_CDF) readonly buffer TexelCdf { uint texel_cdf[]; };
layout(std430, binding = BINDING_RSM_BLOCK_CDF) readonly buffer BlockCdf { uint block_cdf[]; };

void main() {
    int k = int(gl_GlobalInvocationID.x);
    if (k >= u_vpl_count) return;
    uint total = block_cdf[u_block_count - 1u];
    if (total == 0u) {  // nothing lit: no flux to carry
        vpls[k].position = vec4(0.0);
        vpls[k].normal = vec4(0.0, 0.0, 1.0, 0.0);
        vpls[k].flux = vec4(0.0);
        return;
    }
    uint h1 = hash_u32(u_rand ^ hash_u32(uint(k) * 2u + 0x2545F491u));
    uint h2 = hash_u32(h1 ^ 0x9E3779B9u);
    double xi = (double(h1) * 2097152.0LF + double(h2 >> 11)) * (1.0LF / 9007199254740992.0LF);  // [0, 1), 53 bits
    double u = (double(k) + xi) / double(u_vpl_count);
    uint target = min(uint(floor(u * double(total))), total - 1u);

    // block: smallest j with block_cdf[j] > target
    uint lo = 0u, hi = u_block_count - 1u;
    while (lo < hi) {
        uint mid = (lo + hi) / 2u;
        if (block_cdf[mid] > target) hi = mid; else lo = mid + 1u;
    }
    uint rest = target - (lo > 0u ? block_cdf[lo - 1u] : 0u);
    // texel: smallest i in the block with texel_cdf[i] > rest
    uint first = lo * uint(CDF_BLOCK);
    uint a = first, b = first + uint(CDF_BLOCK) - 1u;
    while (a < b) {
        uint mid = (a + b) / 2u;
        if (texel_cdf[mid] > rest) b = mid; else a = mid + 1u;
    }
    uint q = texel_cdf[a] - (a > first ? texel_cdf[a - 1u] : 0u);

    ivec2 t = rsm_atlas_texel(a);
    vec4 flux = texelFetch(u_rsm_flux, t, 0);
    float share = float(double(total) / (double(u_vpl_count) * double(q)));  // 1 / (N pdf)
    // .w: the surface area this VPL stands for, its texel's footprint / (N pdf)
    vpls[k].position = vec4(texelFetch(u_rsm_position, t, 0).xyz, flux.a * share);
    vpls[k].normal = vec4(texelFetch(u_rsm_normal, t, 0).xyz, 0.0);
    vpls[k].flux = vec4(flux.rgb * share, 0.0);
}
