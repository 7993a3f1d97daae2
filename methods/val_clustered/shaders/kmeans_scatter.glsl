// One k-means step by scattering (paper Sec. 6): one point per VPL; its vertex shader finds the
// nearest VAL and moves the point onto that VAL's texel of an M x 1 target.
//  - default: additive blending sums position (+1 in w: the count), normal and flux;
//  - ASSIGN_PASS: the final pass writes the mapping C (VPL -> VAL) and, with MAX blending,
//    counts the VPLs of each VAL (integer atomics: exact in any order) and
//    the bounding rectangle (s, t, -s, -t) of the VPLs projected onto the VAL's plane.
#include "val_records.glsl"

uniform int u_orphans_only;
#if defined VERTEX_SHADER
flat out vec4 v_out0;
flat out vec4 v_out1;
flat out vec4 v_out2;
void main() {
    int k = gl_VertexID;
    Vpl v = vpls[k];
    int c = nearest_val(v.position.xyz, v.normal.xyz);
    bool live = v.flux.rgb != vec3(0.0);  // a VPL of flux 0 (unlit Halton texel) joins no cluster
    if (u_orphans_only != 0 && vpl_cluster[k] >= 0) live = false;  // split round: the orphans only
#if ASSIGN_PASS
    if (u_orphans_only == 0 || live) vpl_cluster[k] = c;
    if (live) atomicAdd(val_vpl_count[c], 1u);
    vec3 t, b;
    orthonormal_basis(vals[c].normal.xyz, t, b);
    vec3 rel = v.position.xyz - vals[c].position.xyz;
    float s = dot(rel, t), r = dot(rel, b);
    v_out0 = vec4(s, r, -s, -r);
    v_out1 = vec4(0.0);
    v_out2 = vec4(0.0);
#else
    v_out0 = vec4(v.position.xyz, 1.0);
    v_out1 = vec4(v.normal.xyz, 0.0);
    v_out2 = vec4(v.flux.rgb, 0.0);
#endif
    gl_Position = live ? vec4((float(c) + 0.5) / float(u_cluster_count) * 2.0 - 1.0, 0.0, 0.0, 1.0)
                       : vec4(-2.0, -2.0, 0.0, 1.0);  // outside the viewport: not drawn
}
#endif

#if defined FRAGMENT_SHADER
flat in vec4 v_out0;
flat in vec4 v_out1;
flat in vec4 v_out2;
layout(location = 0) out vec4 out0;
#if !ASSIGN_PASS
layout(location = 1) out vec4 out1;
layout(location = 2) out vec4 out2;
#endif
void main() {
    out0 = v_out0;
#if !ASSIGN_PASS
    out1 = v_out1;
    out2 = v_out2;
#endif
}
#endif
