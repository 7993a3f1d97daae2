"""Measurements about FLC's approximations and noise (not used when rendering).

Both work on the exact many-lights sum (eq. 4 with eq. 6's lobe, one VPL per triangle at its
centroid, shadowed direct radiosity from `manylights`' own compute pass), split per pair
(VPL t, pixel x) by d = |x - y| / |<n_t, (x - y)/|x - y|>|:

`energy_beyond_support`: the share of the sum carried by pairs with d > D_N: the energy FLC's
bounded partition of unity cuts (every f^k is 0 there), and that `last_level_unbounded` keeps.

`level_statistics`: the share of the sum each level k carries (through f^k), the expected
number of lit level-k VPLs per sub-frame, and the predicted relative standard deviation of the
image mean. A triangle t lands in level k with probability A_t / S_k (at most one level) and
then adds S_k / A_t times its exact share C_tk = sum_x f^k(d) H(t, x) A_t; so the variance of
the image sum is

    Var = sum_t [ sum_k (S_k / A_t) C_tk^2 - (sum_k C_tk)^2 / P_t ],

with P_t = ceil(A_t / S_bar_N) pieces for a divergent triangle (1 if regular; equal pieces
assumed, each drawn independently). VPL jitter and interleaved sampling add a little more. When the lit surface holds
only a few top-level VPLs (a spot light on a small patch, receivers far from it), this is large
and a render's error is spread over much of the frame by a few powerful VPLs: noise, not a
bias (see method.py).
"""
from __future__ import annotations

import numpy as np

from bench.gl import Frame, GpuScene, SharedPasses, StageProfiler, check_gl
from bench.method import resolve_params
from bench.scene import compute_facts

from .levels import FlcLevels


def _exact_pairs(ctx, scene, camera: str, width: int, height: int, eps_rel: float, chunk: int):
    """(facts, areas, chunks) for the lit centroid VPLs of `manylights`' compute pass: the scene
    facts, the VPLs' triangle areas, and an iterator over pixel chunks of (contrib (pixels, vpls),
    summed over rgb with rho_x / pi; d (pixels, vpls))."""
    from methods.manylights.method import ManyLights

    facts = compute_facts(scene)
    gpu = GpuScene(ctx, scene, facts=facts)
    view = gpu.view(camera, width, height)
    passes = SharedPasses(gpu, view, ManyLights.needs)
    ml = ManyLights()
    prof = None
    try:
        ml.prepare(gpu, scene, facts, resolve_params(ManyLights, {"emission": "flc"}), view)
        prof = StageProfiler(ctx)
        passes.render(prof)
        ml.render(Frame(ctx=ctx, gpu=gpu, view=view, passes=passes, index=0, seed=0), prof)
        check_gl(ctx, "flc analysis")
        vpl = np.frombuffer(ml.vpls.read(), dtype=np.float32).reshape(-1, 4, 4)[: gpu.triangle_count]
        g = passes.gbuffer.read()
    finally:
        ml.release()
        passes.release()
        if prof is not None:
            prof.release()
        gpu.release()
    y = vpl[:, 0, :3].astype(np.float64) + gpu.origin
    area = vpl[:, 0, 3].astype(np.float64)
    n = vpl[:, 1, :3].astype(np.float64)
    front, back = vpl[:, 2, :3].astype(np.float64), vpl[:, 3, :3].astype(np.float64)
    lit = ((front + back).sum(1) > 0) & (area > 0)
    y, area, n, front, back = y[lit], area[lit], n[lit], front[lit], back[lit]
    m = g["mask"]
    x, nx, rho = g["position"][m].astype(np.float64), g["normal"][m].astype(np.float64), g["albedo"][m]
    eps = eps_rel * facts.scene_radius

    def chunks():
        for s in range(0, len(x), chunk):
            v = y[None] - x[s:s + chunk, None]
            dist = np.linalg.norm(v, axis=-1)
            w = v / np.maximum(dist, 1e-300)[..., None]
            cos_x = np.maximum((nx[s:s + chunk, None] * w).sum(-1), 0.0)
            cos_y = -(n[None] * w).sum(-1)
            c = np.abs(cos_y)
            radiosity = np.where((cos_y > 0)[..., None], front[None], back[None])
            contrib = (radiosity * (1.5 / np.pi * c * c * cos_x / np.maximum(eps, dist) ** 2 * area[None])[..., None])
            contrib = (contrib * rho[s:s + chunk, None] / np.pi).sum(-1)
            with np.errstate(divide="ignore", invalid="ignore"):
                d = np.where(c > 0, dist / c, np.inf)
            yield contrib, d

    return facts, area, chunks()


def _levels(facts, flc_params: dict | None) -> tuple[FlcLevels, dict]:
    from methods.flc.method import ForwardLightCuts
    p = resolve_params(ForwardLightCuts, flc_params)
    return FlcLevels(facts.scene_radius, float(p["n_avg"]), p["mu"], p["levels"], p["dnear_factor"],
                     last_level_unbounded=bool(p["last_level_unbounded"])), p


def energy_beyond_support(ctx, scene, camera: str, width: int, height: int, flc_params: dict | None = None,
                          eps_rel: float = 1e-4, chunk: int = 256) -> dict:
    """{'share_beyond_DN', 'D_N_m', 'total'}: share of the summed indirect radiance (all pixels)
    coming from pairs with d > D_N for FLC's parameters `flc_params` (defaults otherwise)."""
    facts, _area, chunks = _exact_pairs(ctx, scene, camera, width, height, eps_rel, chunk)
    levels, _ = _levels(facts, flc_params)
    d_n = float(levels.d[levels.levels])
    total = beyond = 0.0
    for contrib, d in chunks:
        total += contrib.sum()
        beyond += contrib[d > d_n].sum()
    return {"share_beyond_DN": beyond / total if total > 0 else 0.0, "D_N_m": d_n, "total": total}


def level_statistics(ctx, scene, camera: str, width: int, height: int, flc_params: dict | None = None,
                     eps_rel: float = 1e-4, chunk: int = 256) -> dict:
    """For FLC's parameters `flc_params` (defaults otherwise), per level k = 0..N: 'share' of the
    exact image sum ('total') carried by f^k (they sum to 1 - share beyond D_N, or to 1 when
    unbounded), 'lit_vpls_per_subframe' (expected lit level-k VPLs, sum_t A_t / S_k over lit
    triangles), 'S_m2', 'D_m'; and the relative standard deviation of the image mean that the
    module docstring's variance predicts for one sub-frame ('relative_std_subframe') and for one
    render of `progressive_frames` sub-frames ('relative_std')."""
    facts, area, chunks = _exact_pairs(ctx, scene, camera, width, height, eps_rel, chunk)
    levels, p = _levels(facts, flc_params)
    s = levels.s
    per_tri = np.zeros((levels.levels + 1, len(area)))   # C_tk
    exact = 0.0
    for contrib, d in chunks:
        exact += contrib.sum()
        with np.errstate(invalid="ignore"):
            per_tri += (levels.partition(d) * contrib[None]).sum(1)
    expected = float(per_tri.sum())   # what FLC converges to (= exact when unbounded)
    pieces = np.maximum(1.0, np.ceil(area / levels.divergent_area))
    var = float(np.sum((s[:, None] / area[None]) * per_tri ** 2) - np.sum(per_tri.sum(0) ** 2 / pieces))
    rel = float(np.sqrt(var) / expected) if expected > 0 else 0.0
    return {"share": per_tri.sum(1) / exact if exact > 0 else np.zeros(levels.levels + 1),
            "lit_vpls_per_subframe": area.sum() / s, "S_m2": s, "D_m": levels.d[: levels.levels + 1],
            "relative_std_subframe": rel, "relative_std": rel / np.sqrt(p["progressive_frames"]),
            "total": float(exact)}
