// Point-based gather between lightmap texels (Bunnell 2005 disk-to-point transfer, as the
// article): every receiver texel sums the emitters [u_emitter_first, u_emitter_end) into its
// irradiance on each side,
//     E(r) += B_e  a_e |cos_e| |cos_r| / (pi d^2 + a_e),
// the emitter's side facing r emitting, the receiver's side facing e receiving. No visibility.
// Outputs (additive blending): this bounce's irradiance front/back, and the running total.
#include "fullscreen.glsl"
#include "pbgi_records.glsl"
#include "lightmap_texel.glsl"
layout(std430, binding = BINDING_PBGI_EMITTERS) readonly buffer EmitterBlock { Surfel emitters[]; };
uniform int u_emitter_first;
uniform int u_emitter_end;

#if defined FRAGMENT_SHADER
layout(location = 0) out vec4 out_bounce_front;
layout(location = 1) out vec4 out_bounce_back;
layout(location = 2) out vec4 out_total_front;
layout(location = 3) out vec4 out_total_back;
void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec3 front = vec3(0.0), back = vec3(0.0);
    vec3 xr, nr; float ar;
    if (lightmap_surfel(px, xr, nr, ar)) {
        for (int i = u_emitter_first; i < u_emitter_end; ++i) {
            Surfel e = emitters[i];
            vec3 v = xr - e.position_area.xyz;   // emitter -> receiver
            float d2 = dot(v, v);
            if (d2 <= 0.0) continue;                 // the receiver's own surfel
            vec3 w = v * inversesqrt(d2);
            float cos_e = dot(e.normal.xyz, w);
            float cos_r = -dot(nr, w);
            float a = e.position_area.w;
            float transfer = a * abs(cos_e) * abs(cos_r) / (PI * d2 + a);
            vec3 b = cos_e > 0.0 ? e.radiosity_front.rgb : e.radiosity_back.rgb;
            if (cos_r > 0.0) front += b * transfer; else back += b * transfer;
        }
    }
    out_bounce_front = vec4(front, 0.0);
    out_bounce_back = vec4(back, 0.0);
    out_total_front = vec4(front, 0.0);
    out_total_back = vec4(back, 0.0);
}
#endif
