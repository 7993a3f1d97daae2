// Per-triangle VPL records: one VPL per triangle, at its centroid or jittered uniformly over it,
// carrying the shadowed direct radiosity B = rho * E on each side of its shading normal (the
// vertex normals interpolated at the VPL, as Mitsuba's shading frame).
#ifndef VPL_TRIANGLES_GLSL
#define VPL_TRIANGLES_GLSL

// Vertex positions (v0.w = area) and the vertex shading normals n0..n2 (w unused).
struct TriangleRecord { vec4 v0_area; vec4 v1; vec4 v2; vec4 n0; vec4 n1; vec4 n2; };
layout(std430, binding = BINDING_VPL_TRIANGLES) readonly buffer TriangleBlock { TriangleRecord triangles[]; };

struct Vpl {
    vec4 position_area;   // xyz position (re-centred), w triangle area (m^2)
    vec4 normal;          // xyz unit geometric (face) normal: the cosine of the geometric term
    vec4 radiosity_front; // rgb rho * E on the side +shading_normal
    vec4 radiosity_back;  // rgb rho * E on the side -shading_normal
    vec4 shading_normal;  // xyz unit shading normal at the VPL: the incident cosine and the side
};
layout(std430, binding = BINDING_VPLS) buffer VplBlock { Vpl vpls[]; };

#endif
