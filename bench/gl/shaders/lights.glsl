// Scene lights (std430 records written by GpuScene._light_records) and Mitsuba's emitter
// conventions: point I/r^2, spot I*falloff/r^2 (Mitsuba `spot` falloff), directional E.
#ifndef LIGHTS_GLSL
#define LIGHTS_GLSL

#define LIGHT_POINT 0
#define LIGHT_SPOT 1
#define LIGHT_DIRECTIONAL 2

struct Light {
    vec4 position_kind;         // xyz position (re-centred), w kind
    vec4 direction_cos_cutoff;  // xyz spot axis / directional travel direction, w cos(cutoff)
    vec4 intensity_cos_beam;    // rgb intensity (W/sr) or irradiance (W/m^2), w cos(beam width)
    vec4 angles_layers;         // x cutoff (rad), y beam width (rad), z first shadow layer, w layer count
};

layout(std430, binding = BINDING_LIGHTS) readonly buffer LightBlock { Light lights[]; };
uniform int u_light_count;

int light_kind(int i) { return int(lights[i].position_kind.w + 0.5); }

// Mitsuba 3 spot falloff: 1 inside the beam width, linear in angle to 0 at the cutoff.
float spot_falloff(Light L, vec3 dir_from_light) {
    float cos_theta = dot(dir_from_light, L.direction_cos_cutoff.xyz);
    if (cos_theta <= L.direction_cos_cutoff.w) return 0.0;
    if (cos_theta >= L.intensity_cos_beam.w) return 1.0;
    // atan form: llvmpipe's acos is off by ~1e-4 rad, enough to show in the falloff ramp
    float theta = atan(sqrt(max(1.0 - cos_theta * cos_theta, 0.0)), cos_theta);
    return (L.angles_layers.x - theta) / (L.angles_layers.x - L.angles_layers.y);
}

// Irradiance on a surface facing the light at p (W/m^2, rgb), the unit direction towards the
// light `wi` and the distance `dist` (infinite for directional lights).
vec3 light_incident(int i, vec3 p, out vec3 wi, out float dist) {
    Light L = lights[i];
    int kind = light_kind(i);
    if (kind == LIGHT_DIRECTIONAL) {
        wi = -L.direction_cos_cutoff.xyz;
        dist = 3.0e38;
        return L.intensity_cos_beam.rgb;
    }
    vec3 d = L.position_kind.xyz - p;
    float r2 = max(dot(d, d), 1e-30);
    dist = sqrt(r2);
    wi = d / dist;
    vec3 e = L.intensity_cos_beam.rgb / r2;
    if (kind == LIGHT_SPOT) e *= spot_falloff(L, -wi);
    return e;
}

#endif
