// The paraboloid projection into a VAL's atlas tile and the fragment stage shared by the two
// map programs (paraboloid_depth.glsl, untessellated; paraboloid_depth_tess.glsl, tessellated).
// The stage that emits the map's vertices defines EMITS_MAP_VERTEX before including this file.
#include "map_pairs.glsl"
uniform int u_tiles_x;
uniform int u_tiles_y;

#if defined EMITS_MAP_VERTEX
out float gl_ClipDistance[5];
// Atlas position and clip distances of a point l in VAL j's frame.
void emit_map_vertex(vec3 l, int j) {
    float dist = length(l);
    vec3 dir = l / max(dist, 1e-30);
    vec2 uv = dir.xy / max(1.0 + dir.z, 1e-6);  // paraboloid_uv in the VAL frame
    gl_ClipDistance[0] = 1.0 - uv.x;
    gl_ClipDistance[1] = 1.0 + uv.x;
    gl_ClipDistance[2] = 1.0 - uv.y;
    gl_ClipDistance[3] = 1.0 + uv.y;
    gl_ClipDistance[4] = dir.z;
    vec2 tile = vec2(j % u_tiles_x, j / u_tiles_x);
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
