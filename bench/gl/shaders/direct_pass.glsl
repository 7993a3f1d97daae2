// Direct lighting of the GBuffer: L = albedo / pi * E (shadowed or not).
#include "fullscreen.glsl"
#include "direct_lighting.glsl"
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_normal;
uniform sampler2D u_gbuffer_albedo;
uniform sampler2D u_gbuffer_geo_normal;
uniform bool u_shadows;

#if defined FRAGMENT_SHADER
layout(location = 0) out vec4 out_radiance;
void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec4 p = texelFetch(u_gbuffer_position, px, 0);
    if (p.w == 0.0) { out_radiance = vec4(0.0); return; }
    vec3 n = texelFetch(u_gbuffer_normal, px, 0).xyz;
    vec3 ng = texelFetch(u_gbuffer_geo_normal, px, 0).xyz;
    vec3 albedo = texelFetch(u_gbuffer_albedo, px, 0).rgb;
    out_radiance = vec4(albedo * INV_PI * direct_irradiance(p.xyz, n, ng, u_shadows), 1.0);
}
#endif
