// The paraboloid map pass for the (VAL, triangle) pairs that map_split.glsl lists from the back
// of the pair buffer (see paraboloid_depth.glsl for the pass). The projection is not linear, so straight triangle
// edges become arcs (of circles of radius >= 1 in uv units: the images of great circles). The
// tessellation control stage splits each edge into pieces whose chord strays from the true arc
// by at most TESS_SAGITTA_TEXELS texels (TESS_MAX_ARC_UV: the longest chord allowed on a circle
// of radius 1, c^2 / 8 <= the sagitta); a piece subtending phi radians spans phi / (1 + cos
// theta) uv units at angle theta from the VAL normal (the map is conformal), largest at the
// endpoint furthest from the normal. Vertices are pulled from the scene's buffers: vertex
// 3k + c is corner c of listed pair k. The fragment stage computes the exact distance along the
// texel's direction to the triangle's plane (paraboloid_map.glsl).
#if defined TESS_EVALUATION_SHADER
#define EMITS_MAP_VERTEX
#endif
#include "paraboloid_map.glsl"

#if defined VERTEX_SHADER
out vec3 v_local;   // the vertex relative to VAL j's map origin, in its frame (t, b, n)
flat out int v_val;
void main() {
    uint pair = map_pairs[u_pair_capacity - 1u - uint(gl_VertexID) / 3u];
    int j = pair_val(pair);
    Val c = vals[j];
    vec3 t, b;
    orthonormal_basis(c.normal.xyz, t, b);
    v_local = corner_in_val_frame(pair_triangle(pair), uint(gl_VertexID) % 3u, c, t, b);
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
void main() {
    c_local[gl_InvocationID] = v_local[gl_InvocationID];
    if (gl_InvocationID == 0) {
        int j = v_val[0];
        c_val = j;
        vec3 r0 = v_local[0], r1 = v_local[1], r2 = v_local[2];
        vec3 plane;
        val_plane(r0, r1, r2, plane);   // not edge-on: map_split.glsl lists no such pair
        c_plane = vec4(plane, ignore_radius(vals[j]));
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
void main() {
    e_plane = c_plane;
    emit_map_vertex(gl_TessCoord.x * c_local[0] + gl_TessCoord.y * c_local[1] + gl_TessCoord.z * c_local[2], c_val);
}
#endif
