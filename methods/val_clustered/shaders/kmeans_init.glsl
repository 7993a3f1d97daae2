// k-means start (paper Sec. 6): VAL k starts at VPL k N / M, the same VPL index every frame,
// so that the clustering restarts from an identical assignment each frame (temporal coherence).
// The split round (u_orphans_only) starts spare VAL s of S at the first orphan VPL (one its
// VAL's origin does not see, vpl_cluster < 0) from index s N / S on; with no orphan it stays
// empty, out of every VPL's reach.
#include "val_records.glsl"
layout(local_size_x = 64) in;
uniform int u_vpl_count;
uniform int u_orphans_only;

void main() {
    int j = u_val_first + int(gl_GlobalInvocationID.x);
    if (j >= u_val_end) return;
    int k0 = ((j - u_val_first) * u_vpl_count) / (u_val_end - u_val_first);  // j < M <= 512, N <= 8192: no overflow
    // the first VPL from there on that carries light (Halton VPLs on unlit texels carry none)
    int k = -1;
    for (int i = 0; i < u_vpl_count; ++i) {
        int kk = (k0 + i) % u_vpl_count;
        if (vpls[kk].flux.rgb != vec3(0.0) && (u_orphans_only == 0 || vpl_cluster[kk] < 0)) { k = kk; break; }
    }
    if (k < 0 && u_orphans_only != 0) {   // no orphan: an empty VAL no VPL is nearest to
        vals[j].position = vec4(vec3(1.0e30), 0.0);
        vals[j].normal = vec4(0.0, 0.0, 1.0, 0.0);
        vals[j].flux = vec4(0.0);
        vals[j].origin = vals[j].position;
        return;
    }
    Vpl v = vpls[max(k, k0)];
    vals[j].position = vec4(v.position.xyz, 0.0);
    vals[j].normal = vec4(v.normal.xyz, 0.0);
    vals[j].flux = vec4(0.0);
    vals[j].origin = vec4(v.position.xyz, 0.0);
}
