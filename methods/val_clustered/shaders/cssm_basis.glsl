// Convolution shadow map basis images (Annen et al. 2007, 2008; paper Sec. 4.1 and 6): per
// texel of VAL j's paraboloid map, the normalised depth z = R min(distance / far_j, 1) (R where
// nothing was drawn; R = CSM_DEPTH_RANGE = 1 - the sharpened step's ramp: the step has period 2
// in z - d and steps back at z - d = -1, which the unit range let blockers near the map's origin
// reach, see the method's manual) expanded into the Fourier basis of the shadow test,
//   sin(c_k z), cos(c_k z)  (the basis images B_i)
//   z sin(c_k z), z cos(c_k z), z  (the "basis-z" images of the average-blocker search)
// with c_k = pi (2k - 1), k = 1 .. 4 TERM_GROUPS, four terms per RGBA image. One quad per tile
// j of the atlas (tile_x = j mod tiles_x), VAL j's map as in the depth atlas; tiles past the
// last VAL get an empty map (z = 1). The MIP maps of these atlases (built after this pass) are
// the box-filter convolutions w * B_i of every tile at once (tiles of a power-of-two size
// never share a texel of a MIP level).
// HALF_RES = 0: the basis images at the map's resolution, outputs sin_g, cos_g per group g.
// HALF_RES = 1: the basis-z images at half resolution, each texel the mean of its 2 x 2 map
//   texels: exactly level 1 of their full-resolution MIP chain (the blocker search, a kernel
//   the size of the VAL, never reads level 0); outputs zsin_g, zcos_g per group, then z.
#include "val_records.glsl"
uniform sampler2D u_depth_atlas;
uniform int u_tiles_x;
uniform int u_tiles_y;

#if defined VERTEX_SHADER
flat out float v_far;
void main() {  // instance j: a quad over tile j, carrying VAL j's depth normalisation
    int j = gl_InstanceID;
    vec2 corner = vec2(gl_VertexID & 1, (gl_VertexID >> 1) & 1);
    vec2 tile = vec2(j % u_tiles_x, j / u_tiles_x);
    gl_Position = vec4((tile + corner) / vec2(u_tiles_x, u_tiles_y) * 2.0 - 1.0, 0.0, 1.0);
    v_far = j < u_cluster_count ? vals[j].flux.w : 0.0;
}
#endif

#if defined FRAGMENT_SHADER
flat in float v_far;
layout(location = 0) out vec4 out_basis[2 * TERM_GROUPS];
#if HALF_RES
layout(location = 2 * TERM_GROUPS) out float out_z;
#endif

float normalised_depth(ivec2 texel) {
    return CSM_DEPTH_RANGE * (v_far > 0.0 ? clamp(texelFetch(u_depth_atlas, texel, 0).r / v_far, 0.0, 1.0) : 1.0);
}

void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
#if HALF_RES
    vec4 zs[TERM_GROUPS], zc[TERM_GROUPS];
    for (int g = 0; g < TERM_GROUPS; ++g) { zs[g] = vec4(0.0); zc[g] = vec4(0.0); }
    float zsum = 0.0;
    for (int k = 0; k < 4; ++k) {
        float z = normalised_depth(2 * px + ivec2(k & 1, k >> 1));
        zsum += z;
        for (int g = 0; g < TERM_GROUPS; ++g) {
            vec4 ck = PI * (2.0 * vec4(4 * g + 1, 4 * g + 2, 4 * g + 3, 4 * g + 4) - 1.0);
            zs[g] += z * sin(ck * z);
            zc[g] += z * cos(ck * z);
        }
    }
    for (int g = 0; g < TERM_GROUPS; ++g) {
        out_basis[2 * g] = 0.25 * zs[g];
        out_basis[2 * g + 1] = 0.25 * zc[g];
    }
    out_z = 0.25 * zsum;
#else
    float z = normalised_depth(px);
    for (int g = 0; g < TERM_GROUPS; ++g) {
        vec4 ck = PI * (2.0 * vec4(4 * g + 1, 4 * g + 2, 4 * g + 3, 4 * g + 4) - 1.0);
        out_basis[2 * g] = sin(ck * z);
        out_basis[2 * g + 1] = cos(ck * z);
    }
#endif
}
#endif
