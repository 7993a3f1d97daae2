// Virtual area lights (VALs): one record per cluster of VPLs, the VPL -> VAL mapping C, the
// k-means clustering distance and the VAL's tangent frame. Shared by every VAL pass.
#ifndef VAL_RECORDS_GLSL
#define VAL_RECORDS_GLSL
#include "common.glsl"
#include "vpl_records.glsl"

struct Val {
    vec4 position;  // xyz centre (mean of its VPL positions), w number of VPLs mapped to it
    vec4 normal;    // xyz unit mean normal, w size lambda = sqrt(area of the bounding rectangle)
    vec4 flux;      // rgb total flux of its VPLs, w far: depth normalisation distance of its map
    vec4 origin;    // xyz the map's origin (see val_origin), w unused
};
layout(std430, binding = BINDING_VALS) buffer ValBlock { Val vals[]; };
layout(std430, binding = BINDING_VPL_CLUSTER) buffer VplClusterBlock { int vpl_cluster[]; };
layout(std430, binding = BINDING_VAL_COUNT) buffer ValCountBlock { uint val_vpl_count[]; };  // of the mapping C

uniform int u_cluster_count;
uniform float u_weight_position;   // w_x, applied to |dx| / scene radius
uniform float u_weight_angle;      // w_a, applied to the angle between the normals (radians)
uniform float u_inv_scene_radius;
uniform int u_val_first;           // the VALs [first, end) a clustering round works on (split round: the spare VALs)
uniform int u_val_end;

// Angle between two unit vectors; the atan form is accurate near 0 and pi (llvmpipe's acos is not).
float angle_between(vec3 a, vec3 b) { return atan(length(cross(a, b)), dot(a, b)); }

// The paper's clustering distance d = w_x dx + w_a da, with dx made scale-free.
float cluster_distance(vec3 p, vec3 n, Val c) {
    return u_weight_position * length(p - c.position.xyz) * u_inv_scene_radius
         + u_weight_angle * angle_between(n, c.normal.xyz);
}

// Nearest VAL of the round's range (lowest index on ties: deterministic).
int nearest_val(vec3 p, vec3 n) {
    int best = u_val_first;
    float best_d = 3.0e38;
    for (int j = u_val_first; j < u_val_end; ++j) {
        float d = cluster_distance(p, n, vals[j]);
        if (d < best_d) { best_d = d; best = j; }
    }
    return best;
}

// The paraboloid map's origin, set by kmeans_update.glsl's FINALIZE pass: the VAL centre lifted
// off its surface along its normal (the paper's), or its medoid VPL (the one nearest the centre)
// lifted along that VPL's normal (the default; see the method's manual).
uniform float u_val_lift;
vec3 val_origin(Val c) { return c.origin.xyz; }

// Paraboloid (Brabec et al. 2002) coordinates in [-1, 1]^2 of the direction `rel` from the VAL,
// and the cosine to the VAL normal (`cos_theta` < 0: behind the VAL's plane, outside the map).
vec2 paraboloid_uv(Val c, vec3 rel, out float cos_theta) {
    vec3 t, b;
    orthonormal_basis(c.normal.xyz, t, b);
    vec3 l = vec3(dot(rel, t), dot(rel, b), dot(rel, c.normal.xyz)) / max(length(rel), 1e-30);
    cos_theta = l.z;
    return l.xy / max(1.0 + l.z, 1e-6);
}

#endif
