// CDF pass 1: the largest texel flux luminance of the RSM (the scale of the integer weights).
// Max is exact in floating point, so the result does not depend on the reduction order; the
// bits of a non-negative float order like the float, hence atomicMax on them.
#include "vpl_records.glsl"
layout(local_size_x = CDF_BLOCK) in;
uniform sampler2D u_rsm_flux;
layout(std430, binding = BINDING_RSM_MAX) buffer FluxMax { uint flux_max_bits; };
shared float partial[CDF_BLOCK];

void main() {
    uint i = gl_GlobalInvocationID.x, l = gl_LocalInvocationID.x;
    partial[l] = i < rsm_texel_count() ? flux_luminance(texelFetch(u_rsm_flux, rsm_atlas_texel(i), 0).rgb) : 0.0;
    barrier();
    for (uint half_size = uint(CDF_BLOCK) / 2u; half_size > 0u; half_size >>= 1) {
        if (l < half_size) partial[l] = max(partial[l], partial[l + half_size]);
        barrier();
    }
    if (l == 0u) atomicMax(flux_max_bits, floatBitsToUint(partial[0]));
}
