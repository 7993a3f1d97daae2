// Deinterleaved receivers (interleaved sampling, Segovia et al. 2006: the G-buffer split into
// one sub-buffer per tile): texel q of the tiled layout holds the full-resolution pixel the
// splat's fragment q stands for (phase + 2^L i): its position's bits in xyz and its shading
// normal octahedron-encoded (2 x 16-bit snorm) in w. A splat fragment then reads one texel,
// next to its neighbours' (the full-resolution G-buffer read 2^L pixels apart misses the
// cache on a CPU rasteriser and fetches twice the bytes on a GPU).
#include "fullscreen.glsl"
#include "receivers.glsl"
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_normal;

#if defined FRAGMENT_SHADER
layout(location = 0) out uvec4 out_receiver;
void main() {
    ivec2 q = ivec2(gl_FragCoord.xy);
    ivec2 px = tiled_to_pixel(q);
    if (any(greaterThanEqual(px, u_screen))) { out_receiver = uvec4(0u, 0u, 0u, RECEIVER_NONE); return; }
    vec4 p = texelFetch(u_gbuffer_position, px, 0);
    if (p.w == 0.0) { out_receiver = uvec4(0u, 0u, 0u, RECEIVER_NONE); return; }
    out_receiver = uvec4(floatBitsToUint(p.xyz), encode_receiver_normal(texelFetch(u_gbuffer_normal, px, 0).xyz));
}
#endif
