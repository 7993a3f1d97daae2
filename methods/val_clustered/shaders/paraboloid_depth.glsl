// Paraboloid shadow maps of all VALs (paper Sec. 4.2 / 6) in one instanced draw: instance j
// renders the scene as seen from VAL j's centre through a paraboloid projection oriented
// around its normal (Brabec et al. 2002: uv = (l.x, l.y) / (1 + l.z), the hemisphere above the
// VAL's plane onto the unit disc). The projection is not linear, so straight triangle edges
// become arcs: the tessellation stages split every edge into pieces subtending at most
// TESS_MAX_ANGLE radians from the VAL before projecting, and clipping drops what lies behind
// the VAL's plane. Each texel keeps the smallest distance to the VAL (MIN blending into an
// R32F atlas, tile j). Geometry closer than the VAL's ignore radius is dropped (paper Sec. 5.1:
// a cluster centre may lie inside geometry).
#include "val_records.glsl"
uniform int u_tiles_x;
uniform int u_tiles_y;
uniform float u_near_ignore;   // ignore radius = max(u_near_min, u_near_ignore * lambda)
uniform float u_near_min;

#if defined VERTEX_SHADER
in vec3 in_position;
out vec3 v_position;
flat out int v_val;
void main() {
    v_position = in_position;
    v_val = gl_InstanceID;
}
#endif

#if defined TESS_CONTROL_SHADER
layout(vertices = 3) out;
in vec3 v_position[];
flat in int v_val[];
out vec3 c_position[];
patch out int c_val;
float edge_level(vec3 a, vec3 b, vec3 o) {
    float angle = angle_between(normalize(a - o), normalize(b - o));
    return clamp(ceil(angle / TESS_MAX_ANGLE), 1.0, float(TESS_MAX_LEVEL));
}
void main() {
    c_position[gl_InvocationID] = v_position[gl_InvocationID];
    if (gl_InvocationID == 0) {
        int j = v_val[0];
        c_val = j;
        if (vals[j].position.w <= 0.0) {  // empty VAL: nothing uses its map
            gl_TessLevelOuter[0] = 0.0; gl_TessLevelOuter[1] = 0.0; gl_TessLevelOuter[2] = 0.0;
            gl_TessLevelInner[0] = 0.0;
            return;
        }
        vec3 o = val_origin(vals[j]);
        float l0 = edge_level(v_position[1], v_position[2], o);
        float l1 = edge_level(v_position[2], v_position[0], o);
        float l2 = edge_level(v_position[0], v_position[1], o);
        gl_TessLevelOuter[0] = l0;
        gl_TessLevelOuter[1] = l1;
        gl_TessLevelOuter[2] = l2;
        gl_TessLevelInner[0] = max(l0, max(l1, l2));
    }
}
#endif

#if defined TESS_EVALUATION_SHADER
layout(triangles, equal_spacing, ccw) in;
in vec3 c_position[];
patch in int c_val;
out float e_distance;
flat out int e_val;
out float gl_ClipDistance[5];
void main() {
    vec3 p = gl_TessCoord.x * c_position[0] + gl_TessCoord.y * c_position[1] + gl_TessCoord.z * c_position[2];
    Val c = vals[c_val];
    vec3 rel = p - val_origin(c);
    float cos_theta;
    vec2 uv = paraboloid_uv(c, rel, cos_theta);
    gl_ClipDistance[0] = 1.0 - uv.x;
    gl_ClipDistance[1] = 1.0 + uv.x;
    gl_ClipDistance[2] = 1.0 - uv.y;
    gl_ClipDistance[3] = 1.0 + uv.y;
    gl_ClipDistance[4] = cos_theta;
    e_distance = length(rel);
    e_val = c_val;
    vec2 tile = vec2(c_val % u_tiles_x, c_val / u_tiles_x);
    vec2 tiles = vec2(u_tiles_x, u_tiles_y);
    gl_Position = vec4((uv + 1.0 + 2.0 * tile) / tiles - 1.0, 0.0, 1.0);
}
#endif

#if defined FRAGMENT_SHADER
in float e_distance;
flat in int e_val;
layout(location = 0) out float out_distance;
void main() {
    if (e_distance < max(u_near_min, u_near_ignore * vals[e_val].normal.w)) discard;
    out_distance = e_distance;
}
#endif
