// Chart overlap check (prepare only): every triangle rasterised at its lightmap coordinates
// with GL's ordinary rules, which give a texel centre on an edge shared by two triangles of
// a chart to exactly one of them; additive blending counts the triangles per texel centre, so
// a count above 1 means a chart folds over itself in projection (not a height field).
#include "pbgi_records.glsl"
uniform float u_lightmap_size;

#if defined VERTEX_SHADER
in vec3 in_position;
out vec3 v_position;
void main() {
    v_position = in_position;
    gl_Position = vec4(0.0, 0.0, 0.0, 1.0);
}
#endif

#if defined GEOMETRY_SHADER
layout(triangles) in;
layout(triangle_strip, max_vertices = 3) out;
in vec3 v_position[];
void main() {
    for (int k = 0; k < 3; ++k) {
        vec2 q = chart_texel_coords(gl_PrimitiveIDIn, v_position[k]);
        gl_Position = vec4(q / u_lightmap_size * 2.0 - 1.0, 0.0, 1.0);
        EmitVertex();
    }
    EndPrimitive();
}
#endif

#if defined FRAGMENT_SHADER
layout(location = 0) out vec4 out_count;
void main() { out_count = vec4(1.0, 0.0, 0.0, 0.0); }
#endif
