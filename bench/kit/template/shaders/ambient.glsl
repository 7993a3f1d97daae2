// The one-bounce ambient term at each pixel: L(x) = rho_x / pi * flux / area, where flux is the
// total flux the lights' first bounce reflects (the 1 x 1 result of flux_sum.glsl) and area the
// scene's total surface area. Background pixels (GBuffer position.w = 0) get 0.
#include "fullscreen.glsl"
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_albedo;
uniform sampler2D u_flux_total;
uniform float u_inv_area_m2;

#if defined FRAGMENT_SHADER
layout(location = 0) out vec4 out_radiance;
void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    if (texelFetch(u_gbuffer_position, pixel, 0).w == 0.0) {
        out_radiance = vec4(0.0);
        return;
    }
    vec3 albedo = texelFetch(u_gbuffer_albedo, pixel, 0).rgb;
    vec3 flux = texelFetch(u_flux_total, ivec2(0, 0), 0).rgb;
    out_radiance = vec4(albedo * INV_PI * flux * u_inv_area_m2, 1.0);
}
#endif
