// Upsample and sum: every full-resolution pixel takes level 0 as is and each coarser level
// bilinearly from the four nearest level pixels on its own surface, level pixel X sitting at
// full-resolution pixel X 2^l where its receiver is (deinterleave.glsl) (weights of the rejected
// ones dropped and the rest renormalised; if all four are rejected, the same-surface pixels
// of the 3 x 3 around the nearest one; if none, plain bilinear over the covered ones: a pixel
// on a surface too small for the level still gets its far field), then applies its rho / pi.
#include "fullscreen.glsl"
#include "dss_common.glsl"
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_normal;
uniform sampler2D u_gbuffer_albedo;
uniform sampler2D u_receiver_position;
uniform sampler2D u_receiver_normal;
uniform sampler2D u_levels;            // blurred irradiance, plain level layout
uniform mat4 u_view;

#if defined FRAGMENT_SHADER
layout(location = 0) out vec4 out_radiance;

vec3 level_value(int l, ivec2 X) { return texelFetch(u_levels, ivec2(X.x, u_level_y[l] + X.y), 0).rgb; }

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    vec4 xp = texelFetch(u_gbuffer_position, p, 0);
    if (xp.w == 0.0) { out_radiance = vec4(0.0); return; }
    vec3 np = texelFetch(u_gbuffer_normal, p, 0).xyz;
    vec3 rho = texelFetch(u_gbuffer_albedo, p, 0).rgb;
    float depth = -(u_view * vec4(xp.xyz, 1.0)).z;
    vec3 irradiance = level_value(0, p);
    for (int l = 1; l < LEVELS; ++l) {
        ivec2 size = u_level_size[l].xy;
        float footprint = exp2(float(l)) * u_pixel_k * depth;
        // nodes X0, X0 + 1 bracket p: at X 2^l, the last one clamped to the screen (node_pixel)
        ivec2 screen = textureSize(u_gbuffer_position, 0);
        ivec2 X0 = min(p >> l, size - 2);
        ivec2 P0 = node_pixel(l, X0, screen), P1 = node_pixel(l, X0 + 1, screen);
        vec2 f = clamp(vec2(p - P0) / vec2(max(P1 - P0, ivec2(1))), 0.0, 1.0);
        vec3 sum = vec3(0.0), plain = vec3(0.0);
        float wsum = 0.0, plain_wsum = 0.0;
        for (int k = 0; k < 4; ++k) {
            ivec2 o = ivec2(k & 1, k >> 1);
            ivec2 X = X0 + o;
            if (any(lessThan(X, ivec2(0))) || any(greaterThanEqual(X, size))) continue;
            ivec2 a = atlas_of(l, X);
            vec4 xq = texelFetch(u_receiver_position, a, 0);
            if (xq.w == 0.0) continue;
            vec2 bw = mix(1.0 - f, f, vec2(o));
            float wb = bw.x * bw.y + 1e-6;
            float w = wb * same_surface(xp.xyz, np, footprint, xq.xyz, texelFetch(u_receiver_normal, a, 0).xyz);
            vec3 value = level_value(l, X);
            sum += w * value;
            wsum += w;
            plain += wb * value;
            plain_wsum += wb;
        }
        if (wsum <= 0.0) {
            ivec2 Xc = X0 + ivec2(greaterThanEqual(f, vec2(0.5)));
            for (int k = 0; k < 9; ++k) {
                ivec2 X = Xc + ivec2(k % 3 - 1, k / 3 - 1);
                if (any(lessThan(X, ivec2(0))) || any(greaterThanEqual(X, size))) continue;
                ivec2 a = atlas_of(l, X);
                vec4 xq = texelFetch(u_receiver_position, a, 0);
                if (xq.w == 0.0) continue;
                float w = same_surface(xp.xyz, np, footprint, xq.xyz, texelFetch(u_receiver_normal, a, 0).xyz);
                sum += w * level_value(l, X);
                wsum += w;
            }
        }
        if (wsum > 0.0) irradiance += sum / wsum;
        else if (plain_wsum > 0.0) irradiance += plain / plain_wsum;
    }
    out_radiance = vec4(rho * INV_PI * irradiance, 1.0);
}
#endif
