"""Measurements about FLC's approximations (not used when rendering).

`energy_beyond_support`: the share of the exact many-lights sum (eq. 4 with eq. 6's lobe, one
VPL per triangle at its centroid, shadowed direct radiosity from `manylights`' own compute pass)
carried by VPL-receiver pairs with d = |x - y| / |<n_t, (x - y)/|x - y|>| > D_N: the energy FLC's
bounded partition of unity cuts (every f^k is 0 there), and that `last_level_unbounded` keeps.
"""
from __future__ import annotations

import numpy as np

from bench.gl import Frame, GpuScene, SharedPasses, StageProfiler, check_gl
from bench.method import resolve_params
from bench.scene import compute_facts

from .levels import FlcLevels


def energy_beyond_support(ctx, scene, camera: str, width: int, height: int, flc_params: dict | None = None,
                          eps_rel: float = 1e-4, chunk: int = 256) -> dict:
    """{'share_beyond_DN', 'D_N_m', 'total'}: share of the summed indirect radiance (all pixels)
    coming from pairs with d > D_N for FLC's parameters `flc_params` (defaults otherwise)."""
    from methods.flc.method import ForwardLightCuts
    from methods.manylights.method import ManyLights

    p = resolve_params(ForwardLightCuts, flc_params)
    facts = compute_facts(scene)
    levels = FlcLevels(facts.scene_radius, float(p["n_avg"]), p["mu"], p["levels"], p["dnear_factor"])
    d_n = float(levels.d[levels.levels])
    gpu = GpuScene(ctx, scene, facts=facts)
    view = gpu.view(camera, width, height)
    passes = SharedPasses(gpu, view, ManyLights.needs)
    ml = ManyLights()
    try:
        ml.prepare(gpu, scene, facts, resolve_params(ManyLights, {"emission": "flc"}), view)
        prof = StageProfiler(ctx)
        passes.render(prof)
        ml.render(Frame(ctx=ctx, gpu=gpu, view=view, passes=passes, index=0, seed=0), prof)
        check_gl(ctx, "energy_beyond_support")
        vpl = np.frombuffer(ml.vpls.read(), dtype=np.float32).reshape(-1, 4, 4)[: gpu.triangle_count]
        g = passes.gbuffer.read()
    finally:
        ml.release()
        passes.release()
        gpu.release()
    y = vpl[:, 0, :3].astype(np.float64) + gpu.origin
    area = vpl[:, 0, 3].astype(np.float64)
    n = vpl[:, 1, :3].astype(np.float64)
    front, back = vpl[:, 2, :3].astype(np.float64), vpl[:, 3, :3].astype(np.float64)
    lit = (front + back).sum(1) > 0
    y, area, n, front, back = y[lit], area[lit], n[lit], front[lit], back[lit]
    m = g["mask"]
    x, nx, rho = g["position"][m].astype(np.float64), g["normal"][m].astype(np.float64), g["albedo"][m]
    eps = eps_rel * facts.scene_radius
    total = beyond = 0.0
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
            far = dist > d_n * c
        total += contrib.sum()
        beyond += contrib[far].sum()
    return {"share_beyond_DN": beyond / total if total > 0 else 0.0, "D_N_m": d_n, "total": total}
