// Reflective shadow map layer (Dachsbacher & Stamminger 2005): per texel the first surface seen
// from the light, its normal (facing the light), and the flux it reflects,
// rho * Phi_in with Phi_in = I * falloff * (texel solid angle) for point and spot lights and
// E * (texel area) for directional lights, times |<n_s, l>| / |<n_g, l>|: the irradiance of a
// smooth-shaded surface takes its cosine against the shading normal n_s (the vertex normals
// interpolated, as Mitsuba), while the texel's footprint follows the geometric normal n_g.
// (Where n_s and n_g put the light on different sides, at a smooth mesh's terminator, Mitsuba
// would emit on the shading side; the VPL keeps emitting on the lit geometric side.)
#include "common.glsl"
#include "lights.glsl"
uniform mat4 u_view_proj;
uniform int u_light_index;
uniform vec4 u_layer_info;  // as ShadowLayer.info
uniform int u_rsm_resolution;
uniform vec2 u_depth_map;   // linear depth test on the light-space metric, as shadow_depth.glsl

#if defined VERTEX_SHADER
in vec3 in_position;
in vec3 in_normal;
out vec3 v_position;
out vec3 v_normal;
out vec4 v_clip;
void main() {
    v_position = in_position;
    v_normal = in_normal;
    v_clip = u_view_proj * vec4(in_position, 1.0);
    gl_Position = v_clip;
}
#endif

#if defined GEOMETRY_SHADER
layout(triangles) in;
layout(triangle_strip, max_vertices = 3) out;
in vec3 v_position[];
in vec3 v_normal[];
in vec4 v_clip[];
out vec3 g_position;
out vec3 g_normal;
out vec4 g_clip;
flat out vec3 g_geo_normal;
void main() {
    vec3 n = cross(v_position[1] - v_position[0], v_position[2] - v_position[0]);
    vec3 geo = n / max(length(n), 1e-30);
    for (int k = 0; k < 3; ++k) {
        g_position = v_position[k];
        g_normal = v_normal[k];
        g_clip = v_clip[k];
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
in vec4 g_clip;
flat in vec3 g_geo_normal;
layout(location = 0) out vec4 out_position;
layout(location = 1) out vec4 out_normal;
layout(location = 2) out vec4 out_flux;
void main() {
    vec3 wi; float dist;
    vec3 incident = light_incident(u_light_index, g_position, wi, dist);
    vec3 n = dot(g_geo_normal, wi) < 0.0 ? -g_geo_normal : g_geo_normal;
    vec3 phi_in;
    float cross_section;  // the texel's area across the light's rays at the surface
    if (u_layer_info.y > 0.5) {
        float texel_area = u_layer_info.x * u_layer_info.x;
        phi_in = incident * texel_area;  // irradiance on the plane facing the light
        cross_section = texel_area;
    } else {
        vec2 ndc = g_clip.xy / g_clip.w;
        vec2 plane = ndc * u_layer_info.z;  // texel centre on the image plane at distance 1
        float s = 2.0 * u_layer_info.z / float(u_rsm_resolution);
        float solid_angle = s * s / pow(1.0 + dot(plane, plane), 1.5);
        phi_in = incident * dist * dist * solid_angle;  // I * falloff * d_omega
        cross_section = dist * dist * solid_angle;
    }
    float len = length(g_normal);
    vec3 ns = len > 0.0 ? g_normal / len : n;
    phi_in *= abs(dot(ns, wi)) / max(abs(dot(n, wi)), 1e-4);
    out_position = vec4(g_position, 1.0);
    out_normal = vec4(n, 0.0);
    // .a: the texel's footprint on the surface (m^2), the area its VPL stands for (vpl_sample.glsl)
    out_flux = vec4(triangle_albedo[gl_PrimitiveID].rgb * phi_in, cross_section / max(abs(dot(n, wi)), 1e-4));
    float metric = u_layer_info.y > 0.5 ? dot(g_position, lights[u_light_index].direction_cos_cutoff.xyz) : dist;
    gl_FragDepth = clamp((metric - u_depth_map.x) * u_depth_map.y, 0.0, 1.0);
}
#endif
