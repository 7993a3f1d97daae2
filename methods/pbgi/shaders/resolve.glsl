// Camera view reads the lightmap: each pixel maps its position through its triangle's chart
// map to lightmap texel coordinates, interpolates the total gathered irradiance of the side it
// shows bilinearly over the covered texels of its own chart's box only (weights renormalised
// at chart borders; boxes touch, so a tap past the box could read another chart), and leaves
// L = rho / pi * E.
#include "fullscreen.glsl"
#include "pbgi_records.glsl"
#include "lightmap_texel.glsl"
uniform sampler2D u_gbuffer_position;
uniform sampler2D u_gbuffer_geo_normal;
uniform sampler2D u_gbuffer_albedo;
uniform sampler2D u_total_front;
uniform sampler2D u_total_back;

#if defined FRAGMENT_SHADER
layout(location = 0) out vec4 out_radiance;
void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec4 p = texelFetch(u_gbuffer_position, px, 0);
    if (p.w == 0.0) { out_radiance = vec4(0.0); return; }
    vec4 geo = texelFetch(u_gbuffer_geo_normal, px, 0);   // turned to the camera, w = triangle id
    int t = int(geo.w + 0.5);
    bool front = dot(geo.xyz, chart_triangles[t].face_normal.xyz) >= 0.0;
    vec2 f = chart_texel_coords(t, p.xyz) - 0.5;
    ivec2 base = ivec2(floor(f));
    ivec4 box = ivec4(chart_triangles[t].box);
    vec2 frac_ = f - vec2(base);
    vec3 sum = vec3(0.0);
    float weight = 0.0;
    for (int k = 0; k < 4; ++k) {
        ivec2 o = ivec2(k & 1, k >> 1);
        ivec2 q = base + o;
        if (any(lessThan(q, box.xy)) || any(greaterThanEqual(q, box.zw))) continue;
        if (!(lightmap_area(q) > 0.0)) continue;
        // floor: a point exactly on a covered texel's centre line still gets a weight
        float w = max((o.x == 1 ? frac_.x : 1.0 - frac_.x) * (o.y == 1 ? frac_.y : 1.0 - frac_.y), 1e-6);
        sum += w * (front ? texelFetch(u_total_front, q, 0).rgb : texelFetch(u_total_back, q, 0).rgb);
        weight += w;
    }
    vec3 e = weight > 0.0 ? sum / weight : vec3(0.0);
    vec3 rho = texelFetch(u_gbuffer_albedo, px, 0).rgb;
    out_radiance = vec4(rho * INV_PI * e, 1.0);
}
#endif
