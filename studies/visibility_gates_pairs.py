"""visibility_gates (issue #23): the gates' visibility rule against a ray-cast truth, per (pixel, VPL) pair.

One frame of the method (seed 0 unless --seed, the defaults unless overridden), its VPLs and GBuffer; for
every covered pixel x VPL pair the rule's verdict (the numpy brute force of tests/methods/test_visibility_gates.py,
walk of `gate_hops` gates) and the truth (Mitsuba's ray_test on the scene's triangles between the two points, each
moved 2 mm off its surface along its normal). Prints the pairs' shares of the truly visible light (luminance
of the method's own transfer term: near field included): passed correctly, lost (visible, culled), leaked
(occluded, passed), split by same / other visibility cluster and by the pair's length in voxels, the
cluster pairs holding most of the lost and leaked light, the lost light by how much of its segment's middle
lies in voxels the voxelization does not call empty, and the relMSE of the rule's image against the
exact-visibility image of the same VPLs ("proxy": no Mitsuba reference needed) next to an all-black image's.
`--lookup` evaluates other readings of which cluster a pair's ends belong to (rule_matrix; one frame, one
ray test, every reading listed): the method's (`normal`) and variants not in the method.

    python -m studies.visibility_gates_pairs lost_empire --res 64x36 [--param voxel_resolution=128]
    python -m studies.visibility_gates_pairs sponza --res 64x36 --lookup normal,direction,first_empty,either
"""
from __future__ import annotations

import argparse
from collections import Counter

import numpy as np

import tests.methods.test_visibility_gates as tv
from bench.analysis.metrics import relmse
from bench.gl import create_context
from bench.model.corpus import load_scene
from methods.visibility_gates.method import topology_seeds
from methods.visibility_gates.voxels import voxelize
from studies.segment_truth import mitsuba_scene, ray_truth

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
OFFSET = 2e-3  # m: ray ends moved off their surfaces


LOOKUPS = ("normal", "direction", "first_empty", "either", "direction_vpl", "direction_pixel", "direction_long")


def walk(topo, crossing, start, target, t0, hops) -> np.ndarray:
    """(P, K) the rule for per-pair clusters: V = 1 when `start` (the VPL's side) equals `target` (the
    pixel's side), else the segment walks from `start` through the first gate of the current cluster it
    crosses beyond the last crossing (beyond t0 at first) and must enter `target` within `hops` gates."""
    vis = start == target
    here, t_prev, walking = start.copy(), np.array(t0, float, copy=True), ~vis
    for _ in range(hops):
        t_best, nxt = np.full(vis.shape, 2.0), -np.ones(vis.shape, np.int64)
        for g, (a, b) in enumerate(topo.gate_clusters):
            t = crossing[..., g]
            for src, dst in ((a, b), (b, a)):
                better = walking & (here == src) & (t > t_prev) & (t < t_best)
                t_best, nxt = np.where(better, t, t_best), np.where(better, dst, nxt)
        arrived = walking & (nxt == target)
        vis |= arrived
        walking &= (nxt >= 0) & ~arrived
        here, t_prev = np.where(walking, nxt, here), t_best
    return vis


def along_segment(topo, a, b, empty=None, max_voxels=8.0):
    """(P, K) cluster of each pair's end `a` looked up towards `b` and its parameter t on a -> b: one voxel
    along the segment (empty None), or the first voxel centre-sampled every half voxel along it (up to
    `max_voxels` and half the segment) that is empty; pairs whose first half meets no empty voxel get -2."""
    d = b - a
    length = np.maximum(np.linalg.norm(d, axis=-1), 1e-12)
    if empty is None:
        s = np.minimum(topo.pitch, 0.5 * length)
        q = a + (s / length)[..., None] * d
        return topo.cluster_of(q.reshape(-1, 3)).reshape(length.shape), s / length
    out, t_out = -2 * np.ones(length.shape, np.int64), np.zeros(length.shape)
    found = np.zeros(length.shape, bool)
    dims = np.asarray(empty.shape)
    for j in range(1, int(2 * max_voxels) + 1):
        s = 0.5 * j * topo.pitch
        ok = ~found & (s <= 0.5 * length)
        if not ok.any():
            break
        q = a[ok] + (s / length[ok])[:, None] * d[ok]
        idx = np.clip(np.floor((q - topo.origin) / topo.pitch).astype(np.int64), 0, dims - 1)
        e = empty[idx[:, 0], idx[:, 1], idx[:, 2]]
        sel = np.flatnonzero(ok.ravel())[e]
        out.ravel()[sel] = topo.cluster_of(q[e])
        t_out.ravel()[sel] = s / length.ravel()[sel]
        found.ravel()[sel] = True
    return out, t_out


def rule_matrix(frame, lookup="normal", empty=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pixels, VPLs) verdicts of the rule and the pixels' / VPLs' visibility clusters (normal lookup).
    lookup "normal": the method's (each end's cluster one voxel off its surface along its normal);
    "direction": each end's cluster one voxel (at most half the pair) along the segment towards the other
    end, the walk starting beyond the VPL's lookup; "first_empty": the first empty voxel along the segment
    from each end (the normal lookup when none within 8 voxels / half the segment); "either": normal or
    direction passes; "direction_vpl" / "direction_pixel": the direction lookup at that end only, the
    normal one at the other; "direction_long": the direction lookup for pairs at least 2 voxels long (where the
    two lookups are distinct points), the normal one for shorter pairs."""
    topo, gb, v, hops = frame["topology"], frame["gbuffer"], frame["vpls"], frame["params"]["gate_hops"]
    mask = gb["mask"].ravel()
    xs, nxs = (gb[k].reshape(-1, 3)[mask].astype(np.float64) for k in ("position", "normal"))
    lit = np.any(v["flux"] != 0, axis=1)
    y, ny = v["position"][lit], v["normal"][lit].astype(np.float64)
    cy = topo.cluster_of(y + ny * topo.pitch)
    cx = topo.cluster_of(xs + nxs * topo.pitch)
    parts = []
    for first in range(0, len(xs), 256):
        x, cxx = xs[first:first + 256], cx[first:first + 256]
        crossing = tv.gate_crossings(topo, y, x, frame["params"]["gate_radius_scale"])
        shape = (len(x), len(y))
        normal = walk(topo, crossing, np.broadcast_to(cy[None], shape), np.broadcast_to(cxx[:, None], shape),
                      np.zeros(shape), hops)
        if lookup == "normal":
            parts.append(normal)
            continue
        yy, xx = np.broadcast_to(y[None], shape + (3,)), np.broadcast_to(x[:, None], shape + (3,))
        start, t0 = along_segment(topo, yy, xx, empty if lookup == "first_empty" else None)
        target, _ = along_segment(topo, xx, yy, empty if lookup == "first_empty" else None)
        if lookup == "first_empty":
            start = np.where(start == -2, np.broadcast_to(cy[None], shape), start)
            target = np.where(target == -2, np.broadcast_to(cxx[:, None], shape), target)
        if lookup == "direction_vpl":
            target = np.broadcast_to(cxx[:, None], shape)
        if lookup == "direction_pixel":
            start, t0 = np.broadcast_to(cy[None], shape), np.zeros(shape)
        if lookup == "direction_long":
            short = np.linalg.norm(xx - yy, axis=-1) < 2 * topo.pitch
            start = np.where(short, np.broadcast_to(cy[None], shape), start)
            target = np.where(short, np.broadcast_to(cxx[:, None], shape), target)
            t0 = np.where(short, 0.0, t0)
        directed = walk(topo, crossing, start, target, t0, hops)
        parts.append(directed | normal if lookup == "either" else directed)
    return np.concatenate(parts), cx, cy


def truth_matrix(scene, frame) -> np.ndarray:
    """(pixels, VPLs): is the segment between the two points free of triangles (Mitsuba's ray tests)?"""
    mi, msc = mitsuba_scene(scene)
    gb, v = frame["gbuffer"], frame["vpls"]
    mask = gb["mask"].ravel()
    xs = (gb["position"].reshape(-1, 3)[mask] + OFFSET * gb["normal"].reshape(-1, 3)[mask]).astype(np.float64)
    lit = np.any(v["flux"] != 0, axis=1)
    y = v["position"][lit] + OFFSET * v["normal"][lit]
    return ray_truth(mi, msc, xs, y)[0]


def contributions(frame) -> np.ndarray:
    """(pixels, VPLs) luminance of each pair's transfer term (the method's near field), visibility aside."""
    gb, v = frame["gbuffer"], frame["vpls"]
    mask = gb["mask"].ravel()
    xs, nxs = (gb[k].reshape(-1, 3)[mask].astype(np.float64) for k in ("position", "normal"))
    rho = gb["albedo"].reshape(-1, 3)[mask]
    lit = np.any(v["flux"] != 0, axis=1)
    y, ny, phi = v["position"][lit], v["normal"][lit].astype(np.float64), v["flux"][lit].astype(np.float64)
    area = v["area"][lit].astype(np.float64)[None]
    out = np.zeros((len(xs), len(y)))
    for first in range(0, len(xs), 256):
        part = slice(first, first + 256)
        d = y[None] - xs[part][:, None]
        dist = np.linalg.norm(d, axis=2)
        w = d / np.maximum(dist, 1e-30)[..., None]
        cos_x, cos_y = np.einsum("pkc,pc->pk", w, nxs[part]), -np.einsum("pkc,kc->pk", w, ny)
        term = np.where((cos_x > 0) & (cos_y > 0), cos_x * cos_y / tv.near_d2(frame, dist, area), 0.0)
        out[part] = term * ((rho[part] * LUMINANCE) @ phi.T) / np.pi ** 2
    return out


def middle_occupancy(topo, empty, y, xs, pixels, vpls, chunk=20000) -> np.ndarray:
    """Per pair (pixels[i], vpls[i]): the fraction of its segment's points, every half voxel beyond 1.5 voxels
    of both ends, in voxels that are not empty space (NaN for a pair shorter than 3 voxels)."""
    dims = np.asarray(empty.shape)
    out = np.full(len(pixels), np.nan)
    for first in range(0, len(pixels), chunk):
        part = slice(first, first + chunk)
        a, b = y[vpls[part]], xs[pixels[part]]
        length = np.linalg.norm(b - a, axis=1)
        total, solid = np.zeros(len(a)), np.zeros(len(a))
        s = 1.5 * topo.pitch
        while True:
            ok = s < length - 1.5 * topo.pitch
            if not ok.any():
                break
            q = a[ok] + (s / length[ok])[:, None] * (b[ok] - a[ok])
            idx = np.clip(np.floor((q - topo.origin) / topo.pitch).astype(np.int64), 0, dims - 1)
            total[ok] += 1
            solid[ok] += ~empty[idx[:, 0], idx[:, 1], idx[:, 2]]
            s += 0.5 * topo.pitch
        out[part] = np.where(total > 0, solid / np.maximum(total, 1), np.nan)
    return out


def study(scene_name: str, width: int, height: int, params: dict, lookups=("normal",), seed: int = 0) -> None:
    tv.W, tv.H = width, height   # the test module's brute force reads its image size from these
    scene = load_scene(scene_name)
    frame = tv.render_frame(create_context(), scene, params, seed=seed)
    topo = frame["topology"]
    p = frame["params"]
    _, empty, origin, pitch, _, _ = voxelize(scene.vertices, scene.faces, p["voxel_resolution"],
                                             topology_seeds(scene), p["occupancy"])
    assert np.allclose(origin, topo.origin) and np.isclose(pitch, topo.pitch)
    truth = truth_matrix(scene, frame)
    c = contributions(frame)
    visible = c[truth].sum()
    exact = tv.vpl_sum(frame, truth)
    m = frame["gbuffer"]["mask"]
    for lookup in lookups:
        rule, cx, cy = rule_matrix(frame, lookup, empty)
        print(f"== {scene_name} {width}x{height} seed {seed} {params or 'defaults'} lookup={lookup}: "
              f"{topo.cluster_count} clusters, {len(topo.gate_radius)} gates, voxel {topo.pitch:.3g} m; "
              f"{rule.shape[0]} pixels x {rule.shape[1]} VPLs")
        print(f"truly visible light / unshadowed {visible / c.sum():.3f}; the rule passes {c[rule].sum() / c.sum():.3f}")
        same = cx[:, None] == cy[None]
        length = np.linalg.norm(frame["vpls"]["position"][np.any(frame["vpls"]["flux"] != 0, axis=1)][None]
                                - frame["gbuffer"]["position"].reshape(-1, 3)[m.ravel()][:, None],
                                axis=2) / topo.pitch
        print("share of the truly visible light | all | same cluster | other cluster | < 3 voxels long | >= 3 voxels")
        for name, sel in (("passed (visible)", truth & rule), ("lost (visible, culled)", truth & ~rule),
                          ("leaked (occluded, passed)", ~truth & rule)):
            shares = [c[sel & mm].sum() / visible for mm in (True, same, ~same, length < 3, length >= 3)]
            print(f"  {name:26s} " + " | ".join(f"{s:.3f}" for s in shares))
        for name, sel in (("lost", truth & ~rule), ("leaked", ~truth & rule)):
            p_, k = np.nonzero(sel)
            pairs = Counter()
            for a, b, w in zip(cx[p_], cy[k], c[p_, k]):
                pairs[(int(a), int(b))] += w / visible
            print(f"  {name} by (pixel cluster, VPL cluster): " +
                  ", ".join(f"{a}<-{b} {w:.3f}" for (a, b), w in pairs.most_common(6)))
        lost_p, lost_k = np.nonzero(truth & ~rule)
        weight = c[lost_p, lost_k]
        xs = frame["gbuffer"]["position"].reshape(-1, 3)[m.ravel()].astype(np.float64)
        ys = frame["vpls"]["position"][np.any(frame["vpls"]["flux"] != 0, axis=1)]
        solid = middle_occupancy(topo, empty, ys, xs, lost_p, lost_k)
        short = np.isnan(solid)
        shares = [weight[sel].sum() / max(weight.sum(), 1e-300) for sel in
                  (short, ~short & (solid == 0), ~short & (solid > 0) & (solid < 0.5), ~short & (solid >= 0.5))]
        print("  lost light by its segment's middle (beyond 1.5 voxels of both ends): pair < 3 voxels {:.3f}, "
              "all in empty voxels {:.3f}, under half in occupied voxels {:.3f}, at least half {:.3f}".format(*shares))
        gated = tv.vpl_sum(frame, rule)
        print(f"proxy relMSE against the exact-visibility image of the same VPLs: rule {relmse(gated, exact, m):.3f}, "
              f"all black {relmse(0 * exact, exact, m):.3f}; image mean rule / exact {gated[m].mean() / exact[m].mean():.3f}",
              flush=True)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("scene")
    p.add_argument("--res", default="64x36")
    p.add_argument("--seed", type=int, default=0, help="the frame's seed (its VPLs)")
    p.add_argument("--lookup", default="normal", help="comma list of " + ", ".join(LOOKUPS))
    p.add_argument("--param", action="append", default=[], help="NAME=VALUE override (repeatable)")
    args = p.parse_args(argv)
    width, height = (int(v) for v in args.res.split("x"))
    params = {}
    for text in args.param:
        name, _, value = text.partition("=")
        params[name] = value.lower() == "true" if value.lower() in ("true", "false") else \
            (int(value) if value.lstrip("-").isdigit() else float(value) if value.replace(".", "", 1).isdigit() else value)
    lookups = tuple(args.lookup.split(","))
    bad = [x for x in lookups if x not in LOOKUPS]
    if bad:
        p.error(f"--lookup {bad[0]!r} is not one of {', '.join(LOOKUPS)}")
    study(args.scene, width, height, params, lookups, args.seed)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
