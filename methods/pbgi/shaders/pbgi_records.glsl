// Records shared by the pbgi programs: per-triangle lightmap chart maps, the covered texels,
// and surfels (one disk per covered texel, or per node of the emitter hierarchy).
#ifndef PBGI_RECORDS_GLSL
#define PBGI_RECORDS_GLSL

struct ChartTriangle {
    vec4 row0;         // texel u = dot(row0.xyz, p) + row0.w  (p re-centred world position)
    vec4 row1;         // texel v = dot(row1.xyz, p) + row1.w
    vec4 face_normal;  // xyz unit geometric normal (the triangle's front side), w unused
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

#endif
