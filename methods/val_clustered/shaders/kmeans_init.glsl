// k-means start (paper Sec. 6): VAL k starts at VPL k N / M, the same VPL index every frame,
// so that the clustering restarts from an identical assignment each frame (temporal coherence).
#include "val_records.glsl"
layout(local_size_x = 64) in;
uniform int u_vpl_count;

void main() {
    int j = int(gl_GlobalInvocationID.x);
    if (j >= u_cluster_count) return;
    int k0 = (j * u_vpl_count) / u_cluster_count;  // j < M <= 256, N <= 8192: no overflow
    // the first VPL from there on that carries light (Halton VPLs on unlit texels carry none)
    int k = k0;
    for (int i = 0; i < u_vpl_count; ++i) {
        int kk = (k0 + i) % u_vpl_count;
        if (vpls[kk].flux.rgb != vec3(0.0)) { k = kk; break; }
    }
    Vpl v = vpls[k];
    vals[j].position = vec4(v.position.xyz, 0.0);
    vals[j].normal = vec4(v.normal.xyz, 0.0);
    vals[j].flux = vec4(0.0);
}
