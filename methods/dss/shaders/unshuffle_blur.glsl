// Unshuffle + blur: every level pixel X of every slot (grid and thin-face receivers; written in
// the plain level layout, slot k from row u_level_y[k]) averages the splatted irradiance of its (2 u_blur_radius + 1)^2 neighbours on
// the same surface, read from the deinterleaved atlas. Neighbours come from different
// interleaved sub-buffers, so the average mixes the surfel subsets back together; the weights
// balance the classes (class_weight).
#include "fullscreen.glsl"
#include "dss_common.glsl"
uniform sampler2D u_receiver_position;
uniform sampler2D u_receiver_normal;
uniform sampler2D u_splat;             // deinterleaved splatted irradiance
uniform int u_blur_radius;

#if defined FRAGMENT_SHADER
layout(location = 0) out vec4 out_irradiance;

// 1 / (number of offsets in [-b, b] congruent to d mod INTERLEAVE): every interleaved class in
// the window gets the same total weight, so no M-periodic pattern survives the blur (for M = 2,
// b = 1 this is the tent 1/2, 1, 1/2).
float class_weight(int d) {
    int b = u_blur_radius;
    int r = ((d + b) % INTERLEAVE + INTERLEAVE) % INTERLEAVE;   // class of d, counted from -b
    int count = (2 * b - r) / INTERLEAVE + 1;
    return 1.0 / float(count);
}
void main() {
    out_irradiance = vec4(0.0);
    ivec2 a = ivec2(gl_FragCoord.xy);
    int slot = -1;
    for (int k = 0; k < SLOTS; ++k) {
        ivec4 s = u_level_size[k];
        if (a.y >= u_level_y[k] && a.y < u_level_y[k] + s.y && a.x < s.x) slot = k;
    }
    if (slot < 0) return;
    int l = slot_level(slot);
    ivec2 X = ivec2(a.x, a.y - u_level_y[slot]);
    ivec2 size = u_level_size[slot].xy;
    ivec2 ac = atlas_of(slot, X);
    vec4 xp = texelFetch(u_receiver_position, ac, 0);
    if (xp.w == 0.0) return;
    vec3 np = texelFetch(u_receiver_normal, ac, 0).xyz;
    float footprint = exp2(float(l)) * u_pixel_k * xp.w;
    vec3 sum = vec3(0.0);
    float wsum = 0.0;
    for (int dy = -u_blur_radius; dy <= u_blur_radius; ++dy) {
        for (int dx = -u_blur_radius; dx <= u_blur_radius; ++dx) {
            ivec2 Xn = X + ivec2(dx, dy);
            if (any(lessThan(Xn, ivec2(0))) || any(greaterThanEqual(Xn, size))) continue;
            ivec2 an = atlas_of(slot, Xn);
            vec4 xq = texelFetch(u_receiver_position, an, 0);
            if (xq.w == 0.0) continue;
            float w = same_surface(xp.xyz, np, footprint, xq.xyz, texelFetch(u_receiver_normal, an, 0).xyz)
                    * class_weight(dx) * class_weight(dy);
            if (w == 0.0) continue;
            sum += w * texelFetch(u_splat, an, 0).rgb;
            wsum += w;
        }
    }
    out_irradiance = vec4(sum / max(wsum, 1e-30), 0.0);
}
#endif
