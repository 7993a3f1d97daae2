// VPL records written by vpl_sample.glsl and read by the gather (and ir_shadowed's hemicubes),
// and the RSM texel indexing shared by the CDF passes.
#ifndef VPL_RECORDS_GLSL
#define VPL_RECORDS_GLSL
#include "near_field.glsl"

struct Vpl {
    vec4 position;  // xyz re-centred position of the RSM texel's surface point, w the surface
                    // area the VPL stands for (its texel's footprint / (N pdf), m^2)
    vec4 normal;    // xyz unit geometric normal facing the light: the VPL emits on this side
    vec4 flux;      // rgb flux the VPL carries (W): its texel's rho Phi_in |<n_s, l>| / |<n_g, l>|
                    // (shading-normal irradiance, rsm.glsl) / (N pdf)
};
layout(std430, binding = BINDING_VPLS) buffer VplBlock { Vpl vpls[]; };

// RSM atlas layout (ReflectiveShadowMap.bind): layer k is tile (k % tiles_x, k / tiles_x).
uniform int u_rsm_tiles_x;
uniform int u_rsm_resolution;
uniform int u_rsm_layer_count;

uint rsm_texel_count() { return uint(u_rsm_layer_count * u_rsm_resolution * u_rsm_resolution); }

ivec2 rsm_atlas_texel(uint i) {
    uint res = uint(u_rsm_resolution);
    uint layer = i / (res * res), within = i % (res * res);
    uvec2 tile = uvec2(layer % uint(u_rsm_tiles_x), layer / uint(u_rsm_tiles_x));
    return ivec2(tile * res + uvec2(within % res, within / res));
}

// One VPL's unshadowed Lambertian transfer to receiver x (normal nx):
//   Phi <n_x, w>+ <n_k, -w>+ / d2,  w = (y_k - x) / |y_k - x|
// (the one-bounce radiance is rho_x / pi^2 times the sum over VPLs); zero when either side
// faces away. Every VPL gather (ir_*, val_clustered, visibility_gates) sums this term. d2 is the
// near field of a VPL standing for the area A_k = position.w (near_field.glsl).
vec3 vpl_transfer(Vpl v, vec3 x, vec3 nx, float eps) {
    vec3 d = v.position.xyz - x;  // x -> y
    float dist = length(d);
    if (dist <= 0.0) return vec3(0.0);
    vec3 w = d / dist;
    float cos_x = dot(nx, w);
    float cos_y = -dot(v.normal.xyz, w);
    if (cos_x <= 0.0 || cos_y <= 0.0) return vec3(0.0);
    return v.flux.rgb * (cos_x * cos_y / near_field_d2(dist, v.position.w, eps));
}

// Rec. 709 luminance: positive weights, so it is > 0 whenever any channel of the flux is.
float flux_luminance(vec3 flux) { return dot(max(flux, vec3(0.0)), vec3(0.2126, 0.7152, 0.0722)); }

#endif
