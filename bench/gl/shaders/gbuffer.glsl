// GBuffer: re-centred world position (w = 1 where covered), shading normal and geometric
// normal flipped towards the camera (two-sided surfaces, as Mitsuba's `twosided` diffuse),
// albedo, and the triangle index. The depth test runs on the distance to the camera times
// u_depth_scale (1 / far), linear, not on the projection's 1/z depth: with near = 1e-5 far a
// 24-bit 1/z buffer cannot order surfaces closer than ~far/170 at the far end.
#include "common.glsl"
uniform mat4 u_view_proj;
uniform vec3 u_camera_pos;
uniform float u_depth_scale;

#if defined VERTEX_SHADER
in vec3 in_position;
in vec3 in_normal;
out vec3 v_position;
out vec3 v_normal;
void main() {
    v_position = in_position;
    v_normal = in_normal;
    gl_Position = u_view_proj * vec4(in_position, 1.0);
}
#endif

#if defined GEOMETRY_SHADER
layout(triangles) in;
layout(triangle_strip, max_vertices = 3) out;
in vec3 v_position[];
in vec3 v_normal[];
out vec3 g_position;
out vec3 g_normal;
flat out vec3 g_geo_normal;
void main() {
    vec3 n = cross(v_position[1] - v_position[0], v_position[2] - v_position[0]);
    vec3 geo = n / max(length(n), 1e-30);
    for (int k = 0; k < 3; ++k) {
        g_position = v_position[k];
        g_normal = v_normal[k];
        g_geo_normal = geo;
        gl_PrimitiveID = gl_PrimitiveIDIn;
        gl_Position = gl_in[k].gl_Position;
        EmitVertex();
    }
    EndPrimitive();
}
#endif

#if defined FRAGMENT_SHADER
in vec3 g_position;
in vec3 g_normal;
flat in vec3 g_geo_normal;
layout(location = 0) out vec4 out_position;
layout(location = 1) out vec4 out_normal;
layout(location = 2) out vec4 out_albedo;
layout(location = 3) out vec4 out_geo_normal;
void main() {
    vec3 to_camera = u_camera_pos - g_position;
    vec3 n = normalize(g_normal);
    // Mitsuba's twosided BSDF flips by the side of the shading normal the viewer is on.
    if (dot(n, to_camera) < 0.0) n = -n;
    vec3 ng = dot(g_geo_normal, to_camera) < 0.0 ? -g_geo_normal : g_geo_normal;
    out_position = vec4(g_position, 1.0);
    out_normal = vec4(n, 0.0);
    out_albedo = vec4(triangle_albedo[gl_PrimitiveID].rgb, 1.0);
    out_geo_normal = vec4(ng, float(gl_PrimitiveID));
    gl_FragDepth = clamp(length(to_camera) * u_depth_scale, 0.0, 1.0);
}
#endif
