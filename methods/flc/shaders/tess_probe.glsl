// Measures the tessellator once per context: for every uniform level n = 1..TESS_MAX_LEVEL
// (one instance per level), the largest generated sub-triangle's area as a fraction of the
// patch's (atomicMax on the float bits, order-preserving for positive floats) and the sum of
// the fractions in 2^-24 units (a check that the pieces tile the patch).
// Area ratios are affine invariant, so the largest fraction per level holds for any patch:
// the divergent pass picks the smallest level whose largest piece is regular.
#if defined VERTEX_SHADER
out int v_level;
void main() {
    v_level = gl_InstanceID + 1;
    gl_Position = vec4(0.0);
}
#endif

#if defined TESS_CONTROL_SHADER
layout(vertices = 3) out;
in int v_level[];
patch out float tc_level;
void main() {
    if (gl_InvocationID == 0) {
        float n = float(v_level[0]);
        gl_TessLevelOuter[0] = n;
        gl_TessLevelOuter[1] = n;
        gl_TessLevelOuter[2] = n;
        gl_TessLevelInner[0] = n;
        tc_level = n;
    }
}
#endif

#if defined TESS_EVALUATION_SHADER
layout(triangles, equal_spacing, ccw) in;
patch in float tc_level;
out vec3 te_coord;
out float te_level;
void main() {
    te_coord = gl_TessCoord;
    te_level = tc_level;
    gl_Position = vec4(gl_TessCoord, 1.0);
}
#endif

#if defined GEOMETRY_SHADER
layout(triangles) in;
layout(points, max_vertices = 1) out;
layout(std430, binding = BINDING_PROBE) buffer ProbeBlock { uint probe_max[TESS_MAX_LEVEL]; uint probe_sum[TESS_MAX_LEVEL]; };
in vec3 te_coord[];
in float te_level[];
void main() {
    vec2 e1 = te_coord[1].xy - te_coord[0].xy;
    vec2 e2 = te_coord[2].xy - te_coord[0].xy;
    float fraction = abs(e1.x * e2.y - e1.y * e2.x);  // the (u, v) domain triangle has area 1/2
    int k = int(te_level[0] + 0.5) - 1;
    atomicMax(probe_max[k], floatBitsToUint(fraction));
    atomicAdd(probe_sum[k], uint(round(fraction * 16777216.0)));
}
#endif
