// CDF pass 2: integer weight per RSM texel and its inclusive prefix sum within blocks of
// CDF_BLOCK texels (Hillis-Steele scan in shared memory), plus each block's total.
//
// Weights are integers q = ceil(lum / lum_max * u_levels), at least 1 wherever the flux is not
// zero: integer sums are exact in any order (the CDF is monotone and deterministic), and
// every lit texel keeps a non-zero probability, which keeps the VPL estimate unbiased.
// u_levels * (padded texel count) < 2^32, so no sum overflows.
#include "vpl_records.glsl"
layout(local_size_x = CDF_BLOCK) in;
uniform sampler2D u_rsm_flux;
uniform uint u_levels;
layout(std430, binding = BINDING_RSM_MAX) readonly buffer FluxMax { uint flux_max_bits; };
layout(std430, binding = BINDING_RSM_CDF) writeonly buffer TexelCdf { uint texel_cdf[]; };
layout(std430, binding = BINDING_RSM_BLOCK_CDF) writeonly buffer BlockCdf { uint block_cdf[]; };
shared uint partial[CDF_BLOCK];

void main() {
    uint i = gl_GlobalInvocationID.x, l = gl_LocalInvocationID.x;
    float lum = i < rsm_texel_count() ? flux_luminance(texelFetch(u_rsm_flux, rsm_atlas_texel(i), 0).rgb) : 0.0;
    float lum_max = uintBitsToFloat(flux_max_bits);
    uint q = 0u;
    if (lum > 0.0) q = clamp(uint(ceil(lum / lum_max * float(u_levels))), 1u, u_levels);
    partial[l] = q;
    barrier();
    for (uint offset = 1u; offset < uint(CDF_BLOCK); offset <<= 1) {
        uint add = l >= offset ? partial[l - offset] : 0u;
        barrier();
        partial[l] += add;
        barrier();
    }
    texel_cdf[i] = partial[l];
    if (l == uint(CDF_BLOCK) - 1u) block_cdf[gl_WorkGroupID.x] = partial[l];
}
