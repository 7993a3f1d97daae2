// Deep Screen Space: surfel records, the multi-resolution interleaved atlas layout, the shell
// rule that gives every (surfel, receiver) pair exactly one level, and the geometry test of
// the blur and the upsampling. LEVELS, SLOTS (2 LEVELS - 1) and INTERLEAVE are injected #defines.
#ifndef DSS_COMMON_GLSL
#define DSS_COMMON_GLSL

struct Surfel {
    vec4 position_area;     // xyz centre (re-centred world), w area (m^2)
    vec3 normal;            // unit geometric normal of its triangle: the geometric term's cosine
    uint key;               // stable hash of (triangle key, sub-triangle): picks the interleaved sub-buffer
    vec4 radiosity_front;   // rgb rho E on the side +shading_normal, w luminance
    vec4 radiosity_back;    // rgb rho E on the side -shading_normal, w luminance
    vec4 shading_normal;    // xyz unit shading normal at the centre: picks the side a receiver sees;
                            // w (with exact_reach > 0): the triangle's albedo, red
#if EXACT_CONTACT
    vec4 corner0;           // xyz: the sub-triangle's corner 0 minus the centre (corner 2 = -corner0 - corner1); w albedo, green
    vec4 corner1;           // xyz: corner 1 minus the centre (both only with exact_reach > 0: 112 bytes, else 80); w albedo, blue
#endif
};
layout(std430, binding = BINDING_DSS_SURFELS) buffer SurfelBlock { Surfel surfels[]; };

// Doubles as the DrawArraysIndirect command of the splat pass (count, instances, first, base).
layout(std430, binding = BINDING_DSS_COUNTER) buffer SurfelCounter {
    uint surfel_count;
    uint instance_count;
    uint first_vertex;
    uint base_instance;
    uint command_pad;
    uint max_luminance_bits;   // floatBitsToUint of the brightest surfel's luminance (>= 0)
};

float luminance(vec3 c) { return dot(c, vec3(0.2126, 0.7152, 0.0722)); }

// Level l has ceil((W - 1) / 2^l) + 1 x ceil((H - 1) / 2^l) + 1 pixels; pixel X stands for the
// receiver at full-resolution pixel node_pixel(l, X). It is stored deinterleaved: INTERLEAVE x INTERLEAVE sub-buffers of
// tile x tile pixels, sub-buffer (i, j) holding the level pixels X = INTERLEAVE * uv + (i, j).
// Slots are stacked vertically in one atlas, slot k from row u_level_y[k]: slot l < LEVELS holds
// level l's grid receivers, slot thin_slot(l) (l >= 1) level l's thin-face receivers (one per
// 2^l x 2^l block, a pixel of the block with no grid receiver of its surface near), same layout.
uniform ivec4 u_level_size[SLOTS];   // W_l, H_l, tile width, tile height
uniform int u_level_y[SLOTS];
uniform float u_pixel_k;              // full-resolution pixel size at unit view depth (m / m)
uniform float u_shell_pixels;         // S: level 0 takes receivers closer than 2 S pixel footprints

int slot_level(int k) { return k < LEVELS ? k : k - LEVELS + 1; }
int thin_slot(int l) { return LEVELS - 1 + l; }

// Full-resolution pixel of level l's node X (its receiver's pixel, where compose places it):
// X 2^l, the last node of a row or column clamped to the screen's last pixel.
ivec2 node_pixel(int l, ivec2 X, ivec2 screen) { return min(X << l, screen - 1); }

// The grid nodes X0, X0 + 1 that bracket full-resolution pixel p at level l (nodes at X 2^l,
// the last one clamped to the screen) and p's bilinear weights f between them.
ivec2 bracket_nodes(int l, ivec2 p, ivec2 size, ivec2 screen, out vec2 f) {
    ivec2 X0 = min(p >> l, size - 2);
    ivec2 P0 = node_pixel(l, X0, screen), P1 = node_pixel(l, X0 + 1, screen);
    f = clamp(vec2(p - P0) / vec2(max(P1 - P0, ivec2(1))), 0.0, 1.0);
    return X0;
}

ivec2 atlas_of(int k, ivec2 X) {
    ivec4 s = u_level_size[k];
    ivec2 cls = X % INTERLEAVE;
    ivec2 uv = X / INTERLEAVE;
    return ivec2(cls.x * s.z + uv.x, u_level_y[k] + cls.y * s.w + uv.y);
}

// Inverse of atlas_of for a pixel of the deinterleaved atlas (slot k); false outside every slot.
bool level_pixel_of_atlas(ivec2 a, out int k, out ivec2 X) {
    for (k = 0; k < SLOTS; ++k) {
        ivec4 s = u_level_size[k];
        ivec2 local = ivec2(a.x, a.y - u_level_y[k]);
        if (local.y < 0 || local.y >= INTERLEAVE * s.w) continue;
        ivec2 cls = local / s.zw;
        if (cls.x >= INTERLEAVE) return false;
        X = (local % s.zw) * INTERLEAVE + cls;
        return X.x < s.x && X.y < s.y;
    }
    return false;
}

// The level a receiver at view depth `depth` gets a surfel at distance `dist` from: level 0
// below 2 S pixel footprints, level l in [2^l, 2^(l+1)) S footprints, the last level beyond.
// Level l samples the receivers every 2^l pixels, i.e. about 1/S of the distance: the shells
// of Deep Screen Space's splatting (fine near the surfel, coarse far from it).
int shell_level(float dist, float depth) {
    float t = dist / (u_shell_pixels * u_pixel_k * depth);
    if (t < 2.0) return 0;
    return min(LEVELS - 1, int(floor(log2(t))));
}

uniform float u_blur_normal_cos;    // neighbours whose normals differ more are rejected
uniform float u_blur_plane_pixels;  // max distance to the tangent plane, in pixel footprints

// 1 when receiver q may share p's smooth indirect irradiance (same surface), else 0.
float same_surface(vec3 xp, vec3 np, float footprint, vec3 xq, vec3 nq) {
    if (dot(np, nq) < u_blur_normal_cos) return 0.0;
    return abs(dot(np, xq - xp)) <= u_blur_plane_pixels * footprint ? 1.0 : 0.0;
}

#endif
