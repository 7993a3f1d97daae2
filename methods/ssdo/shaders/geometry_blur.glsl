// One axis of SSDO's geometry-aware blur: a box of u_blur_size taps along u_axis over the
// interleaved indirect image, keeping only neighbours on the centre pixel's surface: distance
// from the centre's tangent plane <= u_depth_threshold x the centre's view depth (a plane test,
// so slanted floors blur as well as frontal walls) and normal cosine >= u_normal_threshold.
// The window is centred, an odd number of taps -h .. h with h = u_blur_size / 2, so it never
// shifts the image: an odd u_blur_size is a plain box of u_blur_size taps; an even one has
// u_blur_size + 1 taps whose two end taps weigh 1/2 (effective width u_blur_size). With the
// width a multiple of the pattern size, every sample set of the M x M block enters each pixel
// with the same weight (the two half-weight ends share one set).
// Input/output: rgb = indirect radiance, a = view depth (0 = background).
#include "fullscreen.glsl"
uniform sampler2D u_input;
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_normal;
uniform ivec2 u_axis;                // (1, 0) or (0, 1)
uniform int u_blur_size;             // effective window width along the axis (see above)
uniform float u_depth_threshold;     // tangent-plane distance / view depth
uniform float u_normal_threshold;    // minimum cosine between normals

#if defined FRAGMENT_SHADER
layout(location = 0) out vec4 out_radiance;
void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec4 c = texelFetch(u_input, px, 0);
    if (c.a == 0.0) { out_radiance = vec4(0.0); return; }
    ivec2 size = textureSize(u_input, 0);
    vec3 nc = texelFetch(u_gbuffer_normal, px, 0).xyz;
    vec3 pc = texelFetch(u_gbuffer_position, px, 0).xyz;
    float max_offset = u_depth_threshold * c.a;
    vec3 sum = vec3(0.0);
    float count = 0.0;
    int h = u_blur_size / 2;                                   // taps -h .. h (2h + 1, odd)
    float end_weight = (u_blur_size % 2 == 0) ? 0.5 : 1.0;
    for (int j = -h; j <= h; ++j) {
        ivec2 q = px + u_axis * j;
        if (any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, size))) continue;
        vec4 s = texelFetch(u_input, q, 0);
        if (s.a == 0.0) continue;
        if (j != 0 && abs(dot(nc, texelFetch(u_gbuffer_position, q, 0).xyz - pc)) > max_offset) continue;
        if (j != 0 && dot(texelFetch(u_gbuffer_normal, q, 0).xyz, nc) < u_normal_threshold) continue;
        float wgt = (j == -h || j == h) && h > 0 ? end_weight : 1.0;
        sum += wgt * s.rgb;
        count += wgt;
    }
    out_radiance = vec4(sum / count, c.a);   // count >= 1: the centre always enters
}
#endif
