// Gather pass: every pixel sums every VPL (eq. 4 of the FLC paper), no indirect visibility.
// EMISSION_FLC: VPL radiance rho E 3/(2 pi) <n, w>+ (eq. 6); otherwise Lambert rho E / pi.
#include "fullscreen.glsl"
#include "common.glsl"
#include "vpl_triangles.glsl"
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_normal;
uniform sampler2D u_gbuffer_albedo;
uniform int u_vpl_first;  // this draw sums VPLs [first, end): see bench.gl.context.LOOP_CHUNK
uniform int u_vpl_end;
uniform float u_eps;       // distance clamp d = max(eps, |x - y|)
uniform float u_weight;    // 1 / jitter frames

#if defined FRAGMENT_SHADER
layout(location = 0) out vec4 out_radiance;
void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec4 p = texelFetch(u_gbuffer_position, px, 0);
    if (p.w == 0.0) { out_radiance = vec4(0.0); return; }
    vec3 x = p.xyz;
    vec3 nx = texelFetch(u_gbuffer_normal, px, 0).xyz;
    vec3 rho_x = texelFetch(u_gbuffer_albedo, px, 0).rgb;
    vec3 sum = vec3(0.0);
    for (int i = u_vpl_first; i < u_vpl_end; ++i) {
        Vpl v = vpls[i];
        vec3 d = v.position_area.xyz - x;          // x -> y
        float dist = length(d);
        if (dist <= 0.0) continue;
        vec3 w = d / dist;
        float cos_x = dot(nx, w);
        if (cos_x <= 0.0) continue;
        // the side of the shading normal x is on picks the radiosity (Mitsuba's twosided
        // diffuse); the geometric term's cosine is against the geometric normal
        vec3 radiosity = dot(v.shading_normal.xyz, w) < 0.0 ? v.radiosity_front.rgb : v.radiosity_back.rgb;
        float c = abs(dot(v.normal.xyz, w));
        float dc = max(u_eps, dist);
#if EMISSION_FLC
        vec3 radiance = radiosity * (1.5 * INV_PI) * c;   // rho E 3/(2 pi) <n, w>+
#else
        vec3 radiance = radiosity * INV_PI;               // rho E / pi
#endif
        sum += radiance * (cos_x * c / (dc * dc)) * v.position_area.w;
    }
    out_radiance = vec4(rho_x * INV_PI * sum * u_weight, 1.0);
}
#endif
