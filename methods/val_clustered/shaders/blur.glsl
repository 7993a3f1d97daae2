// Geometry-aware blur of the interleaved gather (paper Sec. 6, after Laine et al. 2007): the
// mean over the B x B window (shifted to stay inside the image, so that it holds each of the
// B^2 interleaved VPL subsets once) of the pixels whose position is within alpha (10% of the
// scene extent) of this pixel's and whose normal has a dot product > beta (0.8) with its
// normal; then L = rho / pi^2 * mean.
#include "fullscreen.glsl"
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_normal;
uniform sampler2D u_gbuffer_albedo;
uniform sampler2D u_gathered;
uniform int u_interleave;
uniform float u_max_distance;
uniform float u_min_normal_dot;

#if defined FRAGMENT_SHADER
layout(location = 0) out vec4 out_radiance;
void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec4 p = texelFetch(u_gbuffer_position, px, 0);
    if (p.w == 0.0) { out_radiance = vec4(0.0); return; }
    vec3 n = texelFetch(u_gbuffer_normal, px, 0).xyz;
    ivec2 size = textureSize(u_gathered, 0);
    ivec2 lo = clamp(px - ivec2(u_interleave / 2), ivec2(0), max(size - ivec2(u_interleave), ivec2(0)));
    vec3 sum = vec3(0.0);
    float count = 0.0;
    for (int dy = 0; dy < u_interleave; ++dy) {
        for (int dx = 0; dx < u_interleave; ++dx) {
            ivec2 q = lo + ivec2(dx, dy);
            if (any(greaterThanEqual(q, size))) continue;
            vec4 pq = texelFetch(u_gbuffer_position, q, 0);
            if (pq.w == 0.0) continue;
            if (length(pq.xyz - p.xyz) > u_max_distance) continue;
            if (dot(texelFetch(u_gbuffer_normal, q, 0).xyz, n) <= u_min_normal_dot) continue;
            sum += texelFetch(u_gathered, q, 0).rgb;
            count += 1.0;
        }
    }
    vec3 rho = texelFetch(u_gbuffer_albedo, px, 0).rgb;
    out_radiance = vec4(rho * (INV_PI * INV_PI) * sum / max(count, 1.0), 1.0);
}
#endif
