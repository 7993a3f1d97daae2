// SSDO's view scale, the first pass: a power-of-two grid (P x Q, the largest powers of two not
// above the view's width and height) where each texel holds (sum of view depths, number of
// covered pixels) over its block of 1 or 2 x 1 or 2 GBuffer pixels. The method then builds
// this texture's mipmaps (2 x 2 averages, exact on power-of-two levels); in the 1 x 1 level
// r / g = (total depth) / (covered pixels) is the exact mean view depth of the covered pixels,
// read by the sampling pass on the GPU (no readback).
#include "fullscreen.glsl"
uniform sampler2D u_gbuffer_position;
uniform mat4 u_view_proj;
uniform ivec2 u_grid;               // P x Q

#if defined FRAGMENT_SHADER
layout(location = 0) out vec2 out_depth;
void main() {
    ivec2 size = textureSize(u_gbuffer_position, 0);
    ivec2 o = ivec2(gl_FragCoord.xy);
    ivec2 lo = (o * size) / u_grid, hi = ((o + 1) * size) / u_grid;
    vec2 acc = vec2(0.0);
    for (int y = lo.y; y < hi.y; ++y)
        for (int x = lo.x; x < hi.x; ++x) {
            vec4 p = texelFetch(u_gbuffer_position, ivec2(x, y), 0);
            if (p.w != 0.0) acc += vec2((u_view_proj * vec4(p.xyz, 1.0)).w, 1.0);
        }
    out_depth = acc;
}
#endif
