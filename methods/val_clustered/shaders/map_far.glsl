// Depth normalisation of each VAL's map for the CSM basis: far_j = the largest distance drawn
// into its tile (x 1.001), so that the map's depths span [0, 1] and the Fourier step, whose
// width is a fixed fraction of that range, is as sharp in metres as the map allows. A tile
// with nothing drawn keeps the bound set by the clustering (the scene box's farthest corner).
// One work group per VAL; each invocation scans a column strip of the tile, then a tree
// reduction in shared memory.
#include "val_records.glsl"
layout(local_size_x = 256) in;
uniform sampler2D u_depth_atlas;
uniform int u_tiles_x;
uniform int u_resolution;
shared float partial[256];

void main() {
    int j = int(gl_WorkGroupID.x);
    int i = int(gl_LocalInvocationIndex);
    ivec2 origin = ivec2(j % u_tiles_x, j / u_tiles_x) * u_resolution;
    float far_drawn = 0.0;
    for (int t = i; t < u_resolution * u_resolution; t += 256) {
        float dist = texelFetch(u_depth_atlas, origin + ivec2(t % u_resolution, t / u_resolution), 0).r;
        if (dist < 1.0e38) far_drawn = max(far_drawn, dist);
    }
    partial[i] = far_drawn;
    barrier();
    for (int s = 128; s > 0; s >>= 1) {
        if (i < s) partial[i] = max(partial[i], partial[i + s]);
        barrier();
    }
    if (i == 0 && partial[0] > 0.0) vals[j].flux.w = min(vals[j].flux.w, partial[0] * 1.001);
}
