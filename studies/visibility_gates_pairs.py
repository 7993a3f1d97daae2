"""visibility_gates (issue #23): the gates' visibility rule against a ray-cast truth, per (pixel, VPL) pair.

One frame of the method (seed 0, the defaults unless overridden), its VPLs and GBuffer; for every covered
pixel x VPL pair the rule's verdict (the numpy brute force of tests/methods/test_visibility_gates.py, walk of
`gate_hops` gates) and the truth (Mitsuba's ray_test on the scene's triangles between the two points, each
moved 2 mm off its surface along its normal). Prints the pairs' shares of the truly visible light (luminance
of the method's own transfer term: near field included): passed correctly, lost (visible, culled), leaked
(occluded, passed), split by same / other visibility cluster and by the pair's length in voxels, the
cluster pairs holding most of the lost and leaked light, and the relMSE of the rule's image against the
exact-visibility image of the same VPLs ("proxy": no Mitsuba reference needed) next to an all-black image's.

    python -m studies.visibility_gates_pairs lost_empire --res 64x36 [--param voxel_resolution=128]
"""
from __future__ import annotations

import argparse
from collections import Counter

import numpy as np

import tests.methods.test_visibility_gates as tv
from bench.analysis.metrics import relmse
from bench.gl import create_context
from bench.model.corpus import load_scene
from reference.env import load_mitsuba

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
OFFSET = 2e-3  # m: ray ends moved off their surfaces


def rule_matrix(frame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pixels, VPLs) verdicts of the method's rule and the pixels' / VPLs' visibility clusters."""
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
        vis = cxx[:, None] == cy[None]
        crossing = tv.gate_crossings(topo, y, x, frame["params"]["gate_radius_scale"])
        here, t_prev, walking = np.broadcast_to(cy[None], vis.shape).copy(), np.zeros(vis.shape), ~vis
        for _ in range(hops):
            t_best, nxt = np.full(vis.shape, 2.0), -np.ones(vis.shape, np.int64)
            for g, (a, b) in enumerate(topo.gate_clusters):
                t = crossing[..., g]
                for src, dst in ((a, b), (b, a)):
                    better = walking & (here == src) & (t > t_prev) & (t < t_best)
                    t_best, nxt = np.where(better, t, t_best), np.where(better, dst, nxt)
            arrived = walking & (nxt == cxx[:, None])
            vis |= arrived
            walking &= (nxt >= 0) & ~arrived
            here, t_prev = np.where(walking, nxt, here), t_best
        parts.append(vis)
    return np.concatenate(parts), cx, cy


def truth_matrix(scene, frame) -> np.ndarray:
    """(pixels, VPLs): is the segment between the two points free of triangles (Mitsuba ray_test)?"""
    mi = load_mitsuba()
    mesh = mi.Mesh("scene", len(scene.vertices), len(scene.faces))
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(scene.vertices.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(scene.faces.astype(np.uint32).ravel())
    params.update()
    msc = mi.load_dict({"type": "scene", "mesh": mesh})
    gb, v = frame["gbuffer"], frame["vpls"]
    mask = gb["mask"].ravel()
    xs = (gb["position"].reshape(-1, 3)[mask] + OFFSET * gb["normal"].reshape(-1, 3)[mask]).astype(np.float64)
    lit = np.any(v["flux"] != 0, axis=1)
    y = v["position"][lit] + OFFSET * v["normal"][lit]
    out = np.zeros((len(xs), len(y)), bool)
    for first in range(0, len(xs), 512):
        o = np.repeat(xs[first:first + 512], len(y), 0)
        d = np.tile(y, (len(o) // len(y), 1)) - o
        length = np.linalg.norm(d, axis=1)
        d /= length[:, None]
        ray = mi.Ray3f(mi.Point3f(*(mi.Float(o[:, i].astype(np.float32)) for i in range(3))),
                       mi.Vector3f(*(mi.Float(d[:, i].astype(np.float32)) for i in range(3))))
        ray.maxt = mi.Float((length * (1 - 1e-4)).astype(np.float32))
        out[first:first + 512] = ~np.array(msc.ray_test(ray), bool).reshape(-1, len(y))
    return out


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


def study(scene_name: str, width: int, height: int, params: dict) -> None:
    tv.W, tv.H = width, height   # the test module's brute force reads its image size from these
    scene = load_scene(scene_name)
    frame = tv.render_frame(create_context(), scene, params, seed=0)
    topo = frame["topology"]
    rule, cx, cy = rule_matrix(frame)
    truth = truth_matrix(scene, frame)
    c = contributions(frame)
    visible = c[truth].sum()
    print(f"{scene_name} {width}x{height} {params or 'defaults'}: {topo.cluster_count} clusters, "
          f"{len(topo.gate_radius)} gates, voxel {topo.pitch:.3g} m; {rule.shape[0]} pixels x {rule.shape[1]} VPLs")
    print(f"truly visible light / unshadowed {visible / c.sum():.3f}; the rule passes {c[rule].sum() / c.sum():.3f}")
    same = cx[:, None] == cy[None]
    length = np.linalg.norm(frame["vpls"]["position"][np.any(frame["vpls"]["flux"] != 0, axis=1)][None]
                            - frame["gbuffer"]["position"].reshape(-1, 3)[frame["gbuffer"]["mask"].ravel()][:, None],
                            axis=2) / topo.pitch
    print("share of the truly visible light | all | same cluster | other cluster | < 3 voxels long | >= 3 voxels")
    for name, sel in (("passed (visible)", truth & rule), ("lost (visible, culled)", truth & ~rule),
                      ("leaked (occluded, passed)", ~truth & rule)):
        shares = [c[sel & m].sum() / visible for m in (True, same, ~same, length < 3, length >= 3)]
        print(f"  {name:26s} " + " | ".join(f"{s:.3f}" for s in shares))
    for name, sel in (("lost", truth & ~rule), ("leaked", ~truth & rule)):
        p, k = np.nonzero(sel)
        pairs = Counter()
        for a, b, w in zip(cx[p], cy[k], c[p, k]):
            pairs[(int(a), int(b))] += w / visible
        print(f"  {name} by (pixel cluster, VPL cluster): " +
              ", ".join(f"{a}<-{b} {w:.3f}" for (a, b), w in pairs.most_common(6)))
    exact, gated = tv.vpl_sum(frame, truth), tv.vpl_sum(frame, rule)
    m = frame["gbuffer"]["mask"]
    print(f"proxy relMSE against the exact-visibility image of the same VPLs: rule {relmse(gated, exact, m):.3f}, "
          f"all black {relmse(0 * exact, exact, m):.3f}; image mean rule / exact {gated[m].mean() / exact[m].mean():.3f}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("scene")
    p.add_argument("--res", default="64x36")
    p.add_argument("--param", action="append", default=[], help="NAME=VALUE override (repeatable)")
    args = p.parse_args(argv)
    width, height = (int(v) for v in args.res.split("x"))
    params = {}
    for text in args.param:
        name, _, value = text.partition("=")
        params[name] = value.lower() == "true" if value.lower() in ("true", "false") else \
            (int(value) if value.lstrip("-").isdigit() else float(value) if value.replace(".", "", 1).isdigit() else value)
    study(args.scene, width, height, params)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
