"""The level and partition maths of Forward Light Cuts (Laurent et al. 2016), in numpy.

This module is the single source of the constants the shaders use: `FlcLevels.defines()`
injects them into GLSL as `#define`s, and `partition()` / `level_of()` mirror the GLSL
functions of `shaders/partition.glsl` on the same constants (the tests check the maths here).

Paper notation (Sec. 4-5):

    S_0 = 4 pi D_near^2 / N_avg                    eq. 1, D_near = dnear_factor * R_scene
    S_k = S_0 mu^k,  k = 0..N                      eq. 17
    S_bar_k = 1 / sum_{j<=k} 1 / S_j               Alg. 1
    D_k: the influence distance of level k         eq. 18 (see "Influence distances")

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

(f^N has no falling ramp since D_{N+1} = D_N.) Far field: by default (`last_level_unbounded`)
f^N = 1 beyond D_N, so the f^k sum to 1 for every d > 0 and the estimator is unbiased (eq. 8-11)
for the many-lights sum of eq. 4. The bounded variant (the paper's eq. 16 literally: every f^k
is 0 beyond D_N) cuts far and grazing bounces (d > D_N).

Correction 3, influence distances (eq. 18). The paper prints D_k = sqrt(S_0 mu^k) = sqrt(S_k).
Its stated intent is otherwise. Eq. 1 is "a heuristic aiming at lighting pixels with
approximately N_avg VPLs at least D_near far from them": the surface within distance D of a
receiver is modelled as 4 pi D^2 (a receiver inside a closed environment), and level 0 keeps
one VPL per S_0 of surface, so 4 pi D_near^2 / S_0 = N_avg VPLs of level 0 lie within D_near.
Fig. 10 calls N_avg "the approximate number of VPLs influencing every pixel", and its times
(1, 3, 7, 14 ms for N_avg = 64 .. 512) grow in proportion to N_avg. With the same model a
level-k VPL reaches a receiver when it lies within D_k, and level k has one VPL per S_k, so
about 4 pi D_k^2 / S_k level-k VPLs reach it. Asking for N_avg from every level (the same
count per level, the hierarchical cut the paper mimics) gives

    4 pi D_k^2 / S_k = N_avg   =>   D_k = sqrt(N_avg S_k / (4 pi)) = D_near mu^(k/2)

(`reach="eq1_intent"`, the default): D_0 = D_near, as eq. 1 says, and the reach of every level
grows with N_avg's count, not against it. The printed D_k = sqrt(S_k) (`reach="eq18_printed"`)
gives every level 4 pi VPLs (times the hat's shape factor) whatever N_avg is, and a reach
D_N = D_near sqrt(4 pi / N_avg) mu^(N/2) that shrinks as N_avg grows (at mu 4, N 5: 2.84,
1.42, 0.71 R_scene for N_avg 64, 256, 1024). `expected_vpls_reaching` gives the count per level
under the model; `studies.flc_analysis.count_vpls_reaching` measures it on a scene.

Level set (`levels = -1`, the default). A level-k VPL stands for S_k of surface, so when S_k
is several m^2 a frame rests on a handful of powerful VPLs (the paper's "spikes"); and with the
last level unbounded every top-level VPL lights every pixel, so the top level gives each pixel
A_lit / S_N lit VPLs whatever the reach (each costs a full-screen splat; unlit ones splat
nothing). N is the fewest levels whose top level holds at most TOP_LEVEL_BUDGET (32) N_avg lit
VPLs, and never more than the reach needs (D_N >= R_scene; beyond, more levels would only move
the far field onto fewer VPLs):

    N = min( ceil(log_mu (R_scene / D_0)^2),  ceil(log_mu (A_lit / (32 N_avg S_0))) ),  N >= 0

(`scene_area` is A_lit, the area a light's emission reaches, `lit_area`: A_scene unless every
light is a spot. A_lit / (N_avg S_0) = A_lit / (4 pi D_near^2), independent of N_avg for
eq1_intent.) At the defaults (mu 4, D_near 0.2 R) N = 0 on the benchmark's default scenes,
sibenik and conference (A_lit <= 32 x 4 pi D_near^2) and 1 on sponza; the hierarchy pays off
on scenes whose lit area is large against D_near^2.

D_near (`near_radius`): D_near = dnear_factor * R with R = R_scene (the paper) or the smaller
R that method.py's D_near rule gives (4 pi D_near^2 <= A_lit by default).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.gl.shaders import glsl_literal

MAX_LEVELS = 16  # N <= 15: N + 1 levels
REACHES = ("eq1_intent", "eq18_printed")
TOP_LEVEL_BUDGET = 32   # level set: the top level holds at most this many times N_avg VPLs


def _reach_scale(reach: str, n_avg: float) -> float:
    """D_k = scale * sqrt(S_k): sqrt(N_avg / (4 pi)) for eq1_intent, 1 for eq18_printed."""
    if reach == "eq1_intent":
        return float(np.sqrt(n_avg / (4.0 * np.pi)))
    if reach == "eq18_printed":
        return 1.0
    raise ValueError(f"flc: reach must be one of {list(REACHES)}, got {reach!r}")


def auto_levels(scene_radius: float, n_avg: float, mu: float, dnear_factor: float, reach: str = "eq1_intent",
                scene_area: float | None = None, near_radius: float | None = None) -> int:
    """The default level set (module docstring, "Level set"): the smallest N with D_N >= R_scene,
    lowered until the top level holds at most TOP_LEVEL_BUDGET N_avg VPLs on `scene_area` (A_lit).
    D_near = dnear_factor * near_radius (R_scene when None)."""
    radius = scene_radius if near_radius is None else near_radius
    s0 = 4.0 * np.pi * (dnear_factor * radius) ** 2 / n_avg
    d0 = _reach_scale(reach, n_avg) * np.sqrt(s0)
    n = 0 if d0 >= scene_radius else int(np.ceil(2.0 * np.log(scene_radius / d0) / np.log(mu) - 1e-9))
    if scene_area is not None and scene_area > 0:
        # fewest levels whose top level holds at most TOP_LEVEL_BUDGET N_avg VPLs in the scene
        excess = scene_area / (TOP_LEVEL_BUDGET * n_avg * s0)
        n = min(n, int(np.ceil(np.log(excess) / np.log(mu) - 1e-9)) if excess > 1.0 else 0)
    return int(min(max(n, 0), MAX_LEVELS - 1))


@dataclass(frozen=True)
class FlcLevels:
    scene_radius: float
    n_avg: float
    mu: float
    levels: int            # N: levels 0..N (-1: auto_levels)
    dnear_factor: float = 0.2
    last_level_unbounded: bool = True
    reach: str = "eq1_intent"
    scene_area: float | None = None   # lit area A_lit (method.py): bounds the automatic top level
    near_radius: float | None = None  # R of D_near = dnear_factor R (R_scene when None; see method.py)

    def __post_init__(self):
        if not (self.scene_radius > 0 and np.isfinite(self.scene_radius)):
            raise ValueError(f"flc: scene radius must be > 0, got {self.scene_radius}")
        if not self.mu > 1.0:
            raise ValueError(f"flc: mu must be > 1 (levels of increasing size), got {self.mu}")
        _reach_scale(self.reach, self.n_avg)
        if self.near_radius is not None and not (self.near_radius > 0 and np.isfinite(self.near_radius)):
            raise ValueError(f"flc: near radius (R of D_near) must be > 0, got {self.near_radius}")
        if self.levels == -1:
            object.__setattr__(self, "levels", auto_levels(self.scene_radius, self.n_avg, self.mu,
                                                           self.dnear_factor, self.reach, self.scene_area,
                                                           self.near_radius))
        if not 0 <= self.levels < MAX_LEVELS:
            raise ValueError(f"flc: levels N must be -1 (auto) or in [0, {MAX_LEVELS - 1}], got {self.levels}")

    # ------------------------------------------------------------------ constants
    @property
    def d_near(self) -> float:
        """D_near = dnear_factor * R, R = near_radius (method.py's D_near rule) or R_scene."""
        return self.dnear_factor * (self.scene_radius if self.near_radius is None else self.near_radius)

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
        """Influence distances D_0..D_N and D_{N+1} = D_N (N + 2 values): D_near mu^(k/2) for
        eq1_intent, sqrt(S_k) for eq18_printed (module docstring, correction 3)."""
        d = _reach_scale(self.reach, self.n_avg) * np.sqrt(self.s)
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
        Interior levels get the same count, proportional to D_k^2 / S_k: N_avg times a shape
        factor of the hats for eq1_intent, 4 pi times it for eq18_printed (whatever N_avg);
        level 0 more (f^0 = 1 down to d = 0), the last level less when bounded (no falling
        ramp) and infinitely many when unbounded (f^N = 1 everywhere beyond D_N)."""
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
    """m such that each of the m^2 equal sub-patches of a triangle is made regular by the
    tessellation level whose largest piece is the fraction `fmax_top` of the patch."""
    area = np.asarray(area, float)
    return np.maximum(1, np.ceil(np.sqrt(area * fmax_top / target_area))).astype(np.int64)


def lit_area(scene, piece_area: float, max_split: int = 64) -> float:
    """Area of the surface a light's emission reaches, occlusion ignored (m^2): every surface
    when the scene has a point or directional light (two-sided surfaces face any light not seen
    edge-on), else the part inside a spot light's cutoff cone, measured on the triangles cut into
    m^2 equal pieces of at most `piece_area` (m <= max_split), a piece counting when its centroid
    is inside a cone."""
    if not piece_area > 0:
        raise ValueError(f"flc: lit_area piece_area must be > 0, got {piece_area}")
    area = scene.areas().astype(np.float64)
    if any(light.kind != "spot" for light in scene.lights):
        return float(area.sum())
    tri = scene.vertices[scene.faces].astype(np.float64)
    m_all = np.clip(np.ceil(np.sqrt(area / piece_area)), 1, max_split).astype(np.int64)
    lit = 0.0
    for m in np.unique(m_all):
        sel = np.nonzero(m_all == m)[0]
        bc = []   # barycentric (beta, gamma) of the m^2 sub-triangle centroids
        for i in range(m):
            for j in range(m - i):
                bc.append(((i + 1 / 3) / m, (j + 1 / 3) / m))
                if j < m - i - 1:
                    bc.append(((i + 2 / 3) / m, (j + 2 / 3) / m))
        bc = np.asarray(bc)
        for start in range(0, len(sel), max(1, 2_000_000 // len(bc))):
            part = sel[start:start + max(1, 2_000_000 // len(bc))]
            a, e1, e2 = tri[part, 0], tri[part, 1] - tri[part, 0], tri[part, 2] - tri[part, 0]
            c = a[:, None] + bc[None, :, :1] * e1[:, None] + bc[None, :, 1:] * e2[:, None]   # (t, m^2, 3)
            inside = np.zeros(c.shape[:2], dtype=bool)
            for light in scene.lights:
                v = c - light.position
                dist = np.linalg.norm(v, axis=-1)
                cos_theta = (v @ light.direction) / np.maximum(dist, 1e-300)
                inside |= cos_theta > np.cos(np.radians(light.cutoff_angle_deg))
            lit += float((inside.sum(1) * area[part] / len(bc)).sum())
    return lit
