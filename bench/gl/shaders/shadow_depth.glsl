// One shadow-map layer: the light-space metric of the nearest surface (distance to a point or
// spot light, depth along a directional light's direction).
#include "lights.glsl"
uniform mat4 u_view_proj;
uniform int u_light_index;

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
}
#endif
