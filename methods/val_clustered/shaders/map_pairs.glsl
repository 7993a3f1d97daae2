// The (VAL, triangle) pairs of the paraboloid map pass, one chunk of triangles at a time:
// map_split.glsl tests every pair, rasterises the small ones itself and lists the others in
// the pair buffer (one uint each: VAL index << PAIR_TRIANGLE_BITS | triangle index -
// u_first_triangle) for the two draws, paraboloid_depth.glsl (from the front) and
// paraboloid_depth_tess.glsl (from the back), whose vertices are pulled from the scene's buffers.
#ifndef MAP_PAIRS_GLSL
#define MAP_PAIRS_GLSL
#include "val_records.glsl"
layout(std430, binding = BINDING_MAP_POSITIONS) readonly buffer MapPositions { float map_positions[]; };
layout(std430, binding = BINDING_MAP_FACES) readonly buffer MapFaces { uint map_faces[]; };
layout(std430, binding = BINDING_MAP_PAIRS) buffer MapPairs { uint map_pairs[]; };
uniform uint u_first_triangle;   // the chunk's first triangle
uniform uint u_pair_capacity;    // entries of map_pairs
uniform float u_near_ignore;     // ignore radius = max(u_near_min, u_near_ignore * lambda)
uniform float u_near_min;

const uint PAIR_TRIANGLE_MASK = (1u << PAIR_TRIANGLE_BITS) - 1u;

uint encode_pair(int j, uint triangle) { return (uint(j) << PAIR_TRIANGLE_BITS) | (triangle - u_first_triangle); }
int pair_val(uint pair) { return int(pair >> PAIR_TRIANGLE_BITS); }
uint pair_triangle(uint pair) { return (pair & PAIR_TRIANGLE_MASK) + u_first_triangle; }

vec3 scene_position(uint v) {
    return vec3(map_positions[3u * v], map_positions[3u * v + 1u], map_positions[3u * v + 2u]);
}

// Corner c of a triangle relative to VAL c's map origin, in its frame (t, b, n).
vec3 corner_in_val_frame(uint triangle, uint corner, Val c, vec3 t, vec3 b) {
    vec3 r = scene_position(map_faces[3u * triangle + corner]) - val_origin(c);
    return vec3(dot(r, t), dot(r, b), dot(r, c.normal.xyz));
}

float ignore_radius(Val c) { return max(u_near_min, u_near_ignore * c.normal.w); }

// The triangle's plane in the VAL frame as n / (n . p): 1 / dot(plane, dir) is the distance
// along the unit direction dir. Returns false for a plane through the VAL (seen edge-on: its
// image is a curve that covers no area).
bool val_plane(vec3 r0, vec3 r1, vec3 r2, out vec3 plane) {
    vec3 pn = cross(r1 - r0, r2 - r0);
    float offset = dot(pn, r0);  // |pn| x the plane's distance from the VAL
    plane = pn / offset;
    return abs(offset) > 1e-6 * length(pn) * max(length(r0), 1e-30);
}

// Pieces for edge ab (VAL frame, origin at the VAL): its image spans at most
// angle / (1 + cos theta_max) uv units; split into chords of at most TESS_MAX_ARC_UV.
float edge_level(vec3 a, vec3 b) {
    vec3 da = normalize(a), db = normalize(b);
    float cos_max_theta = max(min(da.z, db.z), 0.0);
    float arc_uv = angle_between(da, db) / (1.0 + cos_max_theta);
    return clamp(ceil(arc_uv / TESS_MAX_ARC_UV), 1.0, float(TESS_MAX_LEVEL));
}
#endif
