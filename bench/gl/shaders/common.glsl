// Small shared helpers: hashing to uniform floats, full-screen triangle, GBuffer access.
#ifndef COMMON_GLSL
#define COMMON_GLSL

// PCG-style integer hash (Jarzynski & Olano 2020): uint32 -> well-mixed uint32.
uint hash_u32(uint v) {
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// uint32 -> float in [0, 1) using the top 24 bits (exact in float32).
float u32_to_unit(uint v) { return float(v >> 8u) * (1.0 / 16777216.0); }

// Orthonormal t, b completing the unit normal n (Duff et al. 2017, branchless).
void orthonormal_basis(vec3 n, out vec3 t, out vec3 b) {
    float s = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (s + n.z);
    float c = n.x * n.y * a;
    t = vec3(1.0 + s * n.x * n.x * a, s * c, -s * n.x);
    b = vec3(c, s + n.y * n.y * a, -n.y);
}

layout(std430, binding = BINDING_TRIANGLE_ALBEDO) readonly buffer TriangleAlbedo { vec4 triangle_albedo[]; };

#endif
