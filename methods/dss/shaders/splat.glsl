// Splatting (Deep Screen Space, Sec. 4): every lit surfel is drawn as one screen-aligned quad
// per level (and one more over the level's thin-face receivers, l >= 1) into one interleaved
// sub-buffer of that level (picked by hashing its key with the
// frame's random value, weight INTERLEAVE^2 so the expectation is the full sum). Each
// receiver takes the surfel at exactly one level (shell_level), and only within the cut
// radius r where the surfel's contribution per unit area falls under the threshold. The
// fragment adds the unshadowed surfel -> receiver irradiance
//     E = B/pi <n_x, w>+ |<n_y, w>| A / d2      (Lambertian emission, as manylights)
// with B the radiosity of the side of the surfel's shading normal the receiver is on and n_y
// its geometric normal (Mitsuba's twosided diffuse with shading normals, as manylights).
// (the receiver's rho/pi is applied after upsampling, at full resolution). d2 is the near field
// of a surfel of area A at distance d (near_field.glsl: max(eps, d)^2, d^2 + A/pi, ...).
// Within u_exact_reach times the surfel's reach (its farthest corner from the centre) the
// point term gives way to the exact transfer from its sub-triangle of uniform radiosity B:
//     E = B F,  F = 1/(2 pi) |sum_i angle(q_i, q_i+1) <n_x, q_i x q_i+1> / |q_i x q_i+1||
// Lambert's contour integral of the form factor from the receiver to the part of the
// sub-triangle above its tangent plane (q_i: the clipped polygon's corners relative to x). The
// point term's cosine at the emitter, taken at the centre, vanishes for a receiver in (or near)
// the emitter's plane, where most of the light at a right-angle contact comes from (a wall's
// row under a lit ceiling: manual rule (5)). That near field is drawn by a second pass (NEAR_PASS)
// into every interleaved sub-buffer with weight 1 (for a surfel whose near-field sphere spans at
// least NEAR_SPLIT_PIXELS pixels; a smaller one keeps the point term in the hashed pass), and its
// radiosity leans towards rho E at the receiver's contact (the sub-triangle's closest point):
// B' = mix(B, B_contact, s^2 / (s^2 + h^2)), s = u_contact_scale x the reach, h the distance to it.
#include "common.glsl"
#include "near_field.glsl"
#if EXACT_CONTACT
#include "direct_lighting.glsl"
#endif
#include "dss_common.glsl"
uniform uint u_capacity;
uniform mat4 u_view;
uniform mat4 u_proj;
uniform float u_near;
uniform vec2 u_screen;          // full-resolution width, height
uniform vec2 u_atlas;           // atlas width, height
uniform float u_scene_radius;   // R
uniform float u_radius_max;     // no receiver is farther than the scene's diameter
uniform float u_threshold;      // relative contribution threshold (0: no cut)
uniform float u_eps;            // distance clamp
uniform float u_exact_reach;    // exact sub-triangle transfer within this many reaches of a surfel (0: never)
uniform float u_contact_scale;  // s / reach: the contact radiosity's share of the exact transfer is s^2 / (s^2 + h^2)
uniform uint u_rand;

#if defined VERTEX_SHADER
flat out int v_index;
void main() { v_index = gl_VertexID; }
#endif

#if defined GEOMETRY_SHADER
#if NEAR_PASS
// the near field (within the exact reach) of every surfel in every interleaved sub-buffer, weight 1:
// invocation i draws class (i mod M, i / M)
layout(points, invocations = INTERLEAVE * INTERLEAVE) in;
#else
layout(points) in;
#endif
layout(triangle_strip, max_vertices = 4 * SLOTS) out;
flat in int v_index[];
flat out vec4 g_position_area;
flat out vec4 g_normal_radius;
flat out vec3 g_shading_normal;
flat out vec3 g_front;
flat out vec3 g_back;
flat out vec3 g_corner0;        // the sub-triangle's corners 0 and 1 minus its centre
flat out vec3 g_corner1;
flat out vec2 g_exact_dist;     // x: below this centre distance the near field (exact transfer), y: the reach
flat out vec3 g_rho;            // the emitter's albedo (its contact radiosity is rho E at the contact)
flat out int g_near_split;      // its near field is drawn by the near pass
flat out int g_level;

// Full-resolution pixel bounds (inclusive) of the sphere (view-space centre c, radius rho)
// clipped to the screen; x > z when it covers no pixel.
ivec4 screen_box(vec3 c, float rho) {
    if (-c.z - rho <= u_near) return ivec4(0, 0, ivec2(u_screen) - 1);
    vec2 lo = vec2(3.0e38), hi = vec2(-3.0e38);
    for (int k = 0; k < 8; ++k) {
        vec3 corner = c + rho * vec3((k & 1) != 0 ? 1.0 : -1.0, (k & 2) != 0 ? 1.0 : -1.0, (k & 4) != 0 ? 1.0 : -1.0);
        vec4 clip = u_proj * vec4(corner, 1.0);
        vec2 px = (clip.xy / clip.w * 0.5 + 0.5) * u_screen;
        lo = min(lo, px);
        hi = max(hi, px);
    }
    ivec2 a = ivec2(max(floor(lo) - 1.0, vec2(0.0)));
    ivec2 b = ivec2(min(floor(hi) + 1.0, u_screen - 1.0));
    return ivec4(a, b);
}

#if NEAR_PASS
// Tight full-resolution pixel bounds of a sphere wholly in front of the camera (view-space centre
// c, radius rho, -c.z - rho > near): per screen axis the two tangent directions at the centre's
// angle +- asin(rho / |c|) in that axis' plane; else screen_box.
ivec4 sphere_box(vec3 c, float rho) {
    float depth = -c.z;
    if (depth - rho <= u_near) return screen_box(c, rho);
    vec2 lo, hi;
    for (int k = 0; k < 2; ++k) {
        float x = c[k];
        float theta = atan(x, depth), alpha = asin(min(rho / sqrt(x * x + depth * depth), 1.0));
        // ndc = P[k][k] x / depth - P[2][k] (P[2][k] 0 on symmetric frusta)
        float t0 = tan(theta - alpha), t1 = tan(theta + alpha);
        lo[k] = (u_proj[k][k] * t0 - u_proj[2][k]) * 0.5 + 0.5;
        hi[k] = (u_proj[k][k] * t1 - u_proj[2][k]) * 0.5 + 0.5;
    }
    lo *= u_screen;
    hi *= u_screen;
    ivec2 a = ivec2(max(floor(lo) - 1.0, vec2(0.0)));
    ivec2 b = ivec2(min(floor(hi) + 1.0, u_screen - 1.0));
    return ivec4(a, b);
}
#endif

void emit_corner(vec2 atlas_px) {
    gl_Position = vec4(atlas_px / u_atlas * 2.0 - 1.0, 0.0, 1.0);
    EmitVertex();
}

void main() {
    int s = v_index[0];
    if (s < 0 || uint(s) >= u_capacity) return;
    Surfel sf = surfels[s];
    float lum = max(sf.radiosity_front.w, sf.radiosity_back.w);
    if (!(lum > 0.0)) return;
    float lum_max = uintBitsToFloat(max_luminance_bits);
    float r = u_radius_max;
    if (u_threshold > 0.0) r = min(r, u_scene_radius * sqrt(lum / (u_threshold * lum_max)));
    vec3 c = (u_view * vec4(sf.position_area.xyz, 1.0)).xyz;
    float depth = -c.z;
    g_position_area = sf.position_area;
    g_normal_radius = vec4(sf.normal, r);
    g_shading_normal = sf.shading_normal.xyz;
    g_front = sf.radiosity_front.rgb;
    g_back = sf.radiosity_back.rgb;
#if EXACT_CONTACT
    g_corner0 = sf.corner0.xyz;
    g_corner1 = sf.corner1.xyz;
    float reach = sqrt(max(max(dot(g_corner0, g_corner0), dot(g_corner1, g_corner1)),
                           dot(g_corner0 + g_corner1, g_corner0 + g_corner1)));
    g_exact_dist = vec2(u_exact_reach * reach, reach);
    g_rho = vec3(sf.shading_normal.w, sf.corner0.w, sf.corner1.w);
#else
    g_corner0 = vec3(0.0);
    g_corner1 = vec3(0.0);
    g_exact_dist = vec2(0.0);
    g_rho = vec3(0.0);
#endif
    // the near field goes to every sub-buffer (near pass, weight 1) when its sphere spans at least
    // NEAR_SPLIT_PIXELS pixels on the screen (or reaches the near plane), else the point term in
    // the surfel's hashed sub-buffer as the far field (weight M^2): a near field of a few pixels is
    // a few pixels' contact light, and llvmpipe pays per primitive (M^2 quads per level)
    g_near_split = int(g_exact_dist.x > 0.0 && (depth - g_exact_dist.x <= u_near ||
                                            g_exact_dist.x >= NEAR_SPLIT_PIXELS * u_pixel_k * depth));
#if NEAR_PASS
    if (g_near_split == 0) return;
    r = min(r, g_exact_dist.x);   // the near pass draws the near field's sphere only
    // none (or wholly in front of the near plane, where no receiver is: screen_box would give
    // the whole screen for a sphere behind the camera)
    if (!(r > 0.0) || depth + r <= u_near) return;
#endif
    for (int l = 0; l < LEVELS; ++l) {
        float b = exp2(float(l)) * u_shell_pixels * u_pixel_k;   // inner shell edge / receiver depth
        if (l > 0) {
            // a receiver at level l has d >= b depth_x >= b (depth - d)
            float inner = max(depth, 0.0) * b / (1.0 + b) * (1.0 - 1e-3);
            if (r <= inner) break;
        }
        float outer = r;
        if (l < LEVELS - 1) {
            // ... and d < 2 b depth_x <= 2 b (depth + d)
            float a = 2.0 * b;
            if (a < 1.0) {
                if (depth <= 0.0) continue;
                outer = min(r, a * depth / (1.0 - a) * (1.0 + 1e-3));
            }
        }
#if NEAR_PASS
        ivec4 box = sphere_box(c, outer);
#else
        ivec4 box = screen_box(c, outer);
#endif
        if (box.x > box.z || box.y > box.w) continue;
        ivec4 size = u_level_size[l];
        // receivers of level pixel X lie in [X 2^l, (X + 1) 2^l) or on the clamped last node
        ivec2 X0 = box.xy >> l, X1 = min((box.zw + (1 << l) - 1) >> l, size.xy - 1);
#if NEAR_PASS
        ivec2 cls = ivec2(gl_InvocationID % INTERLEAVE, gl_InvocationID / INTERLEAVE);
#else
        uint h = hash_u32(sf.key ^ hash_u32(u_rand + uint(l) * 0x9E3779B9u));
        ivec2 cls = ivec2(int(h % uint(INTERLEAVE)), int((h / uint(INTERLEAVE)) % uint(INTERLEAVE)));
#endif
        if (X1.x < cls.x || X1.y < cls.y) continue;
        ivec2 u0 = (max(X0 - cls, ivec2(0)) + (INTERLEAVE - 1)) / INTERLEAVE;
        ivec2 u1 = min((X1 - cls) / INTERLEAVE, size.zw - 1);
        if (u0.x > u1.x || u0.y > u1.y) continue;
        g_level = l;
        // the level's grid receivers, then (l >= 1) its thin-face receivers: same layout and box
        for (int j = 0; j < (l > 0 ? 2 : 1); ++j) {
            int k = j == 0 ? l : thin_slot(l);
            vec2 origin = vec2(cls * size.zw + ivec2(0, u_level_y[k]));
            vec2 lo = origin + vec2(u0), hi = origin + vec2(u1 + 1);
            emit_corner(vec2(lo.x, lo.y));
            emit_corner(vec2(hi.x, lo.y));
            emit_corner(vec2(lo.x, hi.y));
            emit_corner(vec2(hi.x, hi.y));
            EndPrimitive();
        }
    }
}
#endif

#if defined FRAGMENT_SHADER
layout(early_fragment_tests) in;   // the receiver mask's depth test runs before the shader
uniform sampler2D u_receiver_position;   // deinterleaved atlas (deinterleave.glsl)
uniform sampler2D u_receiver_normal;
flat in vec4 g_position_area;
flat in vec4 g_normal_radius;
flat in vec3 g_shading_normal;
flat in vec3 g_front;
flat in vec3 g_back;
flat in vec3 g_corner0;
flat in vec3 g_corner1;
flat in vec2 g_exact_dist;
flat in vec3 g_rho;
flat in int g_near_split;
flat in int g_level;
layout(location = 0) out vec4 out_irradiance;

// Form factor from a receiver (unit normal nx) to the triangle q0 q1 q2 (corners relative to the
// receiver): Lambert's contour integral over the triangle clipped to the receiver's tangent plane
// lifted by tau (at most four corners). The angle by atan (llvmpipe's acos is off by ~1e-4 rad).
float triangle_form_factor(vec3 q0, vec3 q1, vec3 q2, vec3 nx, float tau) {
    vec3 q[3] = vec3[3](q0, q1, q2);
    vec3 poly[4];
    int m = 0;
    for (int i = 0; i < 3; ++i) {
        vec3 a = q[i], b = q[(i + 1) % 3];
        float ha = dot(nx, a) - tau, hb = dot(nx, b) - tau;
        if (ha >= 0.0) poly[m++] = a;
        if ((ha >= 0.0) != (hb >= 0.0)) poly[m++] = a + (b - a) * (ha / (ha - hb));
    }
    if (m < 3) return 0.0;
    float sum = 0.0;
    for (int i = 0; i < m; ++i) {
        vec3 a = normalize(poly[i]), b = normalize(poly[(i + 1) % m]);
        vec3 c = cross(a, b);
        float s = length(c);
        if (s > 0.0) sum += atan(s, dot(a, b)) * dot(nx, c) / s;
    }
    return min(abs(sum) * (0.5 * INV_PI), 1.0);
}

// Closest point of the triangle a b c to p (Ericson, Real-Time Collision Detection, 5.1.5).
vec3 closest_on_triangle(vec3 p, vec3 a, vec3 b, vec3 c) {
    vec3 ab = b - a, ac = c - a, ap = p - a;
    float d1 = dot(ab, ap), d2 = dot(ac, ap);
    if (d1 <= 0.0 && d2 <= 0.0) return a;
    vec3 bp = p - b;
    float d3 = dot(ab, bp), d4 = dot(ac, bp);
    if (d3 >= 0.0 && d4 <= d3) return b;
    float vc = d1 * d4 - d3 * d2;
    if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) return a + ab * (d1 / (d1 - d3));
    vec3 cp = p - c;
    float d5 = dot(ab, cp), d6 = dot(ac, cp);
    if (d6 >= 0.0 && d5 <= d6) return c;
    float vb = d5 * d2 - d1 * d6;
    if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) return a + ac * (d2 / (d2 - d6));
    float va = d3 * d6 - d5 * d4;
    if (va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0) return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    float inv = 1.0 / (va + vb + vc);
    return a + ab * (vb * inv) + ac * (vc * inv);
}

void main() {
    ivec2 a = ivec2(gl_FragCoord.xy);
    vec4 xp = texelFetch(u_receiver_position, a, 0);   // w: view depth, 0 if no receiver
    if (xp.w == 0.0) discard;
    vec3 d = g_position_area.xyz - xp.xyz;   // x -> y
    float dist = length(d);
    if (!(dist > 0.0) || dist >= g_normal_radius.w) discard;
    if (shell_level(dist, xp.w) != g_level) discard;
    vec3 w = d / dist;
    float cos_y = dot(g_normal_radius.xyz, w);
    bool front = dot(g_shading_normal, w) < 0.0;   // the receiver is on the side of the shading normal
    vec3 radiosity = front ? g_front : g_back;   // the side the receiver is on
    if (all(equal(radiosity, vec3(0.0)))) discard;
    vec3 nx = texelFetch(u_receiver_normal, a, 0).xyz;
    float transfer;
#if EXACT_CONTACT
    // the near field (dist < reach k) in every sub-buffer with weight 1 (NEAR_PASS), the rest in
    // the surfel's hashed sub-buffer with weight M^2
    bool near = dist < g_exact_dist.x;
#if NEAR_PASS
    if (!near) discard;
    float weight = 1.0;
#else
    if (near && g_near_split != 0) discard;
    float weight = float(INTERLEAVE * INTERLEAVE);
#endif
#else
    float weight = float(INTERLEAVE * INTERLEAVE);
#endif
    // exact near the surfel where its shading side is its geometric side (always on flat-shaded
    // faces; a receiver beside a smooth-shaded edge may see a side's radiosity from behind its
    // plane, where the exact transfer would let the lit side's light through: point term there)
#if NEAR_PASS
    if ((dot(g_shading_normal, w) < 0.0) == (cos_y < 0.0)) {
        // a receiver within tau of the emitter's plane gets nothing (the point term's cos_y = 0;
        // tau absorbs float32 noise so a surface never lights itself)
        float tau = max(1e-4 * sqrt(g_position_area.w), 1e-2 * u_eps);
        if (abs(dot(g_normal_radius.xyz, d)) <= tau) discard;
        transfer = triangle_form_factor(d + g_corner0, d + g_corner1, d - g_corner0 - g_corner1, nx, tau);
        if (!(transfer > 0.0)) discard;
        if (u_contact_scale > 0.0) {
            // the part of the transfer from near the contact (the sub-triangle's point c closest to
            // the receiver, at distance h) takes the radiosity there, rho E(c) (shadow maps), the
            // rest the surfel's mean: a receiver at h from a plane gets the share s^2 / (s^2 + h^2) of
            // its form factor from within s of its foot, s = contact_scale x the reach
            vec3 y = g_position_area.xyz;
            vec3 c = closest_on_triangle(xp.xyz, y + g_corner0, y + g_corner1, y - g_corner0 - g_corner1);
            vec3 hv = c - xp.xyz;
            float s2 = u_contact_scale * g_exact_dist.y;
            s2 *= s2;
            float share = s2 / (s2 + dot(hv, hv));
            vec3 ns = front ? g_shading_normal : -g_shading_normal;
            // the direct light a quarter of the way from c to the centre: inside the sub-triangle,
            // off the edge where the adjacent surface's own shadow-map depth meets it
            vec3 contact = g_rho * direct_irradiance(mix(c, y, CONTACT_INSET), ns, g_normal_radius.xyz, true);
            radiosity = mix(radiosity, contact, share);
        }
        transfer *= weight;
    } else
#endif
    {
        float cos_x = dot(nx, w);
        if (cos_x <= 0.0) discard;
        float d2 = near_field_d2(dist, g_position_area.w, u_eps);
        transfer = INV_PI * cos_x * abs(cos_y) * g_position_area.w / d2 * weight;   // (the point term's float order)
    }
    out_irradiance = vec4(radiosity * transfer, 0.0);
}
#endif
