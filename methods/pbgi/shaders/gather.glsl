// All-pairs point-based gather between lightmap texels (`gather=all_pairs`, the article's
// loop): every receiver texel sums the surfels [u_first, u_end) with Bunnell's transfer
// (transfer.glsl) into its irradiance on each side. No visibility.
// Outputs (additive blending): this bounce's irradiance front/back, and the running total.
#include "fullscreen.glsl"
#include "pbgi_records.glsl"
#include "lightmap_texel.glsl"
#include "transfer.glsl"
layout(std430, binding = BINDING_PBGI_EMITTERS) readonly buffer EmitterBlock { Surfel emitters[]; };
uniform int u_first;
uniform int u_end;

#if defined FRAGMENT_SHADER
layout(location = 0) out vec4 out_bounce_front;
layout(location = 1) out vec4 out_bounce_back;
layout(location = 2) out vec4 out_total_front;
layout(location = 3) out vec4 out_total_back;
void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec3 front = vec3(0.0), back = vec3(0.0);
    vec3 xr, nr; float ar;
    if (lightmap_surfel(px, xr, nr, ar))
        for (int i = u_first; i < u_end; ++i) transfer(emitters[i], emitters[i].position_area.w, xr, nr, front, back);
    out_bounce_front = vec4(front, 0.0);
    out_bounce_back = vec4(back, 0.0);
    out_total_front = vec4(front, 0.0);
    out_total_back = vec4(back, 0.0);
}
#endif
