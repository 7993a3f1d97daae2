// Records shared by the pbgi programs: per-triangle lightmap chart maps, the covered texels,
// surfels (one disk per covered texel) and the nodes of the emitter hierarchy.
#ifndef PBGI_RECORDS_GLSL
#define PBGI_RECORDS_GLSL

struct ChartTriangle {
    vec4 row0;         // texel u = dot(row0.xyz, p) + row0.w  (p re-centred world position)
    vec4 row1;         // texel v = dot(row1.xyz, p) + row1.w
    vec4 face_normal;  // xyz unit geometric normal (the triangle's front side), w unused
    vec4 box;          // its chart's box in texels: x0, y0, x1, y1 (exclusive)
};
layout(std430, binding = BINDING_PBGI_TRIANGLES) readonly buffer ChartTriangleBlock { ChartTriangle chart_triangles[]; };

vec2 chart_texel_coords(int t, vec3 p) {
    ChartTriangle c = chart_triangles[t];
    return vec2(dot(c.row0.xyz, p) + c.row0.w, dot(c.row1.xyz, p) + c.row1.w);
}

struct Surfel {
    vec4 position_area;    // xyz position (re-centred), w world area of the disk (m^2)
    vec4 normal;           // xyz unit normal of the front side
    vec4 radiosity_front;  // rgb rho * E on the +normal side (W/m^2)
    vec4 radiosity_back;   // rgb rho * E on the -normal side
};

// A node of the emitter hierarchy (emitter_hierarchy.glsl): the power its leaves send towards
// direction w is, per colour c, dot(w, flux_odd[c]) + |dot(w, flux_even[c])| whenever all its
// leaves' normals face w on the same side (emitter_hierarchy.glsl).
struct EmitterNode {
    vec4 position_area;    // xyz area-weighted centroid, w summed area (m^2)
    vec4 axis_radius;      // xyz area-weighted mean normal, w bounding radius
    vec4 shape;            // x leaves' area-weighted mean area, y flat flag (1: every leaf on the node's plane)
    vec4 flux_odd[3];      // per colour: xyz sum a (B_front - B_back) / 2 n
    vec4 flux_even[3];     // per colour: xyz sum a (B_front + B_back) / 2 n
};

#endif
