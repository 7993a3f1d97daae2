// CDF pass 3: inclusive prefix sum of the block totals, in place, by one work group walking
// the blocks CDF_BLOCK at a time with a running carry.
layout(local_size_x = CDF_BLOCK) in;
uniform uint u_block_count;
layout(std430, binding = BINDING_RSM_BLOCK_CDF) buffer BlockCdf { uint block_cdf[]; };
shared uint partial[CDF_BLOCK];
shared uint carry;

void main() {
    uint l = gl_LocalInvocationID.x;
    if (l == 0u) carry = 0u;
    barrier();
    for (uint start = 0u; start < u_block_count; start += uint(CDF_BLOCK)) {
        uint j = start + l;
        partial[l] = j < u_block_count ? block_cdf[j] : 0u;
        barrier();
        for (uint offset = 1u; offset < uint(CDF_BLOCK); offset <<= 1) {
            uint add = l >= offset ? partial[l - offset] : 0u;
            barrier();
            partial[l] += add;
            barrier();
        }
        if (j < u_block_count) block_cdf[j] = carry + partial[l];
        barrier();
        if (l == 0u) carry += partial[CDF_BLOCK - 1];
        barrier();
    }
}
