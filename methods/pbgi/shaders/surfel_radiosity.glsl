// One surfel per covered lightmap texel (the article's Surfel): position, normal, area and the
// radiosity B = rho * E it emits on each side. Bounce 1 (`u_from_direct`): E is the shadowed
// direct irradiance of the scene lights at the texel ("getting the data of your lights", in
// texture space); bounce k > 1: E is the irradiance gathered by bounce k - 1.
#include "common.glsl"
#include "direct_lighting.glsl"
#include "pbgi_records.glsl"
#include "lightmap_texel.glsl"
layout(local_size_x = 64) in;

layout(std430, binding = BINDING_PBGI_TEXELS) readonly buffer TexelBlock { ivec2 texels[]; };
layout(std430, binding = BINDING_PBGI_SURFELS) writeonly buffer SurfelBlock { Surfel surfels[]; };

uniform sampler2D u_irradiance_front;
uniform sampler2D u_irradiance_back;
uniform int u_texel_count;
uniform bool u_from_direct;

void main() {
    int i = int(gl_GlobalInvocationID.x);
    if (i >= u_texel_count) return;
    ivec2 xy = texels[i];
    vec3 p, n; float area;
    lightmap_surfel(xy, p, n, area);
    vec3 ng = lightmap_face_normal(xy);
    vec3 rho = lightmap_albedo(xy);
    vec3 e_front, e_back;
    if (u_from_direct) {
        e_front = direct_irradiance(p, n, ng, true);
        e_back = direct_irradiance(p, -n, -ng, true);
    } else {
        e_front = texelFetch(u_irradiance_front, xy, 0).rgb;
        e_back = texelFetch(u_irradiance_back, xy, 0).rgb;
    }
    surfels[i].position_area = vec4(p, area);
    surfels[i].normal = vec4(n, 0.0);
    surfels[i].radiosity_front = vec4(rho * e_front, 0.0);
    surfels[i].radiosity_back = vec4(rho * e_back, 0.0);
}
