// Gather: every pixel sums every VPL's Lambertian emission (no visibility unless VPL_SHADOWS):
//   L(x) = rho_x / pi * sum_k Phi_k / pi * <n_x, w>+ <n_k, -w>+ / max(eps, |y_k - x|)^2
// VPL_SHADOWS (ir_shadowed) multiplies each term by vpl_visibility(), defined by the file
// that includes this one; the sum is otherwise the same code, term for term.
#include "fullscreen.glsl"
#include "common.glsl"
#include "vpl_records.glsl"
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_normal;
uniform sampler2D u_gbuffer_albedo;
uniform sampler2D u_gbuffer_geo_normal;
uniform int u_vpl_first;  // this draw sums VPLs [first, end): see bench.gl.context.LOOP_CHUNK
uniform int u_vpl_end;
uniform float u_eps;  // distance clamp d = max(eps, |x - y|)

#if defined FRAGMENT_SHADER
layout(location = 0) out vec4 out_radiance;
void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec4 p = texelFetch(u_gbuffer_position, px, 0);
    if (p.w == 0.0) { out_radiance = vec4(0.0); return; }
    vec3 x = p.xyz;
    vec3 nx = texelFetch(u_gbuffer_normal, px, 0).xyz;
    vec3 ng = texelFetch(u_gbuffer_geo_normal, px, 0).xyz;
    vec3 rho_x = texelFetch(u_gbuffer_albedo, px, 0).rgb;
    vec3 sum = vec3(0.0);
    for (int k = u_vpl_first; k < u_vpl_end; ++k) {
        Vpl v = vpls[k];
        vec3 transfer = vpl_transfer(v, x, nx, u_eps);
        if (transfer == vec3(0.0)) continue;
#if VPL_SHADOWS
        if (vpl_visibility(k, v, x, ng) == 0.0) continue;
#endif
        sum += transfer;
    }
    out_radiance = vec4(rho_x * (INV_PI * INV_PI) * sum, 1.0);
}
#endif
