// Per-triangle VPL records: one VPL per triangle, at its centroid or jittered uniformly over it,
// carrying the shadowed direct radiosity B = rho * E on each side of the triangle.
#ifndef VPL_TRIANGLES_GLSL
#define VPL_TRIANGLES_GLSL

struct TriangleRecord { vec4 v0_area; vec4 v1; vec4 v2; };
layout(std430, binding = BINDING_VPL_TRIANGLES) readonly buffer TriangleBlock { TriangleRecord triangles[]; };

struct Vpl {
    vec4 position_area;   // xyz position (re-centred), w triangle area (m^2)
    vec4 normal;          // xyz unit face normal
    vec4 radiosity_front; // rgb rho * E on the side +normal
    vec4 radiosity_back;  // rgb rho * E on the side -normal
};
layout(std430, binding = BINDING_VPLS) buffer VplBlock { Vpl vpls[]; };

#endif
