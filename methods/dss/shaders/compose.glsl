// Upsample and sum: every full-resolution pixel takes level 0 as is and each coarser level
// bilinearly from the four nearest grid receivers (slot l) on its own surface, level pixel X
// sitting at full-resolution pixel X 2^l where its receiver is (deinterleave.glsl) (weights of the
// rejected ones dropped and the rest renormalised; if all four are rejected, the same-surface
// ones of the 3 x 3 around the nearest one), then applies its rho / pi. A pixel with no grid
// receiver of its surface there (a face one or two pixels wide: the side of a column, an edge)
// takes the level from the thin-face receivers (slot thin_slot(l)): its own block's if on its
// surface, else the same-surface ones of the 3 x 3 blocks around. Failing that (two thin surfaces
// in one block), the mean of the grid receivers of its orientation (normal test only) closer to
// it than half the level's inner shell radius, 2^(l-1) S pixel footprints, searched within
// u_orient_radius = S/2 level pixels of the nearest node: the level holds the unshadowed light of
// surfels at least 2^l S footprints away, which changes with the receiver's orientation at once
// but with its position only over the shell's radius. With none, the level adds nothing there:
// another orientation's irradiance is no estimate (taking it gave sponza's thin faces 3x theirs).
#include "fullscreen.glsl"
#include "dss_common.glsl"
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_normal;
uniform sampler2D u_gbuffer_albedo;
uniform sampler2D u_receiver_position;
uniform sampler2D u_receiver_normal;
uniform sampler2D u_levels;            // blurred irradiance, plain level layout
uniform mat4 u_view;
uniform int u_orient_radius;       // same-orientation search radius, level pixels

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
        ivec2 screen = textureSize(u_gbuffer_position, 0);
        vec2 f;
        ivec2 X0 = bracket_nodes(l, p, size, screen, f);
        vec3 sum = vec3(0.0);
        float wsum = 0.0;
        for (int k = 0; k < 4; ++k) {
            ivec2 o = ivec2(k & 1, k >> 1);
            ivec2 X = X0 + o;
            if (any(lessThan(X, ivec2(0))) || any(greaterThanEqual(X, size))) continue;
            ivec2 a = atlas_of(l, X);
            vec4 xq = texelFetch(u_receiver_position, a, 0);
            if (xq.w == 0.0) continue;
            vec2 bw = mix(1.0 - f, f, vec2(o));
            float w = (bw.x * bw.y + 1e-6)
                    * same_surface(xp.xyz, np, footprint, xq.xyz, texelFetch(u_receiver_normal, a, 0).xyz);
            sum += w * level_value(l, X);
            wsum += w;
        }
        ivec2 Xc = X0 + ivec2(greaterThanEqual(f, vec2(0.5)));
        if (wsum <= 0.0) {
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
        // no grid receiver of its surface (deinterleave.glsl made p's block a thin-face receiver):
        // the thin-face receivers of its surface, its own block's first, else the 3 x 3 around it
        int thin = thin_slot(l);
        ivec2 Xb = min(p >> l, size - 1);
        for (int k = 0; k < 10 && wsum <= 0.0; ++k) {
            ivec2 X = Xb + (k == 0 ? ivec2(0) : ivec2((k - 1) % 3 - 1, (k - 1) / 3 - 1));
            if (k == 5) continue;   // the block itself, done first
            if (any(lessThan(X, ivec2(0))) || any(greaterThanEqual(X, size))) continue;
            ivec2 a = atlas_of(thin, X);
            vec4 xq = texelFetch(u_receiver_position, a, 0);
            if (xq.w == 0.0) continue;
            float w = same_surface(xp.xyz, np, footprint, xq.xyz, texelFetch(u_receiver_normal, a, 0).xyz);
            if (k == 0 && w > 0.0) { sum = level_value(thin, X); wsum = 1.0; break; }
            sum += w * level_value(thin, X);
            wsum += w;
        }
        // no receiver of its surface: the mean of the receivers of its orientation within half the
        // inner shell radius (2^l S footprints / 2 = u_shell_pixels / 2 level footprints)
        if (wsum <= 0.0) {
            for (int dy = -u_orient_radius; dy <= u_orient_radius; ++dy) {
                for (int dx = -u_orient_radius; dx <= u_orient_radius; ++dx) {
                    ivec2 X = Xc + ivec2(dx, dy);
                    if (any(lessThan(X, ivec2(0))) || any(greaterThanEqual(X, size))) continue;
                    ivec2 a = atlas_of(l, X);
                    vec4 xq = texelFetch(u_receiver_position, a, 0);
                    if (xq.w == 0.0 || length(xq.xyz - xp.xyz) > 0.5 * u_shell_pixels * footprint) continue;
                    if (dot(np, texelFetch(u_receiver_normal, a, 0).xyz) < u_blur_normal_cos) continue;
                    sum += level_value(l, X);
                    wsum += 1.0;
                }
            }
        }
        if (wsum > 0.0) irradiance += sum / wsum;
    }
    out_radiance = vec4(rho * INV_PI * irradiance, 1.0);
}
#endif
