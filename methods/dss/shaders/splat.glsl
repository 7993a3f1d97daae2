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
flat in int g_level;
layout(location = 0) out vec4 out_irradiance;
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
    float cos_x = dot(texelFetch(u_receiver_normal, a, 0).xyz, w);
    if (cos_x <= 0.0) discard;
    float d2 = near_field_d2(dist, g_position_area.w, u_eps);
    float weight = float(INTERLEAVE * INTERLEAVE);
    out_irradiance = vec4(radiosity * (INV_PI * cos_x * abs(cos_y) * g_position_area.w / d2 * weight), 0.0);
}
#endif
