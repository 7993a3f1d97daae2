// Builds the receivers of every level in the deinterleaved atlas layout: level pixel X stands
// for one pixel of its 2^l x 2^l block, storing its position (w = view depth > 0 where
// covered, 0 elsewhere) and normal. The receivers nest: level l's receiver of X is the
// full-resolution pixel X 2^l, which is also the receiver of every finer level there, and
// compose.glsl places level l's samples at exactly those pixels (bilinear nodes X 2^l). So at
// a receiver, every level decides its shell from the same point: the levels partition the
// surfels there exactly (each surfel is counted once), and elsewhere the compose pass
// interpolates between such points. The last node of a row or column sits on the screen's last
// pixel (node_pixel), so no pixel is extrapolated. Where the node's pixel is uncovered, the
// first covered pixel of the 2^l x 2^l block from it (row by row) stands in, with its own
// position used everywhere.
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
    ivec2 base = node_pixel(l, X, screen);
    ivec2 chosen = base;
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
