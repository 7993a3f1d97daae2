// Clustered visibility (paper Sec. 4): for every pixel x and every VAL j, the fraction V_j(x)
// of VAL j that x sees, stored in layer j of an R32F array; the gather multiplies each VPL's
// term by the V of the VAL it maps to. x is first moved off its surface along its geometric
// normal by `u_normal_offset` texel footprints (more at grazing angles), as ir_shadowed does.
//
// VISIBILITY_CSSM = 0: hard, binary test against the paraboloid map at the VAL centre (one
//   shadow map per cluster, as lightcuts-style clustered visibility).
// VISIBILITY_CSSM = 1: parabolic convolution soft shadow maps (paper Sec. 4.1, 4.2):
//   1. search kernel: the angle the VAL (size lambda) subtends from x, at least 2 texels;
//   2. average blocker depth z_avg = [w * (z f_b(d, z))] / [w * f_b(d, z)] from the MIP-mapped
//      basis and basis-z images (f_b = 1 - f: the blocker indicator); no blocker -> V = 1;
//   3. penumbra angle seen from the VAL centre: alpha = atan(lambda (d - z_avg) / (z_avg d));
//   4. F = [w * f(d, z)] with a box kernel of alpha, read as one trilinear MIP lookup, with
//      the CSM reconstruction f = 1/2 + 2 sum_k (cos(c_k d) [w*sin(c_k z)] - sin(c_k d) [w*cos(c_k z)]) / c_k,
//      and V = clamp(1 + s (F - 1/2), 0, 1): a receiver seeing its own surface (F = 1/2) is
//      lit; s = 2 is Annen et al.'s scaled expansion, the default s = 3 also cuts the
//      ringing and the ramp of the 4-term step (see the method's manual).
//   Kernel sizes turn into texture units with the paraboloid's local scale: the map is
//   conformal (a stereographic projection), 1 / (2 (1 + cos theta)) texture widths per radian.
//   Receivers behind the VAL's plane are outside the map: V = 1 (paper Sec. 5.1).
#include "val_records.glsl"
layout(local_size_x = 8, local_size_y = 8) in;
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_geo_normal;
uniform sampler2D u_depth_atlas;
uniform int u_tiles_x;
uniform int u_resolution;
uniform float u_normal_offset;
uniform ivec2 u_size;
layout(r32f, binding = 5) writeonly uniform image2DArray u_visibility;
#if VISIBILITY_CSSM
uniform sampler2D u_basis_sin[TERM_GROUPS];   // atlases tiled as the depth atlas, MIP-mapped
uniform sampler2D u_basis_cos[TERM_GROUPS];
uniform sampler2D u_basis_zsin[TERM_GROUPS];  // half resolution: level L here is level L + 1
uniform sampler2D u_basis_zcos[TERM_GROUPS];
uniform sampler2D u_basis_z;
uniform vec2 u_atlas_size;
uniform float u_blocker_min;  // below this filtered blocker fraction: no blocker
uniform float u_csm_sharpening;  // slope s of the scaled reconstruction clamp(1 + s (F - 1/2))

// Normalised atlas coordinates of map coordinates `tex` in [0, 1]^2 of VAL j's tile for a
// trilinear lookup at full-resolution level `lod`: kept half a texel of the coarser level
// inside the tile, so that the filter never reads a neighbouring VAL's tile (the same
// coordinates serve the half-resolution atlases at level lod - 1).
vec2 atlas_coord(int j, vec2 tex, float lod) {
    float half_texel = 0.5 * exp2(min(ceil(lod), float(MAX_LOD))) / float(u_resolution);
    vec2 tile = vec2(j % u_tiles_x, j / u_tiles_x);
    return (tile + clamp(tex, vec2(half_texel), vec2(1.0 - half_texel))) * float(u_resolution) / u_atlas_size;
}

// Filtered CSM reconstruction at normalised receiver depth d: [w * f(d, z)], f the (unscaled)
// Fourier step, 1 for z > d, 0 for z < d.
float csm_filtered(vec2 at, float lod, float d) {
    float f = 0.0;
    for (int g = 0; g < TERM_GROUPS; ++g) {
        vec4 ck = PI * (2.0 * vec4(4 * g + 1, 4 * g + 2, 4 * g + 3, 4 * g + 4) - 1.0);
        f += dot(cos(ck * d) / ck, textureLod(u_basis_sin[g], at, lod))
           - dot(sin(ck * d) / ck, textureLod(u_basis_cos[g], at, lod));
    }
    return 0.5 + 2.0 * f;
}

// The blocker search's [w * (z f(d, z))] and [w * z] at level lod >= 1.
vec2 csm_filtered_z(vec2 at, float lod, float d) {
    float zf = 0.0;
    for (int g = 0; g < TERM_GROUPS; ++g) {
        vec4 ck = PI * (2.0 * vec4(4 * g + 1, 4 * g + 2, 4 * g + 3, 4 * g + 4) - 1.0);
        zf += dot(cos(ck * d) / ck, textureLod(u_basis_zsin[g], at, lod - 1.0))
            - dot(sin(ck * d) / ck, textureLod(u_basis_zcos[g], at, lod - 1.0));
    }
    float z = textureLod(u_basis_z, at, lod - 1.0).r;
    return vec2(0.5 * z + 2.0 * zf, z);
}

uniform float u_kernel_scale;  // MIP footprint per kernel width: 1 / sqrt(3) matches a box's variance (manual)

float kernel_lod(float angle, float texture_per_radian) {
    float texels = angle * texture_per_radian * float(u_resolution) * u_kernel_scale;
    return min(log2(max(texels, 1.0)), float(MAX_LOD));
}
#endif

float val_visibility(int j, vec3 x, vec3 n_geo) {
    Val c = vals[j];
    if (c.position.w <= 0.0) return 1.0;  // empty VAL: no VPL maps to it
    vec3 o = val_origin(c);
    vec3 to_val = o - x;
    float dist = length(to_val);
    if (dist <= 0.0) return 1.0;
    vec3 wi = to_val / dist;
    float cos0;
    paraboloid_uv(c, -to_val, cos0);
#if BEHIND_HORIZON == 0
    if (cos0 <= 0.0) return 1.0;
#endif
    // texel footprint at x: 2 / res uv units, (1 + cos theta) radians per uv unit
    float texel = dist * 2.0 * (1.0 + max(cos0, 0.0)) / float(u_resolution);
    vec3 n = dot(n_geo, wi) < 0.0 ? -n_geo : n_geo;
    float cos_r = clamp(dot(n, wi), 0.0, 1.0);
    float sin_r = sqrt(max(1.0 - cos_r * cos_r, 0.0));
    vec3 q = x + n * (u_normal_offset * texel * (0.5 + 1.5 * sin_r));
    vec3 rel = q - o;
    float d_world = length(rel);
    float cos_theta;
    vec2 uv = paraboloid_uv(c, rel, cos_theta);
    if (cos_theta <= 0.0) {
#if BEHIND_HORIZON
        // behind the VAL's plane (no map there): the map's horizon in the receiver's azimuth
        // holds the receiver's distance or not (see the manual); straight below: visible
        vec3 h = rel - c.normal.xyz * dot(rel, c.normal.xyz);
        if (dot(h, h) <= 1e-12 * d_world * d_world) return 1.0;
        uv = paraboloid_uv(c, h + c.normal.xyz * (1e-3 * length(h)), cos_theta);
#else
        return 1.0;
#endif
    }
#if VISIBILITY_CSSM
    float far = c.flux.w;
    float d = min(d_world / far, 1.0);
    float lambda = c.normal.w;
    vec2 tex = uv * 0.5 + 0.5;
    float per_radian = 0.5 / (1.0 + cos_theta);
    float search = 2.0 * atan(0.5 * lambda, d_world);
    float search_lod = max(kernel_lod(search, per_radian), 1.0);  // the basis-z starts at level 1
    vec2 search_at = atlas_coord(j, tex, search_lod);
    float blocked = 1.0 - csm_filtered(search_at, search_lod, d);  // [w * f_b]
    if (blocked < u_blocker_min) return 1.0;
    vec2 zfz = csm_filtered_z(search_at, search_lod, d);
    float z_avg = clamp((zfz.y - zfz.x) / blocked, 1e-6, d);     // [w * z f_b] / [w * f_b]
    float z_avg_world = z_avg * far;
    float alpha = atan(lambda * (d_world - z_avg_world), z_avg_world * d_world);
    float lod = kernel_lod(alpha, per_radian);
    float rec = csm_filtered(atlas_coord(j, tex, lod), lod, d);
    return clamp(1.0 + u_csm_sharpening * (rec - 0.5), 0.0, 1.0);
#else
    ivec2 tile = ivec2(j % u_tiles_x, j / u_tiles_x);
    ivec2 t = clamp(ivec2((uv * 0.5 + 0.5) * float(u_resolution)), ivec2(0), ivec2(u_resolution - 1));
    float stored = texelFetch(u_depth_atlas, tile * u_resolution + t, 0).r;
    return d_world <= stored + texel ? 1.0 : 0.0;
#endif
}

void main() {
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    if (px.x >= u_size.x || px.y >= u_size.y) return;
    vec4 p = texelFetch(u_gbuffer_position, px, 0);
    vec3 ng = texelFetch(u_gbuffer_geo_normal, px, 0).xyz;
    for (int j = 0; j < u_cluster_count; ++j) {
        float v = p.w == 0.0 ? 0.0 : val_visibility(j, p.xyz, ng);
        imageStore(u_visibility, ivec3(px, j), vec4(v));
    }
}
