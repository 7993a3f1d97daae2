"""Measurements about FLC's approximations and noise (not used when rendering).

`count_vpls_reaching` (geometry only, numpy): Alg. 1 run on the scene's triangles (divergent
ones cut into the m^2 equal pieces the divergent pass makes regular), and per receiver point
the number of level-k VPLs whose f^k is non-zero there: the count that eq. 1 and Fig. 10 say
grows with N_avg (methods/flc/levels.py, correction 3).

Both work on the exact many-lights sum (eq. 4 with eq. 6's lobe, one VPL per triangle at its
centroid, shadowed direct radiosity from `manylights`' own compute pass, its record layout), split per pair
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
bias (see methods/flc/method.py and NOTES.md).
"""
from __future__ import annotations

import numpy as np

from bench.analysis import metrics
from bench.gl import Frame, GpuScene, SharedPasses, StageProfiler, check_gl
from bench.model.scene import Scene, compute_facts
from bench.protocol.method import resolve_params
from bench.run.harness import run_method
from methods.flc.levels import FlcLevels
from methods.flc.method import ForwardLightCuts, lit_area_for, median_view_distance, near_radius
from methods.manylights.method import ManyLights


def _exact_pairs(ctx, scene, camera: str, width: int, height: int, eps_rel: float, chunk: int):
    """(facts, areas, chunks, median view distance) for the lit centroid VPLs of `manylights`' compute pass: the scene
    facts, the VPLs' triangle areas, and an iterator over pixel chunks of (contrib (pixels, vpls),
    summed over rgb with rho_x / pi; d (pixels, vpls))."""
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
        vpl = np.frombuffer(ml.vpls.read(), dtype=np.float32).reshape(-1, 5, 4)[: gpu.triangle_count]
        g = passes.gbuffer.read()
        seen = median_view_distance(gpu, view) or 0.0
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
    ns = vpl[:, 4, :3].astype(np.float64)   # the side of the shading normal picks the radiosity
    lit = ((front + back).sum(1) > 0) & (area > 0)
    y, area, n, ns, front, back = y[lit], area[lit], n[lit], ns[lit], front[lit], back[lit]
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
            radiosity = np.where(((ns[None] * w).sum(-1) < 0)[..., None], front[None], back[None])
            contrib = (radiosity * (1.5 / np.pi * c * c * cos_x / np.maximum(eps, dist) ** 2 * area[None])[..., None])
            contrib = (contrib * rho[s:s + chunk, None] / np.pi).sum(-1)
            with np.errstate(divide="ignore", invalid="ignore"):
                d = np.where(c > 0, dist / c, np.inf)
            yield contrib, d

    return facts, area, chunks(), seen


def _levels(facts, flc_params: dict | None, scene, seen: float | None = None) -> tuple[FlcLevels, dict]:
    """FLC's levels for `flc_params` as `prepare` makes them; `seen` is the median view distance
    (dnear_rule "view"; None when there is no view)."""
    p = resolve_params(ForwardLightCuts, flc_params)
    if p["dnear_rule"] == "view" and seen is None:
        raise ValueError("flc analysis: dnear_rule 'view' needs a view (use 'lit' or 'scene' here)")
    lit = lit_area_for(scene, facts, p["dnear_factor"])
    radius = near_radius(facts, p["dnear_rule"], p["dnear_factor"], lit, seen)
    return FlcLevels(facts.scene_radius, float(p["n_avg"]), p["mu"], p["levels"], p["dnear_factor"],
                     last_level_unbounded=bool(p["last_level_unbounded"]), reach=p["reach"],
                     scene_area=lit, near_radius=radius), p


def _regular_pieces(scene, max_area: float):
    """(centroids, unit normals, areas) of the scene's triangles, each cut into m^2 equal pieces
    with m = ceil(sqrt(A / max_area)) (every piece regular)."""
    tri = scene.vertices[scene.faces].astype(np.float64)          # (T, 3, 3)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    keep = area > 0
    tri, area = tri[keep], area[keep]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    m_all = np.maximum(1, np.ceil(np.sqrt(area / max_area))).astype(int)
    cents, norms, areas = [], [], []
    for m in np.unique(m_all):
        sel = m_all == m
        a, e1, e2 = tri[sel, 0], tri[sel, 1] - tri[sel, 0], tri[sel, 2] - tri[sel, 0]
        # barycentric centroids of the m^2 sub-triangles of the regular subdivision
        bc = []
        for i in range(m):
            for j in range(m - i):
                bc.append(((i + 1 / 3) / m, (j + 1 / 3) / m))
                if j < m - i - 1:
                    bc.append(((i + 2 / 3) / m, (j + 2 / 3) / m))
        bc = np.asarray(bc)                                        # (m^2, 2)
        c = a[:, None] + bc[None, :, :1] * e1[:, None] + bc[None, :, 1:] * e2[:, None]
        cents.append(c.reshape(-1, 3))
        norms.append(np.repeat(normal[sel], m * m, axis=0))
        areas.append(np.repeat(area[sel] / (m * m), m * m))
    return np.concatenate(cents), np.concatenate(norms), np.concatenate(areas)


def _may_be_lit(tri: np.ndarray, lights) -> np.ndarray:
    """Per triangle (T, 3, 3): can a light reach it (the divergent pass's conservative test,
    `flc_patch_may_be_lit`: only spot lights' cones, against the bounding sphere)."""
    if any(light.kind != "spot" for light in lights):
        return np.ones(len(tri), dtype=bool)
    centre = tri.mean(axis=1)
    r = np.linalg.norm(tri - centre[:, None], axis=2).max(axis=1) * (1 + 1e-3) + 1e-6
    out = np.zeros(len(tri), dtype=bool)
    for light in lights:
        v = centre - light.position
        dist = np.linalg.norm(v, axis=1)
        cos_phi = np.clip((v @ light.direction) / np.maximum(dist, 1e-300), -1.0, 1.0)
        alpha = np.arcsin(np.clip(r / np.maximum(dist, 1e-300), 0.0, 1.0))
        out |= (dist <= r) | (np.arccos(cos_phi) - alpha < np.radians(light.cutoff_angle_deg) + 1e-3)
    return out


def refined_scene(scene, max_edge: float):
    """The scene with its triangles of area > max_edge^2 / 2 that a light can reach cut (4-way,
    recursively) until their edges are <= max_edge, for a `manylights` reference of a scene with
    huge triangles (big_floor: one VPL per triangle). Pieces no light reaches (outside every
    spot's cone) stay whole: their VPLs carry no power whatever their size."""
    big = scene.areas() > 0.5 * max_edge ** 2
    tri = scene.vertices[scene.faces[big]].astype(np.float64)
    parent = np.nonzero(big)[0]
    done_tri, done_parent = [], []
    while len(tri):
        edge = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
        split = (edge > max_edge) & _may_be_lit(tri, scene.lights)
        done_tri.append(tri[~split])
        done_parent.append(parent[~split])
        t, parent = tri[split], parent[split]
        a, b, c = t[:, 0], t[:, 1], t[:, 2]
        ab, bc, ca = 0.5 * (a + b), 0.5 * (b + c), 0.5 * (c + a)
        tri = np.concatenate([np.stack(q, axis=1) for q in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
        parent = np.tile(parent, 4)
    pieces, owner = np.concatenate(done_tri), np.concatenate(done_parent)
    n = len(scene.vertices)
    faces = (np.arange(3 * len(pieces)) + n).reshape(-1, 3)
    return Scene.build(scene.name + "_fine", np.concatenate([scene.vertices, pieces.reshape(-1, 3)]),
                       np.concatenate([scene.faces[~big], faces]),
                       np.concatenate([scene.albedo[~big], scene.albedo[owner]]), scene.lights, scene.cameras)


def count_vpls_reaching(scene, flc_params: dict | None = None, receivers: int = 256, seed: int = 0) -> dict:
    """Alg. 1 on the scene's (regular pieces of) triangles with FLC's parameters `flc_params`
    (defaults otherwise), one draw; `receivers` random points on the surfaces (normal towards
    the emitter, i.e. the maximum of eq. 12). Returns 'per_level' (mean count of level-k VPLs
    with f^k(d) > 0 at a receiver, k = 0..N), 'total' (their sum) and 'levels'."""
    facts = compute_facts(scene)
    levels, _ = _levels(facts, flc_params, scene)
    rng = np.random.default_rng(seed)
    y, n, area = _regular_pieces(scene, levels.divergent_area)
    level = levels.level_of(rng.random(len(area)), area)
    kept = level >= 0
    y, n, level = y[kept], n[kept], level[kept]
    tri = scene.vertices[scene.faces].astype(np.float64)
    tri_area = scene.areas()
    pick = rng.choice(len(tri_area), size=receivers, p=tri_area / tri_area.sum())
    r1, r2 = rng.random(receivers), rng.random(receivers)
    su = np.sqrt(r1)
    x = (1 - su)[:, None] * tri[pick, 0] + (su * (1 - r2))[:, None] * tri[pick, 1] + (su * r2)[:, None] * tri[pick, 2]
    counts = np.zeros(levels.levels + 1)
    for s in range(0, receivers, 64):
        v = x[s:s + 64, None] - y[None]                            # y -> x
        dist = np.linalg.norm(v, axis=-1)
        c = np.abs((v * n[None]).sum(-1)) / np.maximum(dist, 1e-300)
        with np.errstate(divide="ignore", invalid="ignore"):
            d = np.where(c > 0, dist / c, np.inf)
        f = levels.partition(d)                                    # (N+1, r, vpls)
        for k in range(levels.levels + 1):
            counts[k] += ((f[k] > 0) & (level == k)[None]).sum()
    counts /= receivers
    return {"per_level": counts, "total": float(counts.sum()), "levels": int(levels.levels)}


def energy_beyond_support(ctx, scene, camera: str, width: int, height: int, flc_params: dict | None = None,
                          eps_rel: float = 1e-4, chunk: int = 256) -> dict:
    """{'share_beyond_DN', 'D_N_m', 'total'}: share of the summed indirect radiance (all pixels)
    coming from pairs with d > D_N for FLC's parameters `flc_params` (defaults otherwise)."""
    facts, _area, chunks, seen = _exact_pairs(ctx, scene, camera, width, height, eps_rel, chunk)
    levels, _ = _levels(facts, flc_params, scene, seen)
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
    facts, area, chunks, seen = _exact_pairs(ctx, scene, camera, width, height, eps_rel, chunk)
    levels, p = _levels(facts, flc_params, scene, seen)
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


def single_frame_study(ctx, scene, camera: str, width: int, height: int, seeds=range(8),
                       flc_params: dict | None = None, jitter_frames: int = 16, reference_seed: int = 99,
                       reference_scene=None, reference_image=None, mitsuba=None) -> dict:
    """One FLC frame per seed against `manylights` with the FLC lobe and `jitter_frames` jittered
    VPL positions (the sum FLC is unbiased for; see methods/flc/method.py), rendered on `reference_scene` if
    given (the same surfaces finer cut: `manylights` has one VPL per triangle, so a scene of huge
    triangles needs many jitter frames), or `reference_image` (H x W x 3) when given (a reference
    already rendered: returned as 'reference'). Returns per-seed 'ratio' (image
    mean of FLC's indirect / the reference's), 'relmse' (against the reference: mean squared error
    over mean squared reference), 'relmse_pixel' (the report's per-pixel relMSE, `bench.analysis.metrics`)
    and 'relmse_pixel_black' (what an image without indirect light, `direct`, scores), 'splat_ms'
    (regular + divergent + upscale_blur GPU time), the mean ratio 'ratio_mean', the relative
    spread 'ratio_spread' (std / mean over the seeds) and 'reference_mean'. With `jitter_frames`
    0 and no `reference_image` there is no `manylights` reference (only 'splat_ms' and what follows).
    `mitsuba` (a `reference.api.get_reference` result: .mean, .coverage) adds per-seed
    'mitsuba_relmse' (the report's relmse.indirect) and 'mitsuba_relmse_direct' (`direct`'s)."""
    facts = compute_facts(scene)
    ref_scene = scene if reference_scene is None else reference_scene
    if reference_image is not None:
        ref = np.asarray(reference_image, dtype=np.float64)
        if ref.shape != (height, width, 3):
            raise ValueError(f"flc study: reference_image has shape {ref.shape}, expected {(height, width, 3)}")
    elif jitter_frames > 0:
        ref = run_method(ctx, ManyLights, ref_scene, camera, width, height,
                         {"emission": "flc", "jitter_frames": jitter_frames}, seed=reference_seed, frames=1,
                         facts=compute_facts(ref_scene)).indirect.astype(np.float64)
    else:
        ref = None
    ratio, relmse, relmse_pixel, splat, against_mitsuba = [], [], [], [], []
    for s in seeds:
        r = run_method(ctx, ForwardLightCuts, scene, camera, width, height, flc_params, seed=s, frames=1, facts=facts)
        img = r.indirect.astype(np.float64)
        splat.append(sum(float(np.median(r.stage_ms[k])) for k in ("regular", "divergent", "upscale_blur")
                         if k in r.stage_ms))
        if mitsuba is not None:
            against_mitsuba.append(metrics.relmse(img, mitsuba.mean, mitsuba.coverage))
        if ref is not None:
            ratio.append(img.mean() / ref.mean())
            relmse.append(float(((img - ref) ** 2).mean() / (ref ** 2).mean()))
            relmse_pixel.append(metrics.relmse(img, ref))
    out = {"splat_ms": np.asarray(splat)}
    if mitsuba is not None:
        out.update(mitsuba_relmse=np.asarray(against_mitsuba),
                   mitsuba_relmse_direct=metrics.relmse(np.zeros_like(mitsuba.mean), mitsuba.mean, mitsuba.coverage))
    if ref is not None:
        ratio = np.asarray(ratio)
        out.update(ratio=ratio, relmse=np.asarray(relmse), relmse_pixel=np.asarray(relmse_pixel),
                   relmse_pixel_black=metrics.relmse(np.zeros_like(ref), ref), ratio_mean=float(ratio.mean()),
                   ratio_spread=float(ratio.std(ddof=1) / ratio.mean()) if len(ratio) > 1 else 0.0,
                   reference_mean=float(ref.mean()), reference=ref)
    return out
