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
// row under a lit ceiling: manual rule (5)).
#include "common.glsl"
#include "near_field.glsl"
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
uniform uint u_rand;

#if defined VERTEX_SHADER
flat out int v_index;
void main() { v_index = gl_VertexID; }
#endif

#if defined GEOMETRY_SHADER
layout(points) in;
layout(triangle_strip, max_vertices = 4 * SLOTS) out;
flat in int v_index[];
flat out vec4 g_position_area;
flat out vec4 g_normal_radius;
flat out vec3 g_shading_normal;
flat out vec3 g_front;
flat out vec3 g_back;
flat out vec3 g_corner0;        // the sub-triangle's corners 0 and 1 minus its centre
flat out vec3 g_corner1;
flat out float g_exact_dist;    // below this centre distance the transfer is the exact one
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
    g_exact_dist = u_exact_reach * reach;
#else
    g_corner0 = vec3(0.0);
    g_corner1 = vec3(0.0);
    g_exact_dist = 0.0;
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
        ivec4 box = screen_box(c, outer);
        if (box.x > box.z || box.y > box.w) continue;
        ivec4 size = u_level_size[l];
        // receivers of level pixel X lie in [X 2^l, (X + 1) 2^l) or on the clamped last node
        ivec2 X0 = box.xy >> l, X1 = min((box.zw + (1 << l) - 1) >> l, size.xy - 1);
        uint h = hash_u32(sf.key ^ hash_u32(u_rand + uint(l) * 0x9E3779B9u));
        ivec2 cls = ivec2(int(h % uint(INTERLEAVE)), int((h / uint(INTERLEAVE)) % uint(INTERLEAVE)));
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
flat in float g_exact_dist;
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
    vec3 radiosity = dot(g_shading_normal, w) < 0.0 ? g_front : g_back;   // the side the receiver is on
    if (all(equal(radiosity, vec3(0.0)))) discard;
    vec3 nx = texelFetch(u_receiver_normal, a, 0).xyz;
    float weight = float(INTERLEAVE * INTERLEAVE);
    float transfer;
    // exact near the surfel where its shading side is its geometric side (always on flat-shaded
    // faces; a receiver beside a smooth-shaded edge may see a side's radiosity from behind its
    // plane, where the exact transfer would let the lit side's light through: point term there)
#if EXACT_CONTACT
    if (dist < g_exact_dist && (dot(g_shading_normal, w) < 0.0) == (cos_y < 0.0)) {
        // a receiver within tau of the emitter's plane gets nothing (the point term's cos_y = 0;
        // tau absorbs float32 noise so a surface never lights itself)
        float tau = max(1e-4 * sqrt(g_position_area.w), 1e-2 * u_eps);
        if (abs(dot(g_normal_radius.xyz, d)) <= tau) discard;
        transfer = triangle_form_factor(d + g_corner0, d + g_corner1, d - g_corner0 - g_corner1, nx, tau);
        if (!(transfer > 0.0)) discard;
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
