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
// Thin-face slots (rule (4) of the manual): level l's thin-face receiver of X is the first pixel
// (row by row) of X's 2^l x 2^l block that has no grid receiver of its own surface among the
// nodes compose would take at level l (the four bracketing nodes, the 3 x 3 around the nearest),
// e.g. a face one or two pixels wide; none where every pixel of the block has one.

#include "fullscreen.glsl"
#include "dss_common.glsl"
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_normal;
uniform mat4 u_view;

#if defined FRAGMENT_SHADER
layout(location = 0) out vec4 out_position;
layout(location = 1) out vec4 out_normal;

// Level l's grid receiver of X: node_pixel(l, X), or the first covered pixel of its block.
bool grid_receiver(int l, ivec2 X, ivec2 screen, out ivec2 chosen) {
    int block = 1 << l;
    ivec2 base = node_pixel(l, X, screen);
    chosen = base;
    vec4 p = texelFetch(u_gbuffer_position, chosen, 0);
    for (int k = 0; k < block * block && p.w == 0.0; ++k) {
        ivec2 q = base + ivec2(k % block, k / block);
        if (q.x >= screen.x || q.y >= screen.y) continue;
        p = texelFetch(u_gbuffer_position, q, 0);
        chosen = q;
    }
    return p.w != 0.0;
}

bool grid_node_on_surface(int l, ivec2 X, ivec2 size, ivec2 screen, vec3 xp, vec3 np, float footprint) {
    if (any(lessThan(X, ivec2(0))) || any(greaterThanEqual(X, size))) return false;
    ivec2 r;
    if (!grid_receiver(l, X, screen, r)) return false;
    return same_surface(xp, np, footprint, texelFetch(u_gbuffer_position, r, 0).xyz,
                        texelFetch(u_gbuffer_normal, r, 0).xyz) > 0.0;
}

// true when compose finds no grid receiver of q's surface at level l
bool thin_at(int l, ivec2 q, ivec2 screen) {
    vec4 xq = texelFetch(u_gbuffer_position, q, 0);
    if (xq.w == 0.0) return false;
    vec3 nq = texelFetch(u_gbuffer_normal, q, 0).xyz;
    float footprint = exp2(float(l)) * u_pixel_k * -(u_view * vec4(xq.xyz, 1.0)).z;
    ivec2 size = u_level_size[l].xy;
    vec2 f;
    ivec2 X0 = bracket_nodes(l, q, size, screen, f);
    for (int k = 0; k < 4; ++k)
        if (grid_node_on_surface(l, X0 + ivec2(k & 1, k >> 1), size, screen, xq.xyz, nq, footprint)) return false;
    ivec2 Xc = X0 + ivec2(greaterThanEqual(f, vec2(0.5)));
    for (int k = 0; k < 9; ++k)
        if (grid_node_on_surface(l, Xc + ivec2(k % 3 - 1, k / 3 - 1), size, screen, xq.xyz, nq, footprint)) return false;
    return true;
}

void main() {
    out_position = vec4(0.0);
    out_normal = vec4(0.0);
    gl_FragDepth = 0.0;   // receiver mask (method.py): 1 where this slot pixel has a receiver
    int slot;
    ivec2 X;
    if (!level_pixel_of_atlas(ivec2(gl_FragCoord.xy), slot, X)) return;
    int l = slot_level(slot);
    ivec2 screen = textureSize(u_gbuffer_position, 0);
    ivec2 chosen;
    if (slot < LEVELS) {
        if (!grid_receiver(l, X, screen, chosen)) return;
    } else {
        int block = 1 << l;
        bool found = false;
        for (int k = 0; k < block * block && !found; ++k) {
            chosen = (X << l) + ivec2(k % block, k / block);
            if (chosen.x >= screen.x || chosen.y >= screen.y) continue;
            found = thin_at(l, chosen, screen);
        }
        if (!found) return;
    }
    vec4 p = texelFetch(u_gbuffer_position, chosen, 0);
    vec3 n = texelFetch(u_gbuffer_normal, chosen, 0).xyz;
    float depth = -(u_view * vec4(p.xyz, 1.0)).z;
    out_position = vec4(p.xyz, depth);
    out_normal = vec4(n, 0.0);
    gl_FragDepth = 1.0;
}
#endif
