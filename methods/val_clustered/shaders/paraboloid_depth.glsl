// Paraboloid shadow maps of all VALs (paper Sec. 4.2 / 6) in one instanced draw: instance j
// renders the scene as seen from VAL j's centre through a paraboloid projection oriented
// around its normal (Brabec et al. 2002: uv = (l.x, l.y) / (1 + l.z), the hemisphere above the
// VAL's plane onto the unit disc). The projection is not linear, so straight triangle edges
// become arcs (of circles of radius >= 1 in uv units: the images of great circles). The
// tessellation control stage splits each edge into pieces whose chord strays from the true
// arc by at most TESS_SAGITTA_TEXELS texels (TESS_MAX_ARC_UV: the longest chord allowed on a
// circle of radius 1, c^2 / 8 <= the sagitta); a piece subtending phi radians spans
// phi / (1 + cos theta) uv units at angle theta from the VAL normal (the map is conformal),
// largest at the endpoint furthest from the normal. Patches entirely behind the VAL's plane,
// inside its ignore radius or seen edge-on are dropped before tessellation (most of the VAL's
// own surface and its neighbours); clipping drops the rest of what lies behind the plane.
// The vertex stage moves each vertex into the VAL's frame once; the fragment stage computes
// the exact distance along the texel's direction to the triangle's plane (one flat varying:
// per-primitive set-up dominates the draw on a software rasteriser). Each texel keeps the
// smallest distance to the VAL (MIN blending into an R32F atlas, tile j). Geometry closer than
// the VAL's ignore radius is dropped (paper Sec. 5.1: a cluster centre may lie inside geometry).
#include "val_records.glsl"
uniform int u_tiles_x;
uniform int u_tiles_y;
uniform float u_near_ignore;   // ignore radius = max(u_near_min, u_near_ignore * lambda)
uniform float u_near_min;

#if defined VERTEX_SHADER
in vec3 in_position;
out vec3 v_local;   // the vertex relative to VAL j's map origin, in its frame (t, b, n)
flat out int v_val;
void main() {
    int j = gl_InstanceID;
    Val c = vals[j];
    vec3 t, b;
    orthonormal_basis(c.normal.xyz, t, b);
    vec3 r = in_position - val_origin(c);
    v_local = vec3(dot(r, t), dot(r, b), dot(r, c.normal.xyz));
    v_val = j;
}
#endif

#if defined TESS_CONTROL_SHADER
layout(vertices = 3) out;
in vec3 v_local[];
flat in int v_val[];
out vec3 c_local[];
patch out int c_val;
patch out vec4 c_plane;  // the triangle's plane in that frame, n / (n . p), and the ignore radius
// Pieces for edge ab (VAL frame, origin at the VAL): its image spans at most
// angle / (1 + cos theta_max) uv units; split into chords of at most TESS_MAX_ARC_UV.
float edge_level(vec3 a, vec3 b) {
    vec3 da = normalize(a), db = normalize(b);
    float cos_max_theta = max(min(da.z, db.z), 0.0);
    float arc_uv = angle_between(da, db) / (1.0 + cos_max_theta);
    return clamp(ceil(arc_uv / TESS_MAX_ARC_UV), 1.0, float(TESS_MAX_LEVEL));
}
void main() {
    c_local[gl_InvocationID] = v_local[gl_InvocationID];
    if (gl_InvocationID == 0) {
        int j = v_val[0];
        Val c = vals[j];
        c_val = j;
        vec3 r0 = v_local[0], r1 = v_local[1], r2 = v_local[2];
        float ignore = max(u_near_min, u_near_ignore * c.normal.w);
        bool empty = c.position.w <= 0.0;  // no VPL maps to the VAL: nothing uses its map
        bool behind = max(r0.z, max(r1.z, r2.z)) <= 0.0;
        // the triangle lies in the ball of radius `ignore` if its three corners do (convexity)
        bool inside = max(length(r0), max(length(r1), length(r2))) < ignore;
        vec3 pn = cross(r1 - r0, r2 - r0);
        float offset = dot(pn, r0);  // |pn| x the plane's distance from the VAL
        // a plane through the VAL is seen edge-on: its image is a curve that covers no area
        bool edge_on = abs(offset) <= 1e-6 * length(pn) * max(length(r0), 1e-30);
        if (empty || behind || inside || edge_on) {
            gl_TessLevelOuter[0] = 0.0; gl_TessLevelOuter[1] = 0.0; gl_TessLevelOuter[2] = 0.0;
            gl_TessLevelInner[0] = 0.0;
            return;
        }
        c_plane = vec4(pn / offset, ignore);
        float l0 = edge_level(r1, r2);
        float l1 = edge_level(r2, r0);
        float l2 = edge_level(r0, r1);
        gl_TessLevelOuter[0] = l0;
        gl_TessLevelOuter[1] = l1;
        gl_TessLevelOuter[2] = l2;
        gl_TessLevelInner[0] = max(l0, max(l1, l2));
    }
}
#endif

#if defined TESS_EVALUATION_SHADER
layout(triangles, equal_spacing, ccw) in;
in vec3 c_local[];
patch in int c_val;
patch in vec4 c_plane;
flat out vec4 e_plane;
out float gl_ClipDistance[5];
void main() {
    vec3 l = gl_TessCoord.x * c_local[0] + gl_TessCoord.y * c_local[1] + gl_TessCoord.z * c_local[2];
    float dist = length(l);
    vec3 dir = l / max(dist, 1e-30);
    vec2 uv = dir.xy / max(1.0 + dir.z, 1e-6);  // paraboloid_uv in the VAL frame
    gl_ClipDistance[0] = 1.0 - uv.x;
    gl_ClipDistance[1] = 1.0 + uv.x;
    gl_ClipDistance[2] = 1.0 - uv.y;
    gl_ClipDistance[3] = 1.0 + uv.y;
    gl_ClipDistance[4] = dir.z;
    e_plane = c_plane;
    vec2 tile = vec2(c_val % u_tiles_x, c_val / u_tiles_x);
    vec2 tiles = vec2(u_tiles_x, u_tiles_y);
    gl_Position = vec4((uv + 1.0 + 2.0 * tile) / tiles - 1.0, 0.0, 1.0);
}
#endif

#if defined FRAGMENT_SHADER
uniform int u_resolution;
flat in vec4 e_plane;  // xyz: the plane as n / (n . p) in the VAL frame, w: the ignore radius
layout(location = 0) out float out_distance;
void main() {
    // The exact distance along this texel's own direction (the inverse paraboloid projection of
    // its centre, VAL frame) to the triangle's plane, 1 / (e_plane.xyz . dir); a distance
    // interpolated over the tessellated piece would be off by percents. A texel whose ray
    // meets the plane behind the VAL lies outside the triangle (a silhouette texel the chord
    // of an edge covered): not drawn. The map's tile is the one the fragment lies in.
    vec2 uv = fract(gl_FragCoord.xy / float(u_resolution)) * 2.0 - 1.0;
    float uu = dot(uv, uv);
    vec3 dir = vec3(2.0 * uv, 1.0 - uu) / (1.0 + uu);
    float inv_dist = dot(e_plane.xyz, dir);
    if (inv_dist <= 0.0) discard;
    float dist = 1.0 / inv_dist;
    if (dist < e_plane.w) discard;
    out_distance = dist;
}
#endif
