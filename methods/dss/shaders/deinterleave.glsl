// Builds the receivers of every level in the deinterleaved atlas layout: level pixel X stands
// for one pixel of its 2^l x 2^l block (the centre one, else the first covered one), storing
// its position (w = view depth > 0 where covered, 0 elsewhere) and normal.
#include "fullscreen.glsl"
#include "dss_common.glsl"
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_normal;
uniform mat4 u_view;

#if defined FRAGMENT_SHADER
layout(location = 0) out vec4 out_position;
layout(location = 1) out vec4 out_normal;
void main() {
    out_position = vec4(0.0);
    out_normal = vec4(0.0);
    int l;
    ivec2 X;
    if (!level_pixel_of_atlas(ivec2(gl_FragCoord.xy), l, X)) return;
    int block = 1 << l;
    ivec2 screen = textureSize(u_gbuffer_position, 0);
    ivec2 base = X * block;
    ivec2 chosen = min(base + ivec2(block / 2), screen - 1);
    vec4 p = texelFetch(u_gbuffer_position, chosen, 0);
    for (int k = 0; k < block * block && p.w == 0.0; ++k) {
        ivec2 q = base + ivec2(k % block, k / block);
        if (q.x >= screen.x || q.y >= screen.y) continue;
        p = texelFetch(u_gbuffer_position, q, 0);
        chosen = q;
    }
    if (p.w == 0.0) return;
    vec3 n = texelFetch(u_gbuffer_normal, chosen, 0).xyz;
    float depth = -(u_view * vec4(p.xyz, 1.0)).z;
    out_position = vec4(p.xyz, depth);
    out_normal = vec4(n, 0.0);
}
#endif
