// The scene written in texture space (the article's "getting the data of the scene"): every
// triangle rasterised at its lightmap coordinates. Rasterisation is conservative (the
// article's fix for faces smaller than a texel): the geometry shader pushes each edge out by
// half a texel (Hasselgren et al., GPU Gems 2 ch. 42) and clips the grown triangle to the
// triangle's box grown by half a texel (acute corners reach far). Each fragment clips its texel square to
// the triangle (Sutherland-Hodgman) and adds, with additive blending, the piece's world area
// a and a times its piece_centre, shading normal, face normal and albedo. A texel's surfel is
// then the area-weighted mean of the pieces of surface inside it, and the texel areas sum
// exactly to the surface area (the texel squares partition the plane).
//   target 0: (sum a p, sum a)   1: (sum a n_shading, 0)   2: (sum a n_face, 0)   3: (sum a rho, 0)
#include "common.glsl"
#include "pbgi_records.glsl"
uniform float u_lightmap_size;

#if defined VERTEX_SHADER
in vec3 in_position;
in vec3 in_normal;
out vec3 v_position;
out vec3 v_normal;
void main() {
    v_position = in_position;
    v_normal = in_normal;
    gl_Position = vec4(0.0, 0.0, 0.0, 1.0);
}
#endif

float cross2(vec2 a, vec2 b) { return a.x * b.y - a.y * b.x; }

#if defined GEOMETRY_SHADER
layout(triangles) in;
layout(triangle_strip, max_vertices = 8) out;
in vec3 v_position[];
in vec3 v_normal[];
flat out vec3 g_p0, g_p1, g_p2;
flat out vec3 g_n0, g_n1, g_n2;
flat out vec2 g_q0, g_q1, g_q2;
flat out vec4 g_bounds;
flat out float g_area_ratio;  // world m^2 per texel^2 of this triangle
flat out int g_triangle;

void main() {
    int t = gl_PrimitiveIDIn;
    vec2 q[3];
    for (int k = 0; k < 3; ++k) q[k] = chart_texel_coords(t, v_position[k]);
    float area2 = cross2(q[1] - q[0], q[2] - q[0]);
    if (abs(area2) <= 1e-20) return;
    float orient = area2 < 0.0 ? -1.0 : 1.0;
    // Edge k runs q[k] -> q[k+1]; outward normal m and offset line dot(m, x) = c + half-texel support.
    vec2 m[3]; float c[3];
    for (int k = 0; k < 3; ++k) {
        vec2 e = q[(k + 1) % 3] - q[k];
        m[k] = orient * vec2(e.y, -e.x);
        c[k] = dot(m[k], q[k]) + 0.5 * (abs(m[k].x) + abs(m[k].y));
    }
    g_p0 = v_position[0]; g_p1 = v_position[1]; g_p2 = v_position[2];
    vec3 fn = chart_triangles[t].face_normal.xyz;
    // shading normals turned to the front side of the face, like the texel's two sides
    g_n0 = dot(v_normal[0], fn) < 0.0 ? -v_normal[0] : v_normal[0];
    g_n1 = dot(v_normal[1], fn) < 0.0 ? -v_normal[1] : v_normal[1];
    g_n2 = dot(v_normal[2], fn) < 0.0 ? -v_normal[2] : v_normal[2];
    g_q0 = q[0]; g_q1 = q[1]; g_q2 = q[2];
    g_bounds = vec4(min(min(q[0], q[1]), q[2]) - 0.5, max(max(q[0], q[1]), q[2]) + 0.5);
    g_area_ratio = length(cross(v_position[1] - v_position[0], v_position[2] - v_position[0])) / abs(area2);
    g_triangle = t;
    // grown triangle: vertex k where the offset lines of its two edges (k-1 and k) meet
    vec2 poly[8], clipped[8];
    int n = 3;
    bool spiky = false;
    for (int k = 0; k < 3; ++k) {
        int j = (k + 2) % 3;
        float det = cross2(m[j], m[k]);
        poly[k] = vec2(c[j] * m[k].y - c[k] * m[j].y, m[j].x * c[k] - m[k].x * c[j]) / det;
        spiky = spiky || !(abs(det) > 1e-6 * length(m[j]) * length(m[k])) || !(length(poly[k] - q[k]) < 1e4);
    }
    vec2 lo = g_bounds.xy, hi = g_bounds.zw;
    if (spiky) {   // near-parallel edges: the box alone (the fragment shader clips exactly anyway)
        poly[0] = lo; poly[1] = vec2(hi.x, lo.y); poly[2] = hi; poly[3] = vec2(lo.x, hi.y);
        n = 4;
    } else {       // acute corners reach far: keep the part inside the box grown by half a texel
        for (int side = 0; side < 4 && n > 0; ++side) {
            int axis = side & 1;
            float sgn = side < 2 ? 1.0 : -1.0;          // x >= lo, y >= lo, x <= hi, y <= hi
            float bound = side < 2 ? lo[axis] : hi[axis];
            int m2 = 0;
            for (int i = 0; i < n; ++i) {
                vec2 cur = poly[i], prev = poly[(i + n - 1) % n];
                float dc = sgn * (cur[axis] - bound), dp = sgn * (prev[axis] - bound);
                if ((dc >= 0.0) != (dp >= 0.0)) clipped[m2++] = prev + (cur - prev) * (dp / (dp - dc));
                if (dc >= 0.0) clipped[m2++] = cur;
            }
            n = m2;
            for (int i = 0; i < n; ++i) poly[i] = clipped[i];
        }
    }
    // convex polygon as a strip: v0, v1, v(n-1), v2, v(n-2), ...
    for (int s = 0; s < n; ++s) {
        int k = (s & 1) == 1 ? (s + 1) / 2 : (n - s / 2) % n;
        gl_PrimitiveID = t;
        gl_Position = vec4(poly[k] / u_lightmap_size * 2.0 - 1.0, 0.0, 1.0);
        EmitVertex();
    }
    EndPrimitive();
}
#endif

#if defined FRAGMENT_SHADER
flat in vec3 g_p0, g_p1, g_p2;
flat in vec3 g_n0, g_n1, g_n2;
flat in vec2 g_q0, g_q1, g_q2;
flat in vec4 g_bounds;
flat in float g_area_ratio;
flat in int g_triangle;
layout(location = 0) out vec4 out_position;
layout(location = 1) out vec4 out_normal;
layout(location = 2) out vec4 out_face_normal;
layout(location = 3) out vec4 out_albedo;

void main() {
    vec2 x = gl_FragCoord.xy;
    if (any(lessThan(x, g_bounds.xy)) || any(greaterThan(x, g_bounds.zw))) discard;
    // triangle relative to the texel centre, counter-clockwise
    vec2 tri[3] = vec2[3](g_q0 - x, g_q1 - x, g_q2 - x);
    if (cross2(tri[1] - tri[0], tri[2] - tri[0]) < 0.0) { vec2 s = tri[1]; tri[1] = tri[2]; tri[2] = s; }
    vec2 poly[8], clipped[8];
    poly[0] = vec2(-0.5, -0.5); poly[1] = vec2(0.5, -0.5); poly[2] = vec2(0.5, 0.5); poly[3] = vec2(-0.5, 0.5);
    int n = 4;
    for (int e = 0; e < 3 && n > 0; ++e) {
        vec2 a = tri[e], ab = tri[(e + 1) % 3] - tri[e];
        int m = 0;
        for (int i = 0; i < n; ++i) {
            vec2 cur = poly[i], prev = poly[(i + n - 1) % n];
            float dc = cross2(ab, cur - a), dp = cross2(ab, prev - a);
            if ((dc >= 0.0) != (dp >= 0.0)) clipped[m++] = prev + (cur - prev) * (dp / (dp - dc));
            if (dc >= 0.0) clipped[m++] = cur;
        }
        n = m;
        for (int i = 0; i < n; ++i) poly[i] = clipped[i];
    }
    float area2 = 0.0;
    vec2 piece_centre = vec2(0.0);
    for (int i = 0; i < n; ++i) {
        vec2 a = poly[i], b = poly[(i + 1) % n];
        float w = cross2(a, b);
        area2 += w;
        piece_centre += (a + b) * w;
    }
    if (!(area2 > 0.0)) discard;   // the texel only touches the triangle
    piece_centre = piece_centre / (3.0 * area2) + x;
    float area = 0.5 * area2 * g_area_ratio;
    // barycentrics of the piece_centre (inside the triangle: no extrapolation)
    vec2 e1 = g_q1 - g_q0, e2 = g_q2 - g_q0, d = piece_centre - g_q0;
    float den = cross2(e1, e2);
    float b1 = cross2(d, e2) / den, b2 = cross2(e1, d) / den;
    vec3 b = clamp(vec3(1.0 - b1 - b2, b1, b2), 0.0, 1.0);
    b /= b.x + b.y + b.z;
    vec3 p = b.x * g_p0 + b.y * g_p1 + b.z * g_p2;
    vec3 ns = b.x * g_n0 + b.y * g_n1 + b.z * g_n2;
    vec3 fn = chart_triangles[g_triangle].face_normal.xyz;
    float len = length(ns);
    ns = len > 0.0 ? ns / len : fn;
    out_position = vec4(p * area, area);
    out_normal = vec4(ns * area, 0.0);
    out_face_normal = vec4(fn * area, 0.0);
    out_albedo = vec4(triangle_albedo[g_triangle].rgb * area, 0.0);
}
#endif
