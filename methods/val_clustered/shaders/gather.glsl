// Indirect lighting from all VPLs with clustered visibility (paper Sec. 4 and 6):
//   L(x) = rho_x / pi * sum_i Phi_i / pi * <n_x, w>+ <n_i, -w>+ / max(eps, d_i)^2 * V_C(i)(x)
// (ir_unshadowed's term, with VPL i's visibility replaced by that of its VAL C(i)).
// Interleaved sampling (Keller & Heidrich 2001): with blocks of B x B pixels, the pixel at
// block position r sums only the VPLs i = r (mod B^2), weighted by B^2, and the geometry-aware
// blur averages the B x B neighbourhood. B = 1: every pixel sums every VPL, no blur, and the
// albedo is applied here (u_apply_albedo); otherwise the blur pass applies it, and alpha holds the
// luminance of the same sum without visibility (additive like rgb: the blur's visibility test).
#include "fullscreen.glsl"
#include "val_records.glsl"
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_normal;
uniform sampler2D u_gbuffer_albedo;
uniform sampler2DArray u_visibility;
uniform int u_vpl_first;  // this draw scans VPLs [first, end): see bench.gl.context.LOOP_CHUNK
uniform int u_vpl_end;
uniform int u_interleave;
uniform bool u_apply_albedo;
uniform float u_eps;

#if defined FRAGMENT_SHADER
layout(location = 0) out vec4 out_radiance;
void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec4 p = texelFetch(u_gbuffer_position, px, 0);
    if (p.w == 0.0) { out_radiance = vec4(0.0); return; }
    vec3 x = p.xyz;
    vec3 nx = texelFetch(u_gbuffer_normal, px, 0).xyz;
    int stride = u_interleave * u_interleave;
    int r = (px.x % u_interleave) + u_interleave * (px.y % u_interleave);
    int start = u_vpl_first + ((r - u_vpl_first % stride) % stride + stride) % stride;
    vec3 sum = vec3(0.0);
    float unshadowed = 0.0;   // the luminance of the same sum without visibility (the blur's test)
    for (int k = start; k < u_vpl_end; k += stride) {
        vec3 transfer = vpl_transfer(vpls[k], x, nx, u_eps);
        if (transfer == vec3(0.0)) continue;
        float vis = texelFetch(u_visibility, ivec3(px, vpl_cluster[k]), 0).r;
        sum += transfer * vis;
        unshadowed += flux_luminance(transfer);
    }
    sum *= float(stride);
    if (u_apply_albedo) sum *= texelFetch(u_gbuffer_albedo, px, 0).rgb * (INV_PI * INV_PI);
    out_radiance = vec4(sum, u_apply_albedo ? 1.0 : unshadowed * float(stride));
}
#endif
