// Direct irradiance from all scene lights, with or without shadow maps.
#ifndef DIRECT_LIGHTING_GLSL
#define DIRECT_LIGHTING_GLSL
#include "shadow.glsl"

// E(p) on a surface with unit normal n (one-sided: light from behind n gives 0).
vec3 direct_irradiance(vec3 p, vec3 n, vec3 n_geo, bool shadowed) {
    vec3 e = vec3(0.0);
    for (int i = 0; i < u_light_count; ++i) {
        vec3 wi; float dist;
        vec3 incident = light_incident(i, p, wi, dist);
        float c = dot(n, wi);
        if (c <= 0.0 || all(equal(incident, vec3(0.0)))) continue;
        float v = shadowed ? shadow_visibility(i, p, n_geo) : 1.0;
        e += incident * c * v;
    }
    return e;
}

#endif
