// Upscale + blur (Sec. 6): untile the interleaved-sampling buffer (full-resolution pixel p reads
// tile p mod 2^L at p / 2^L) and smooth it with a separable geometry-aware tent filter (a
// neighbour counts when its normal is within the normal threshold and it lies within
// depth_threshold x camera distance of the pixel's tangent plane). The tent has weights
// r + 1 - |o| for |o| <= r: with r + 1 a multiple of 2^L (default r = 2^L - 1) every tile phase
// weighs the same and each tile's samples are linearly interpolated (no 2^L-pixel blocks).
// The last pass multiplies by the receiver's rho_x / pi (eq. 5).
#include "fullscreen.glsl"
uniform sampler2D u_source;
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_normal;
uniform sampler2D u_gbuffer_albedo;
uniform bool u_from_tiled;
uniform int u_tiles_per_axis;
uniform ivec2 u_tile_size;
uniform ivec2 u_screen;
uniform ivec2 u_direction;
uniform int u_radius;
uniform bool u_apply_albedo;
uniform float u_depth_threshold;
uniform float u_normal_threshold;
uniform vec3 u_camera_pos;

#if defined FRAGMENT_SHADER
layout(location = 0) out vec4 out_radiance;

vec3 source(ivec2 px) {
    if (u_from_tiled) {
        ivec2 phase = px % u_tiles_per_axis;
        return texelFetch(u_source, phase * u_tile_size + px / u_tiles_per_axis, 0).rgb;
    }
    return texelFetch(u_source, px, 0).rgb;
}

void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec4 p = texelFetch(u_gbuffer_position, px, 0);
    if (p.w == 0.0) { out_radiance = vec4(0.0); return; }
    vec3 n = texelFetch(u_gbuffer_normal, px, 0).xyz;
    float plane_tolerance = u_depth_threshold * length(p.xyz - u_camera_pos);
    vec3 sum = vec3(0.0);
    float weight = 0.0;
    for (int o = -u_radius; o <= u_radius; ++o) {
        ivec2 q = px + o * u_direction;
        if (any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, u_screen))) continue;
        vec4 pq = texelFetch(u_gbuffer_position, q, 0);
        if (pq.w == 0.0) continue;
        if (dot(n, texelFetch(u_gbuffer_normal, q, 0).xyz) < u_normal_threshold) continue;
        if (abs(dot(pq.xyz - p.xyz, n)) > plane_tolerance) continue;
        float w = float(u_radius + 1 - abs(o));
        sum += w * source(q);
        weight += w;
    }
    vec3 value = weight > 0.0 ? sum / weight : source(px);
    if (u_apply_albedo) value *= texelFetch(u_gbuffer_albedo, px, 0).rgb * INV_PI;
    out_radiance = vec4(value, 1.0);
}
#endif
