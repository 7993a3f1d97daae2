// One shadow-map layer: the light-space metric of the nearest surface (distance to a point or
// spot light, depth along a directional light's direction). The depth test runs on that metric
// mapped linearly to [0, 1] (u_depth_map), not on the projection's 1/z depth: with near =
// 1e-5 far, a 24-bit 1/z buffer has steps of ~far/170 at the far end, coarser than the shadow
// tolerance, so the wrong surface of two close ones could win; linear steps are far / 2^24.
#include "lights.glsl"
uniform mat4 u_view_proj;
uniform int u_light_index;
uniform vec2 u_depth_map;   // depth = (metric - x) * y

#if defined VERTEX_SHADER
in vec3 in_position;
out vec3 v_position;
void main() {
    v_position = in_position;
    gl_Position = u_view_proj * vec4(in_position, 1.0);
}
#endif

#if defined FRAGMENT_SHADER
in vec3 v_position;
layout(location = 0) out float out_metric;
void main() {
    Light L = lights[u_light_index];
    out_metric = light_kind(u_light_index) == LIGHT_DIRECTIONAL
        ? dot(v_position, L.direction_cos_cutoff.xyz)
        : length(v_position - L.position_kind.xyz);
    gl_FragDepth = clamp((out_metric - u_depth_map.x) * u_depth_map.y, 0.0, 1.0);
}
#endif
