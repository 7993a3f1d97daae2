// SSDO one-bounce indirect light (Ritschel, Grosch, Seidel 2009, Sec. 3.2), radiometric form:
//   L(x) = rho_x / pi * sum_{blocked i} L_s(y_i) A_i <n_x, w_i>+ <n_y, -w_i>+ / max(d_clamp, |y_i - x|)^2
// Sample i is the paper's s_i = x + r_max lambda_i w_i: a direction w_i uniform on the hemisphere
// of x's shading normal n_x and a step lambda_i uniform in [0, 1] (volume density
// 1 / (2 pi r_max |s - x|^2)). It is blocked when it lies behind the visible surface at the
// pixel it projects to; that surface point y_i (GBuffer) is then a sender patch whose outgoing
// radiance L_s is its direct radiance (direct pass). Its area A_i is the area the sample stands
// for, 1 / (N p(y_i)), with p(y) the density per unit sender area of a blocked sample landing
// behind y: the samples in the column behind y along the camera ray (unit direction u, from
// t_y to t_out, inside the ball of radius r_max around x and above x's tangent plane) over the
// sender's footprint, p(y) = |n_y . u| / t_y^2 * integral t^2 / (2 pi r_max |e + t u - x|^2) dt
// (3-point Gauss-Legendre; the column at least MIN_COLUMN_REL r_max long). The paper's
// A_s = pi r_max^2 / N is this area only for a plane through x seen head-on by uniform-volume
// samples; it over-weights senders near x and under-weights compact senders seen at grazing
// angles (see the manual).
// r_max is u_radius_m (radius_rel x scene radius), or (radius_rel = 0, the default)
// u_radius_rel x the mean view depth of the covered pixels, read from the last mip level of
// view_depth.glsl's output; d_clamp is u_clamp_rel x r_max, so the estimate does not depend on
// the scene's unit of length.
// Interleaved patterns: the pixels of each PATTERN x PATTERN block use different sample sets
// (one Cranley-Patterson offset per block cell applied to the frame's base set).
// Output: rgb = indirect radiance, a = view depth of x (0 = background) for the blur.
#include "fullscreen.glsl"
#include "common.glsl"
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_normal;
uniform sampler2D u_gbuffer_albedo;
uniform sampler2D u_direct_radiance;
uniform mat4 u_view_proj;
uniform int u_sample_count;      // N
uniform sampler2D u_view_depth;  // mipmapped (view depth, covered); see view_depth.glsl
uniform int u_view_depth_level;  // its last mip level (1 x 1)
uniform float u_radius_m;        // r_max in world units (radius_rel x scene radius); 0: from the view
uniform float u_radius_rel;      // r_max / mean view depth of the covered pixels (u_radius_m == 0)
uniform float u_clamp_rel;       // distance clamp d_clamp / r_max
uniform int u_pattern_size;      // M: M x M pixel blocks, M^2 sample sets
uniform uint u_rand;             // per-frame random value
uniform vec3 u_eye;              // camera position (re-centred world)

#if defined FRAGMENT_SHADER
layout(location = 0) out vec4 out_radiance;

void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec4 p = texelFetch(u_gbuffer_position, px, 0);
    if (p.w == 0.0) { out_radiance = vec4(0.0); return; }
    ivec2 size = textureSize(u_gbuffer_position, 0);
    vec3 x = p.xyz;
    vec3 nx = texelFetch(u_gbuffer_normal, px, 0).xyz;
    vec3 rho_x = texelFetch(u_gbuffer_albedo, px, 0).rgb;
    float depth_x = (u_view_proj * vec4(x, 1.0)).w;
    vec3 t, b;
    orthonormal_basis(nx, t, b);
    float r_max = u_radius_m;
    if (r_max == 0.0) {
        vec2 mean = texelFetch(u_view_depth, ivec2(0), u_view_depth_level).rg;
        r_max = u_radius_rel * mean.r / max(mean.g, 1e-30);
    }
    float d_clamp = u_clamp_rel * r_max;

    ivec2 cell = px % u_pattern_size;
    uint k = uint(cell.x + u_pattern_size * cell.y);
    uint hk = hash_u32(u_rand ^ hash_u32(k * 2654435761u + 0x68E31DA4u));
    vec3 offset = vec3(u32_to_unit(hk), u32_to_unit(hash_u32(hk ^ 0x1B56C4E9u)),
                       u32_to_unit(hash_u32(hk ^ 0x7F4A7C15u)));

    vec3 sum = vec3(0.0);
    for (int i = 0; i < u_sample_count; ++i) {
        // Base set of the frame (the same for every pixel), cos(theta) stratified over N.
        uint h = hash_u32(u_rand + 0x9E3779B9u * uint(i + 1));
        uint h2 = hash_u32(h ^ 0x85EBCA6Bu);
        uint h3 = hash_u32(h2 ^ 0xC2B2AE35u);
        float u1 = fract((float(i) + u32_to_unit(h)) / float(u_sample_count) + offset.x);
        float u2 = fract(u32_to_unit(h2) + offset.y);
        float u3 = fract(u32_to_unit(h3) + offset.z);
        // Uniform direction on the hemisphere (cos theta = u1).
        float cos_t = u1, sin_t = sqrt(max(0.0, 1.0 - u1 * u1)), phi = 2.0 * PI * u2;
        vec3 dir = t * (sin_t * cos(phi)) + b * (sin_t * sin(phi)) + nx * cos_t;
        vec3 s = x + dir * (r_max * u3);   // the paper's step lambda = u3, uniform in [0, 1]

        vec4 clip = u_view_proj * vec4(s, 1.0);
        if (clip.w <= 0.0) continue;
        vec2 ndc = clip.xy / clip.w;
        if (any(greaterThanEqual(abs(ndc), vec2(1.0)))) continue;   // off screen: nothing known
        ivec2 q = min(ivec2((ndc * 0.5 + 0.5) * vec2(size)), size - 1);
        vec4 yp = texelFetch(u_gbuffer_position, q, 0);
        if (yp.w == 0.0) continue;                                  // background: open direction
        vec3 y = yp.xyz;
        float depth_y = (u_view_proj * vec4(y, 1.0)).w;
        if (clip.w <= depth_y * (1.0 + DEPTH_BIAS_REL)) continue;   // in front of the surface: open
        vec3 ny = texelFetch(u_gbuffer_normal, q, 0).xyz;
        vec3 L = texelFetch(u_direct_radiance, q, 0).rgb;
        vec3 d = y - x;
        float dist = length(d);
        if (dist <= 0.0) continue;
        vec3 w = d / dist;
        float cos_r = dot(nx, w);
        // The GBuffer normal faces the camera: the direct radiance is that of this side.
        float cos_s = -dot(ny, w);
        if (cos_r <= 0.0 || cos_s <= 0.0) continue;
        float dc = max(d_clamp, dist);
        // the column behind y: the camera ray e + t u beyond t_y, inside the ball and the half-space
        vec3 ray = y - u_eye;
        float t_y = length(ray);
        vec3 u = ray / t_y;
        vec3 ex = u_eye - x;
        float bq = dot(u, ex);
        float root = sqrt(max(bq * bq - (dot(ex, ex) - r_max * r_max), 0.0));
        float t_in = max(-bq - root, t_y), t_out = -bq + root;
        float a_n = dot(nx, ex), c_n = dot(nx, u);
        if (c_n > 0.0) t_in = max(t_in, -a_n / c_n);
        else if (c_n < 0.0) t_out = min(t_out, -a_n / c_n);
        float len = max(t_out - t_in, 0.0);
        float mid = t_in + 0.5 * len;
        float density = 0.0;   // mean of t^2 / |e + t u - x|^2 over the column
        for (int g = -1; g <= 1; ++g) {
            float tg = mid + float(g) * 0.7745966692 * 0.5 * len;
            vec3 pg = u_eye + tg * u - x;
            density += (g == 0 ? 0.4444444444 : 0.2777777778) * tg * tg / max(dot(pg, pg), d_clamp * d_clamp);
        }
        float p_y = abs(dot(ny, u)) * density * max(len, MIN_COLUMN_REL * r_max) / (2.0 * PI * r_max * t_y * t_y);
        sum += L * (cos_r * cos_s / (dc * dc * p_y));
    }
    out_radiance = vec4(rho_x * INV_PI * sum / float(u_sample_count), depth_x);
}
#endif
