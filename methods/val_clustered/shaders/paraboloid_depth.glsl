// Paraboloid shadow maps of all VALs (paper Sec. 4.2 / 6): the scene as seen from each VAL's
// centre through a paraboloid projection oriented around its normal (Brabec et al. 2002:
// uv = (l.x, l.y) / (1 + l.z), the hemisphere above the VAL's plane onto the unit disc), into
// VAL j's tile of one R32F atlas (each texel keeps the smallest distance: MIN blending).
// map_split.glsl rasterises the small pairs itself and lists the others for two draws:
// - this file: the listed pairs whose projected edges fit in one piece (large ones, or crossing
//   the VAL's plane), drawn as plain triangles from the front of the pair buffer (a
//   tessellation pipeline costs about 4x as much per primitive on a software rasteriser);
// - paraboloid_depth_tess.glsl: those whose edges must be bent into arcs.
// Vertices are pulled from the scene's buffers: vertex 3k + c is corner c of listed pair k.
// Clipping drops what lies behind the VAL's plane or outside the disc's square. The fragment
// stage computes the exact distance along the texel's direction to the triangle's plane (one
// flat varying: per-primitive set-up dominates the draw on a software rasteriser). Geometry
// closer than the VAL's ignore radius is dropped (paper Sec. 5.1: a cluster centre may lie
// inside geometry).
#if defined VERTEX_SHADER
#define EMITS_MAP_VERTEX
#endif
#include "paraboloid_map.glsl"

#if defined VERTEX_SHADER
flat out vec4 e_plane;
void main() {
    uint pair = map_pairs[uint(gl_VertexID) / 3u];
    uint corner = uint(gl_VertexID) % 3u;
    int j = pair_val(pair);
    uint triangle = pair_triangle(pair);
    Val c = vals[j];
    vec3 t, b;
    orthonormal_basis(c.normal.xyz, t, b);
    vec3 r0 = corner_in_val_frame(triangle, 0u, c, t, b);
    vec3 r1 = corner_in_val_frame(triangle, 1u, c, t, b);
    vec3 r2 = corner_in_val_frame(triangle, 2u, c, t, b);
    vec3 plane;
    val_plane(r0, r1, r2, plane);   // not edge-on: map_split.glsl lists no such pair
    e_plane = vec4(plane, ignore_radius(c));
    emit_map_vertex(corner == 0u ? r0 : (corner == 1u ? r1 : r2), j);
}
#endif
