// The hemicube of a VPL: 5 faces of a cube around the VPL aligned with its normal n (front +n,
// sides +t, -t, +b, -b), each a 90-degree perspective view. The rendering pass and the
// lookup both take their frames from here, so they agree face for face. HEMICUBE_FACES (5)
// is injected from Python.
#ifndef HEMICUBE_GLSL
#define HEMICUBE_GLSL
#include "common.glsl"
#include "vpl_records.glsl"

// Face f's viewing axis `axis` and image-plane axes `right`, `up`.
void hemicube_face(int f, vec3 n, out vec3 axis, out vec3 right, out vec3 up) {
    vec3 t, b;
    orthonormal_basis(n, t, b);
    if (f == 0)      { axis = n;  right = t; up = b; }
    else if (f == 1) { axis = t;  right = n; up = b; }
    else if (f == 2) { axis = -t; right = n; up = b; }
    else if (f == 3) { axis = b;  right = t; up = n; }
    else             { axis = -b; right = t; up = n; }
}

// The face seeing direction `rel` (from the VPL) and its image coordinates in [-1, 1]^2;
// -1 for directions behind the VPL's plane whose major axis is -n (no face holds them).
int hemicube_lookup(vec3 n, vec3 rel, out vec2 uv) {
    vec3 t, b;
    orthonormal_basis(n, t, b);
    vec3 l = vec3(dot(rel, t), dot(rel, b), dot(rel, n));
    vec3 a = abs(l);
    int f;
    if (a.z >= a.x && a.z >= a.y) {
        if (l.z <= 0.0) { uv = vec2(0.0); return -1; }
        f = 0;
    } else if (a.x >= a.y) {
        f = l.x > 0.0 ? 1 : 2;
    } else {
        f = l.y > 0.0 ? 3 : 4;
    }
    vec3 axis, right, up;
    hemicube_face(f, n, axis, right, up);
    uv = vec2(dot(rel, right), dot(rel, up)) / dot(rel, axis);
    return f;
}

// The hemicube's centre: the VPL lifted off its surface along its normal by u_hemicube_lift, so
// that its own (flat) surface projects strictly below the side faces' horizon instead of
// rounding into the texel rows just above it.
uniform float u_hemicube_lift;
vec3 hemicube_origin(Vpl v) { return v.position.xyz + v.normal.xyz * u_hemicube_lift; }

// Atlas of hemicube faces (VPL k, face f) -> tile k * HEMICUBE_FACES + f, row-major.
uniform int u_hemicube_tiles_x;
uniform int u_hemicube_tiles_y;
uniform int u_hemicube_resolution;

ivec2 hemicube_tile(int k, int f) {
    int tile = k * HEMICUBE_FACES + f;
    return ivec2(tile % u_hemicube_tiles_x, tile / u_hemicube_tiles_x);
}

#endif
