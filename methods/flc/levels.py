"""The level and partition maths of Forward Light Cuts (Laurent et al. 2016), in numpy.

This module is the single source of the constants the shaders use: `FlcLevels.defines()`
injects them into GLSL as `#define`s, and `partition()` / `level_of()` mirror the GLSL
functions of `shaders/partition.glsl` on the same constants (the tests check the maths here).

Paper notation (Sec. 4-5):

    S_0 = 4 pi D_near^2 / N_avg                    eq. 1, D_near = dnear_factor * R_scene
    S_k = S_0 mu^k,  k = 0..N                      eq. 17
    S_bar_k = 1 / sum_{j<=k} 1 / S_j               Alg. 1
    D_k = sqrt(S_0 mu^k),  D_{N+1} = D_N           eq. 18

Alg. 1 puts a triangle of area A in the first level k with u < A / S_bar_k (u uniform in
[0, 1)), and discards it when there is none. The probability of level k is therefore

    P(t in L^k) = A / S_bar_k - A / S_bar_{k-1} = A / S_k       (1 / S_bar_{-1} = 0)

Correction 1 (eq. 3): the paper prints P(t in L^k) = A / S_bar_k, which is the cumulative
probability of levels 0..k. With F^k = S_k f^k (eq. 10) it is A / S_k that turns eq. 9,
sum_k F^k P(t in L^k) = A, into the partition of unity sum_k f^k = 1 (eq. 11).

Correction 2 (eq. 16): as printed, f^0 = 1 on ]0, D_1], which overlaps f^1's rising ramp on
]D_0, D_1]: there f^0 + f^1 = 1 + (d - D_0) / (D_1 - D_0) > 1 and eq. 11 fails. We use hat functions on the nodes
D_0 < D_1 < ... < D_N that do sum to 1 on ]0, D_N]:

    f^0(d) = 1 on ]0, D_0],  (D_1 - d) / (D_1 - D_0) on ]D_0, D_1]
    f^k(d) = (d - D_{k-1}) / (D_k - D_{k-1}) on ]D_{k-1}, D_k],
             (D_{k+1} - d) / (D_{k+1} - D_k) on ]D_k, D_{k+1}]        (0 < k <= N)
    f^k(d) = 0 elsewhere

(f^N has no falling ramp since D_{N+1} = D_N.) Beyond D_N every f^k is 0: contributions from
d > D_N (far or grazing emitters) are cut. `last_level_unbounded` sets f^N = 1 beyond D_N,
which makes the estimator exactly unbiased with respect to the many-lights sum (eq. 8).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.gl.shaders import glsl_literal

MAX_LEVELS = 16  # N <= 15: N + 1 levels


@dataclass(frozen=True)
class FlcLevels:
    scene_radius: float
    n_avg: float
    mu: float
    levels: int            # N: levels 0..N
    dnear_factor: float = 0.2
    last_level_unbounded: bool = False

    def __post_init__(self):
        if not (self.scene_radius > 0 and np.isfinite(self.scene_radius)):
            raise ValueError(f"flc: scene radius must be > 0, got {self.scene_radius}")
        if not self.mu > 1.0:
            raise ValueError(f"flc: mu must be > 1 (levels of increasing size), got {self.mu}")
        if not 0 <= self.levels < MAX_LEVELS:
            raise ValueError(f"flc: levels N must be in [0, {MAX_LEVELS - 1}], got {self.levels}")

    # ------------------------------------------------------------------ constants
    @property
    def d_near(self) -> float:
        return self.dnear_factor * self.scene_radius

    @property
    def s0(self) -> float:
        """Eq. 1: S_0 = 4 pi D_near^2 / N_avg."""
        return 4.0 * np.pi * self.d_near ** 2 / self.n_avg

    @property
    def s(self) -> np.ndarray:
        """Eq. 17: S_k = S_0 mu^k, k = 0..N."""
        return self.s0 * self.mu ** np.arange(self.levels + 1, dtype=np.float64)

    @property
    def s_bar(self) -> np.ndarray:
        """Alg. 1: S_bar_k = 1 / sum_{j<=k} 1/S_j (decreasing in k)."""
        return 1.0 / np.cumsum(1.0 / self.s)

    @property
    def d(self) -> np.ndarray:
        """Eq. 18: D_k = sqrt(S_0 mu^k) for k = 0..N, and D_{N+1} = D_N (N + 2 values)."""
        d = np.sqrt(self.s)
        return np.append(d, d[-1])

    @property
    def divergent_area(self) -> float:
        """A triangle is divergent when its area is greater than S_bar_N."""
        return float(self.s_bar[-1])

    def support_radius(self, k: int) -> float:
        """d beyond which f^k is 0 (infinite for the last level when unbounded)."""
        if k == self.levels and self.last_level_unbounded:
            return np.inf
        return float(self.d[k + 1])

    # ------------------------------------------------------------------ Alg. 1 and eq. 16
    def level_of(self, u, area) -> np.ndarray:
        """Alg. 1: first k with u < A / S_bar_k, or -1 (discarded)."""
        u, area = np.broadcast_arrays(np.asarray(u, float), np.asarray(area, float))
        thresholds = area[..., None] / self.s_bar  # increasing in k
        hit = u[..., None] < thresholds
        return np.where(hit.any(-1), hit.argmax(-1), -1)

    def level_probabilities(self, area) -> np.ndarray:
        """P(t in L^k) = A / S_k for k = 0..N (last axis), for regular triangles (A <= S_bar_N)."""
        area = np.asarray(area, float)
        return area[..., None] / self.s

    def partition(self, dist) -> np.ndarray:
        """f^k(d) for k = 0..N (first axis), the corrected hat functions (module docstring)."""
        d = np.asarray(dist, dtype=np.float64)
        nodes, n = self.d, self.levels
        out = np.zeros((n + 1,) + d.shape)
        for k in range(n + 1):
            f = np.zeros(d.shape)
            if k == 0:
                f = np.where((d > 0) & (d <= nodes[0]), 1.0, f)
            else:
                rise = (d > nodes[k - 1]) & (d <= nodes[k])
                f = np.where(rise, (d - nodes[k - 1]) / (nodes[k] - nodes[k - 1]), f)
            if k < n:
                fall = (d > nodes[k]) & (d <= nodes[k + 1])
                f = np.where(fall, (nodes[k + 1] - d) / (nodes[k + 1] - nodes[k]), f)
            elif self.last_level_unbounded:
                f = np.where(d > nodes[n], 1.0, f)
            out[k] = f
        return out

    def expected_vpls_reaching(self, samples: int = 20000) -> np.ndarray:
        """Expected number of level-k VPLs whose f^k is non-zero at a receiver, weighted by f^k,
        under eq. 1's model of the surroundings (surface area within distance D of the receiver
        grows as 4 pi D^2, every emitter facing it): n_k = (1 / S_k) int f^k(D) d(4 pi D^2).
        Sec. 5 asks for about the same number from every level; with D_k^2 = S_k the interior
        levels get exactly the same, level 0 more (f^0 = 1 down to d = 0: 1.25x at mu = 5 to
        3.5x at mu = 1.4) and the last level less (no falling ramp: 0.2x to 0.45x) unless it is
        unbounded (then infinite)."""
        nodes = self.d
        out = np.empty(self.levels + 1)
        for k in range(self.levels + 1):
            hi = nodes[min(k + 1, self.levels)]
            if k == self.levels and self.last_level_unbounded:
                out[k] = np.inf
                continue
            # midpoint rule on ]0, hi] with the weight 8 pi D dD
            edges = np.linspace(0.0, hi, samples + 1)
            mid = 0.5 * (edges[1:] + edges[:-1])
            f = self.partition(mid)[k]
            out[k] = float(np.sum(f * 8.0 * np.pi * mid) * (hi / samples)) / self.s[k]
        return out

    # ------------------------------------------------------------------ GLSL
    def defines(self) -> dict:
        """The constants as GLSL #defines: FLC_N, FLC_UNBOUNDED, FLC_S[], FLC_S_BAR[], FLC_D[]."""
        def arr(values) -> str:
            return f"float[{len(values)}](" + ", ".join(glsl_literal(float(v)) for v in values) + ")"
        return {"FLC_N": int(self.levels), "FLC_UNBOUNDED": bool(self.last_level_unbounded),
                "FLC_S": arr(self.s), "FLC_S_BAR": arr(self.s_bar), "FLC_D": arr(self.d),
                "FLC_DIVERGENT_AREA": float(self.divergent_area)}


def presplit_count(area, fmax_top: float, target_area: float) -> np.ndarray:
    """m such that each of the m^2 equal sub-patches of a triangle fits the top tessellation level."""
    area = np.asarray(area, float)
    return np.maximum(1, np.ceil(np.sqrt(area * fmax_top / target_area))).astype(np.int64)
