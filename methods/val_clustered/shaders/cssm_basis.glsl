// Convolution shadow map basis images (Annen et al. 2007, 2008; paper Sec. 4.1 and 6): per
// texel of VAL j's paraboloid map, the normalised depth z = min(distance / far_j, 1) (1 where
// nothing was drawn) expanded into the Fourier basis of the shadow test,
//   sin(c_k z), cos(c_k z)  (the basis images B_i)
//   z sin(c_k z), z cos(c_k z), z  (the "basis-z" images of the average-blocker search)
// with c_k = pi (2k - 1), k = 1 .. 4 * TERM_GROUPS, four terms per RGBA layer. The MIP maps of
// these arrays (built after this pass) are the box-filter convolutions w * B_i.
#include "val_records.glsl"
layout(local_size_x = 8, local_size_y = 8) in;
uniform sampler2D u_depth_atlas;
uniform int u_tiles_x;
uniform int u_resolution;
layout(rgba16f, binding = 0) writeonly uniform image2DArray u_basis_sin;
layout(rgba16f, binding = 1) writeonly uniform image2DArray u_basis_cos;
layout(rgba16f, binding = 2) writeonly uniform image2DArray u_basis_zsin;
layout(rgba16f, binding = 3) writeonly uniform image2DArray u_basis_zcos;
layout(r16f, binding = 4) writeonly uniform image2DArray u_basis_z;

void main() {
    ivec3 id = ivec3(gl_GlobalInvocationID);
    if (id.x >= u_resolution || id.y >= u_resolution || id.z >= u_cluster_count) return;
    int j = id.z;
    ivec2 tile = ivec2(j % u_tiles_x, j / u_tiles_x);
    float dist = texelFetch(u_depth_atlas, tile * u_resolution + id.xy, 0).r;
    float z = clamp(dist / vals[j].flux.w, 0.0, 1.0);
    for (int g = 0; g < TERM_GROUPS; ++g) {
        vec4 ck = PI * (2.0 * vec4(4 * g + 1, 4 * g + 2, 4 * g + 3, 4 * g + 4) - 1.0);
        vec4 s = sin(ck * z), c = cos(ck * z);
        ivec3 at = ivec3(id.xy, j * TERM_GROUPS + g);
        imageStore(u_basis_sin, at, s);
        imageStore(u_basis_cos, at, c);
        imageStore(u_basis_zsin, at, z * s);
        imageStore(u_basis_zcos, at, z * c);
    }
    imageStore(u_basis_z, ivec3(id.xy, j), vec4(z));
}
