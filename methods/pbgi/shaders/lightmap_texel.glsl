// Reading one texel of the texture-space G-buffer written by lightmap_gbuffer.glsl, whose
// targets hold area-weighted sums: divided by the texel's area here.
#ifndef LIGHTMAP_TEXEL_GLSL
#define LIGHTMAP_TEXEL_GLSL
uniform sampler2D u_lightmap_position;     // (sum a p, sum a)
uniform sampler2D u_lightmap_normal;       // (sum a n_shading, 0)
uniform sampler2D u_lightmap_face_normal;  // (sum a n_face, 0)
uniform sampler2D u_lightmap_albedo;       // (sum a rho, 0)

float lightmap_area(ivec2 xy) { return texelFetch(u_lightmap_position, xy, 0).w; }

// false for texels no surface covers
bool lightmap_surfel(ivec2 xy, out vec3 p, out vec3 n, out float area) {
    vec4 pa = texelFetch(u_lightmap_position, xy, 0);
    area = pa.w;
    if (!(area > 0.0)) return false;
    p = pa.xyz / area;
    vec3 s = texelFetch(u_lightmap_normal, xy, 0).xyz;
    float len = length(s);
    n = len > 0.0 ? s / len : vec3(0.0, 0.0, 1.0);
    return true;
}

vec3 lightmap_face_normal(ivec2 xy) {
    vec3 s = texelFetch(u_lightmap_face_normal, xy, 0).xyz;
    float len = length(s);
    return len > 0.0 ? s / len : vec3(0.0, 0.0, 1.0);
}

vec3 lightmap_albedo(ivec2 xy) {
    float a = lightmap_area(xy);
    return a > 0.0 ? texelFetch(u_lightmap_albedo, xy, 0).rgb / a : vec3(0.0);
}
#endif
