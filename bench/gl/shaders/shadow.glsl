// Shadow-map lookup. Every light owns a few layers of one atlas (point: 6 cube faces, spot: 1
// perspective or, wider than 45 degrees, 6 cube faces, directional: 1 orthographic: see
// bench.gl.passes.plan_light_layers); each texel stores the light-space metric of the
// nearest surface: distance to the light (point, spot) or depth along the light direction
// (directional).
#ifndef SHADOW_GLSL
#define SHADOW_GLSL
#include "lights.glsl"

struct ShadowLayer {
    mat4 view_proj;
    vec4 info;  // x world texel size per unit distance (perspective) or world texel size (ortho),
                // y 1 if orthographic, z tan(fov/2) (perspective), w unused
};
layout(std430, binding = BINDING_SHADOW_LAYERS) readonly buffer ShadowLayerBlock { ShadowLayer shadow_layers[]; };
uniform sampler2D u_shadow_atlas;
uniform int u_shadow_tiles_x;
uniform int u_shadow_resolution;

float shadow_metric(int i, vec3 p) {
    Light L = lights[i];
    if (light_kind(i) == LIGHT_DIRECTIONAL) return dot(p, L.direction_cos_cutoff.xyz);
    return length(p - L.position_kind.xyz);
}

int shadow_layer_for(int i, vec3 p) {
    Light L = lights[i];
    int first = int(L.angles_layers.z + 0.5);
    if (int(L.angles_layers.w + 0.5) != 6) return first;   // six layers are cube faces
    vec3 v = p - L.position_kind.xyz;
    vec3 a = abs(v);
    if (a.x >= a.y && a.x >= a.z) return first + (v.x > 0.0 ? 0 : 1);
    if (a.y >= a.z) return first + (v.y > 0.0 ? 2 : 3);
    return first + (v.z > 0.0 ? 4 : 5);
}

// Fraction of light i reaching p (0 or 1), p offset along the geometric normal n_geo (facing the
// light) by a texel footprint to avoid self-shadowing acne. The offset and the depth tolerance
// erode every shadow by about their size, so they are kept at the least that shows no acne on the
// corpus: a normal offset of (0.25 + 0.5 sin) texel and half a texel of depth. Measured against
// the Mitsuba direct reference at 320 x 180 (512^2 shadow maps), relmse: sponza 17.0 -> 10.9
// (image mean 1.154 -> 1.114 of Mitsuba's: the sun's shadow lines under the roof's overhang),
// sibenik 0.50 -> 0.20, rooms 1.15 -> 0.36, cornell_box 1.94 -> 0.94; no pixel of the small
// scenes dark where Mitsuba is lit (acne) with either (offsets were (0.5 + 1.5 sin), one texel).
float shadow_visibility(int i, vec3 p, vec3 n_geo) {
    Light L = lights[i];
    vec3 wi; float dist;
    light_incident(i, p, wi, dist);
    int layer = shadow_layer_for(i, p);
    ShadowLayer S = shadow_layers[layer];
    float texel = S.info.y > 0.5 ? S.info.x : S.info.x * dist;
    vec3 n = dot(n_geo, wi) < 0.0 ? -n_geo : n_geo;
    float cos_l = clamp(dot(n, wi), 0.0, 1.0);
    float sin_l = sqrt(max(1.0 - cos_l * cos_l, 0.0));
    vec3 q = p + n * texel * (0.25 + 0.5 * sin_l);
    layer = shadow_layer_for(i, q);
    S = shadow_layers[layer];
    vec4 clip = S.view_proj * vec4(q, 1.0);
    vec3 ndc = clip.xyz / clip.w;
    if (clip.w <= 0.0 || any(greaterThan(abs(ndc.xy), vec2(1.0)))) return 1.0;
    ivec2 tile = ivec2(layer % u_shadow_tiles_x, layer / u_shadow_tiles_x);
    ivec2 texel_xy = clamp(ivec2((ndc.xy * 0.5 + 0.5) * float(u_shadow_resolution)), ivec2(0), ivec2(u_shadow_resolution - 1));
    float stored = texelFetch(u_shadow_atlas, tile * u_shadow_resolution + texel_xy, 0).r;
    return shadow_metric(i, q) <= stored + 0.5 * texel ? 1.0 : 0.0;
}

#endif
