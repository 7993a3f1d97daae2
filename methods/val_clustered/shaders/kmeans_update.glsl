// k-means update (paper Sec. 6, the "divide by the count" pass): VAL j <- mean position, mean
// normal (normalised) and total flux of the VPLs scattered to it. An empty VAL keeps its centre
// (count 0: no VPL uses it). FINALIZE: the VAL's VPL count under the mapping C and, from the bounding rectangle of its VPLs on its plane,
// the VAL's size lambda = sqrt(area), and its depth normalisation distance `far` (its distance
// to the farthest corner of the scene's bounding box: an upper bound, which map_far.glsl lowers
// to the largest distance drawn in its map).
#include "val_records.glsl"
layout(local_size_x = 64) in;
uniform sampler2D u_sum_position;  // xyz sum, w count
uniform sampler2D u_sum_normal;
uniform sampler2D u_sum_flux;
uniform sampler2D u_bounds;        // max s, max t, -min s, -min t
uniform vec3 u_box_min;
uniform vec3 u_box_max;
uniform int u_vpl_count;
uniform float u_size_scale;        // VAL size lambda / sqrt(bounding rectangle area)

void main() {
    int j = u_val_first + int(gl_GlobalInvocationID.x);
    if (j >= u_val_end) return;
#if FINALIZE
    vals[j].position.w = float(val_vpl_count[j]);
    if (vals[j].position.w > 0.0) {
        vec4 bnd = texelFetch(u_bounds, ivec2(j, 0), 0);
        vec2 extent = max(bnd.xy + bnd.zw, vec2(0.0));
        vals[j].normal.w = u_size_scale * sqrt(extent.x * extent.y);
    } else {
        vals[j].normal.w = 0.0;
    }
    vec3 o = vals[j].position.xyz + vals[j].normal.xyz * u_val_lift;
#if ORIGIN_MEDOID
    // the map's origin on a lit surface: the VPL of the cluster nearest its centre (the centre
    // itself may lie inside geometry or across a wall), lifted along its own normal
    float best = 3.0e38;
    for (int k = 0; k < u_vpl_count && vals[j].position.w > 0.0; ++k) {
        if (vpl_cluster[k] != j || vpls[k].flux.rgb == vec3(0.0)) continue;
        vec3 r = vpls[k].position.xyz - vals[j].position.xyz;
        if (dot(r, r) < best) {
            best = dot(r, r);
            o = vpls[k].position.xyz + vpls[k].normal.xyz * u_val_lift;
        }
    }
#endif
    vals[j].origin = vec4(o, 0.0);
    vec3 far_corner = max(abs(u_box_min - o), abs(u_box_max - o));
    vals[j].flux.w = length(far_corner) * 1.001 + 1e-6;
#else
    vec4 sp = texelFetch(u_sum_position, ivec2(j, 0), 0);
    if (sp.w > 0.0) {
        vec3 sn = texelFetch(u_sum_normal, ivec2(j, 0), 0).xyz;
        vals[j].position = vec4(sp.xyz / sp.w, sp.w);
        float len = length(sn);
        if (len > 1e-6 * sp.w) vals[j].normal.xyz = sn / len;
        vals[j].flux = vec4(texelFetch(u_sum_flux, ivec2(j, 0), 0).rgb, 0.0);
    } else {
        vals[j].position.w = 0.0;
        vals[j].flux = vec4(0.0);
    }
#endif
}
