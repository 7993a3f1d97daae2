// Geometry-aware blur of the interleaved gather (paper Sec. 6, after Laine et al. 2007): the
// mean over the B x B window (shifted to stay inside the image, so that it holds each of the
// B^2 interleaved VPL subsets once) of the pixels whose position is within alpha (10% of the
// scene extent) of this pixel's and whose normal has a dot product > beta (0.8) with its
// normal; then L = rho / pi^2 * mean. With u_max_visibility_diff < 1 the mean's visible share
// (the luminance of the gathered sums over that of the same VPLs' sums without visibility, alpha)
// is replaced by the share over the window's pixels on this pixel's side of a contact shadow's
// edge: those whose VAL-level visible share (u_visible_share, val_visibility.glsl) is not above
// this pixel's by more than u_max_visibility_diff, nor below it by more across a step (off this
// pixel's tangent plane by a sine over BLUR_STEP_SINE). The unshadowed light, smooth across such
// an edge (a lit face 2 cm in front of a shadowed one, same normal), is still averaged over all
// B^2 subsets; a darker neighbour on the same plane counts, as in the paper's blur.
#include "fullscreen.glsl"
#include "vpl_records.glsl"
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_normal;
uniform sampler2D u_gbuffer_albedo;
uniform sampler2D u_gathered;
uniform sampler2D u_visible_share;   // VAL-level visible share per pixel (val_visibility.glsl)
uniform int u_interleave;
uniform float u_max_distance;
uniform float u_min_normal_dot;
uniform float u_max_visibility_diff;

#if defined FRAGMENT_SHADER
layout(location = 0) out vec4 out_radiance;
void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec4 p = texelFetch(u_gbuffer_position, px, 0);
    if (p.w == 0.0) { out_radiance = vec4(0.0); return; }
    vec3 n = texelFetch(u_gbuffer_normal, px, 0).xyz;
    ivec2 size = textureSize(u_gathered, 0);
    ivec2 lo = clamp(px - ivec2(u_interleave / 2), ivec2(0), max(size - ivec2(u_interleave), ivec2(0)));
    float share = texelFetch(u_visible_share, px, 0).r;
    vec3 sum = vec3(0.0);
    float count = 0.0;
    vec2 all_y = vec2(0.0), near_y = vec2(0.0);   // (shadowed, unshadowed) luminance: all, similar share
    for (int dy = 0; dy < u_interleave; ++dy) {
        for (int dx = 0; dx < u_interleave; ++dx) {
            ivec2 q = lo + ivec2(dx, dy);
            if (any(greaterThanEqual(q, size))) continue;
            vec4 pq = texelFetch(u_gbuffer_position, q, 0);
            if (pq.w == 0.0) continue;
            if (length(pq.xyz - p.xyz) > u_max_distance) continue;
            if (dot(texelFetch(u_gbuffer_normal, q, 0).xyz, n) <= u_min_normal_dot) continue;
            vec4 g = texelFetch(u_gathered, q, 0);
            sum += g.rgb;
            count += 1.0;
            vec2 y = vec2(flux_luminance(g.rgb), g.a);
            all_y += y;
            // a much brighter neighbour never counts; a much darker one only on this pixel's tangent plane
            float above = texelFetch(u_visible_share, q, 0).r - share;
            vec3 to_q = pq.xyz - p.xyz;
            if (above <= u_max_visibility_diff
                && (-above <= u_max_visibility_diff || abs(dot(to_q, n)) <= BLUR_STEP_SINE * length(to_q))) near_y += y;
        }
    }
    // the window's mean, its visible share replaced by that of the pixels with a similar share
    if (u_max_visibility_diff < 1.0 && all_y.x > 0.0 && near_y.y > 0.0)
        sum *= (near_y.x / near_y.y) / (all_y.x / all_y.y);
    vec3 rho = texelFetch(u_gbuffer_albedo, px, 0).rgb;
    out_radiance = vec4(rho * (INV_PI * INV_PI) * sum / max(count, 1.0), 1.0);
}
#endif
