// Indirect lighting (paper V.D): every pixel sums the VPLs its geometry cluster was assigned,
// with ir_unshadowed's Lambertian VPL term, term for term:
//   L(x) = rho_x / pi * sum_k Phi_k / pi * <n_x, w>+ <n_k, -w>+ / max(eps, |y_k - x|)^2
// A VPL of another visibility cluster counts only if the pixel lies in the light cone from the
// VPL through a gate of the VPL's cluster into the pixel's cluster, or through a chain of
// gates: the segment VPL -> pixel walks from cluster to cluster through the gates it crosses
// and reaches the pixel's (reaches_through_gates; the final cone test, paper V.D).
#include "fullscreen.glsl"
#include "vpl_records.glsl"
#include "topology.glsl"
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_normal;
uniform sampler2D u_gbuffer_albedo;
uniform int u_width;
uniform int u_vpl_count;
uniform uint u_words;
uniform uint u_word_first;  // this draw sums the VPLs of words [first, end): LOOP_CHUNK
uniform uint u_word_end;
uniform uint u_bit_mask;    // the VPLs of each word this draw sums (a word split over draws: LOOP_CHUNK)
uniform float u_eps;

#if defined FRAGMENT_SHADER
layout(location = 0) out vec4 out_radiance;
void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec4 p = texelFetch(u_gbuffer_position, px, 0);
    int g = pixel_cluster[px.y * u_width + px.x];
    if (p.w == 0.0 || g < 0) { out_radiance = vec4(0.0); return; }
    vec3 x = p.xyz;
    vec3 nx = texelFetch(u_gbuffer_normal, px, 0).xyz;
    vec3 rho_x = texelFetch(u_gbuffer_albedo, px, 0).rgb;
    int d = int(geo_clusters[g].lo.w);
    vec3 sum = vec3(0.0);
    for (uint word = u_word_first; word < u_word_end; ++word) {
        uint mask = light_masks[uint(g) * u_words + word] & u_bit_mask;
        while (mask != 0u) {
            int b = findLSB(mask);
            mask &= mask - 1u;
            int k = int(word) * 32 + b;
            Vpl v = vpls[k];
            vec3 transfer = vpl_transfer(v, x, nx, u_eps);
            if (transfer == vec3(0.0)) continue;
            int c = vpl_cluster[k];
            if (c != d && !reaches_through_gates(c, d, v.position.xyz, x)) continue;
            sum += transfer;
        }
    }
    out_radiance = vec4(rho_x * (INV_PI * INV_PI) * sum, 1.0);
}
#endif
