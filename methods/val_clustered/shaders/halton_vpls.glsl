// The paper's VPL generation (Sec. 6): the RSM fetched at N Halton-distributed locations with
// point sampling. Point k takes the Halton pair (bases 2 and 3) of index k + 1, shifted on the
// torus by a per-seed offset (Cranley-Patterson rotation; the same for every frame, so a
// static scene keeps its VPLs and a moving one moves them smoothly); its first coordinate is
// stretched over the L light layers side by side. Every texel is equally likely, so VPL k
// carries the texel's flux times (texel count) / N: an unbiased estimate of the RSM's total.
// Unlit texels give VPLs of flux 0, which the clustering and the gather skip.
#include "vpl_records.glsl"
layout(local_size_x = 64) in;
uniform sampler2D u_rsm_position;
uniform sampler2D u_rsm_normal;
uniform sampler2D u_rsm_flux;
uniform int u_vpl_count;
uniform vec2 u_shift;

float radical_inverse(uint i, uint base) {
    float inv = 1.0 / float(base), f = inv, r = 0.0;
    while (i > 0u) {
        r += f * float(i % base);
        i /= base;
        f *= inv;
    }
    return r;
}

void main() {
    int k = int(gl_GlobalInvocationID.x);
    if (k >= u_vpl_count) return;
    uint index = uint(k) + 1u;
    vec2 h = fract(vec2(radical_inverse(index, 2u), radical_inverse(index, 3u)) + u_shift);
    float x = h.x * float(u_rsm_layer_count);
    int layer = min(int(x), u_rsm_layer_count - 1);
    int res = u_rsm_resolution;
    ivec2 within = clamp(ivec2(vec2(fract(x), h.y) * float(res)), ivec2(0), ivec2(res - 1));
    ivec2 t = ivec2(layer % u_rsm_tiles_x, layer / u_rsm_tiles_x) * res + within;
    vec4 p = texelFetch(u_rsm_position, t, 0);
    float texels = float(u_rsm_layer_count) * float(res) * float(res);
    vec4 flux = p.w == 0.0 ? vec4(0.0) : texelFetch(u_rsm_flux, t, 0);
    vpls[k].position = vec4(p.xyz, flux.a * (texels / float(u_vpl_count)));  // .w: area it stands for
    vpls[k].normal = vec4(texelFetch(u_rsm_normal, t, 0).xyz, 0.0);
    vpls[k].flux = vec4(flux.rgb * (texels / float(u_vpl_count)), 0.0);
}
