// Forward Light Cuts level maths (Laurent et al. 2016), mirrored in numpy by levels.py.
// Constants injected from Python (FlcLevels.defines): FLC_N, FLC_UNBOUNDED, FLC_S, FLC_S_BAR,
// FLC_D (N + 2 nodes, D_{N+1} = D_N), FLC_DIVERGENT_AREA (S_bar_N).
#ifndef FLC_PARTITION_GLSL
#define FLC_PARTITION_GLSL

const float flc_s[FLC_N + 1] = FLC_S;
const float flc_s_bar[FLC_N + 1] = FLC_S_BAR;
const float flc_d[FLC_N + 2] = FLC_D;

float unit_from_u32(uint h) { return float(h) * (1.0 / 4294967296.0); }  // [0, 1], exact for small values

// Alg. 1: the first level k with u < A / S_bar_k, -1 if the triangle is discarded.
// P(level k) = A / S_bar_k - A / S_bar_{k-1} = A / S_k (eq. 3 as printed is the cumulative one).
int flc_level(float u, float area) {
    for (int k = 0; k <= FLC_N; ++k) {
        if (u * flc_s_bar[k] < area) return k;
    }
    return -1;
}

// The hat functions f^k(d) (eq. 16 corrected: f^0 = 1 only up to D_0, then falls to 0 at D_1),
// which sum to 1 on ]0, D_N]; f^N = 1 beyond D_N when FLC_UNBOUNDED.
float flc_partition(int k, float d) {
    if (k == 0 && d > 0.0 && d <= flc_d[0]) return 1.0;
    if (k > 0 && d > flc_d[k - 1] && d <= flc_d[k]) return (d - flc_d[k - 1]) / (flc_d[k] - flc_d[k - 1]);
    if (k < FLC_N && d > flc_d[k] && d <= flc_d[k + 1]) return (flc_d[k + 1] - d) / (flc_d[k + 1] - flc_d[k]);
#if FLC_UNBOUNDED
    if (k == FLC_N && d > flc_d[FLC_N]) return 1.0;
#endif
    return 0.0;
}

// d beyond which f^k vanishes (negative: unbounded).
float flc_support(int k) {
#if FLC_UNBOUNDED
    if (k == FLC_N) return -1.0;
#endif
    return flc_d[min(k + 1, FLC_N)];
}

#endif
