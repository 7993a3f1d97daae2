"""val_clustered's per-VAL visibility against exact ray-traced visibility (issue #23, the method's NOTES.md,
"contact blockers"). For one view at the given parameters, frame 0's internals are read back (G-buffer,
the per-pixel per-VAL visibility, VAL records, VPLs) and three one-bounce images are formed without
interleaving, each VPL's unshadowed transfer times:

  per-VPL exact   the VPL's own visibility from the pixel (Mitsuba ray test): the stand-in for the
                  visible reference
  origin exact    the visibility of its VAL's map origin (ray test): a perfect per-VAL map
  map             its VAL's visibility as the method computed it

and the method's own image; relMSE (bench.analysis.metrics.relmse), image mean and the 20 worst pixels'
share of the squared error are printed against per-VPL exact, then the VALs whose map visibility
exceeds the origin's exact one the most (flux-weighted).

    python studies/val_clustered_contact.py rooms main [contact_test=off ...]   (env RES=320x180; the defaults otherwise)
"""
import os
import sys

import numpy as np

from bench.analysis.metrics import relmse
from bench.gl import create_context
from bench.gl.passes import read_rgba
from bench.model.corpus import load_scene
from bench.run.config import auto_shadow_resolution
from bench.run.harness import run_method
from methods.val_clustered.method import ClusteredVirtualAreaLights

W, H = map(int, os.environ.get("RES", "320x180").split("x"))


class Capture(ClusteredVirtualAreaLights):
    """The method, keeping frame 0's internals."""
    captured: dict = {}

    def render(self, frame, prof):
        out = super().render(frame, prof)
        if not Capture.captured:
            g, cap = frame.passes.gbuffer, Capture.captured
            cap["pos"], cap["ngeo"] = read_rgba(g.position), read_rgba(g.geo_normal)
            cap["alb"], cap["nsh"] = read_rgba(g.albedo), read_rgba(g.normal)
            m = self.clustering.cluster_count
            vis = np.frombuffer(self.visibility.read(), np.float32).reshape(m, self.height, self.width)
            cap["vis"] = vis[:, ::-1].copy()
            cap.update({"val_" + k: v for k, v in self.clustering.read().items()})
            cap.update({"vpl_" + k: v for k, v in self.sampler.read_vpls().items()})
            cap["origin"] = self.clustering.gpu.origin
        return out


def mitsuba_scene(scene, origin):
    import drjit as dr
    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    v = (scene.vertices - origin).astype(np.float32)
    f = scene.faces.astype(np.uint32)
    mesh = mi.Mesh("m", len(v), len(f))
    p = mi.traverse(mesh)
    p["vertex_positions"] = dr.ravel(mi.Point3f(v.T))
    p["faces"] = dr.ravel(mi.Vector3u(f.T))
    p.update()
    return mi.load_dict({"type": "scene", "m": mesh})


def unoccluded(ms, a, b, eps=1e-4):
    """True where the segment a -> b (both (K, 3)) meets no triangle (its ends shortened by eps)."""
    import mitsuba as mi
    d = b - a
    length = np.linalg.norm(d, axis=1)
    w = d / np.maximum(length, 1e-30)[:, None]
    ray = mi.Ray3f(mi.Point3f((a + w * eps).T.astype(np.float32)), mi.Vector3f(w.T.astype(np.float32)))
    ray.maxt = mi.Float((length - 2 * eps).astype(np.float32))
    return ~np.array(ms.ray_test(ray), dtype=bool)


def transfer(cap, x, n):
    """(P, N, 3) unshadowed VPL transfer (the shared footprint near field, scale 1), without albedo."""
    y, ny, phi, area = cap["vpl_position"], cap["vpl_normal"], cap["vpl_flux"], cap["vpl_area"]
    d = y[None].astype(np.float64) - x[:, None]
    dist = np.linalg.norm(d, axis=2)
    w = d / np.maximum(dist, 1e-30)[..., None]
    cx, cy = np.einsum("pkc,pc->pk", w, n), -np.einsum("pkc,kc->pk", w, ny)
    t = np.where((cx > 0) & (cy > 0), cx * cy / np.maximum(dist ** 2, area[None] / np.pi), 0.0)
    return t[..., None] * phi[None]


def figures(image, ref, mask):
    e = ((image - ref) ** 2).sum(-1)[mask]
    return (f"relmse {relmse(image, ref, mask):.4f} mean {image[mask].mean() / ref[mask].mean():.3f} "
            f"top20 {np.sort(e)[-20:].sum() / e.sum():.2f}")


def main(scene_name, view, params):
    scene = load_scene(scene_name)
    res = run_method(create_context(), Capture, scene, view, W, H, params, seed=0, frames=1,
                     shadow_resolution=auto_shadow_resolution(W, H))
    cap = Capture.captured
    ms = mitsuba_scene(scene, cap["origin"])
    mask = cap["pos"][..., 3] > 0
    rows, cols = np.nonzero(mask)
    x = cap["pos"][rows, cols, :3].astype(np.float64)
    ng, ns = cap["ngeo"][rows, cols, :3].astype(np.float64), cap["nsh"][rows, cols, :3].astype(np.float64)
    xo = x + 1e-4 * np.where((np.einsum("pc,pc->p", ng, ns) < 0)[:, None], -ng, ng)   # off the surface, camera side
    mapping, m = cap["val_mapping"], len(cap["val_count"])
    origins = cap["val_origin"].astype(np.float64)
    v_exact = np.stack([unoccluded(ms, xo, np.repeat(origins[j][None], len(x), 0)) for j in range(m)], 1)
    contrib = np.zeros((len(x), m, 3))
    per_vpl = np.zeros((len(x), 3))
    for s in range(0, len(x), 1500):
        sl = slice(s, s + 1500)
        t = transfer(cap, x[sl], ns[sl])
        for j in range(m):
            contrib[sl, j] = t[:, mapping == j].sum(1)
        pp, kk = np.nonzero(t.sum(2) > 0)
        ends = cap["vpl_position"][kk].astype(np.float64) + 1e-4 * cap["vpl_normal"][kk]
        v = np.zeros(t.shape[:2])
        v[pp, kk] = unoccluded(ms, xo[sl][pp], ends)
        per_vpl[sl] = (t * v[..., None]).sum(1)
    albedo = cap["alb"][rows, cols, :3] / np.pi ** 2
    contrib *= albedo[:, None]
    per_vpl *= albedo
    v_map = cap["vis"][:, rows, cols].T

    def image(values):
        out = np.zeros((H, W, 3))
        out[rows, cols] = values
        return out
    ref = image(per_vpl)
    print(f"{scene_name}/{view} {params}: against per-VPL exact visibility (no indirect: "
          f"relmse {relmse(np.zeros_like(ref), ref, mask):.4f})")
    print("  method        ", figures(res.indirect.astype(np.float64), ref, mask))
    print("  map           ", figures(image((contrib * v_map[..., None]).sum(1)), ref, mask))
    print("  origin exact  ", figures(image((contrib * v_exact[..., None]).sum(1)), ref, mask))
    excess = np.clip(contrib.mean(2) * (v_map - v_exact), 0, None).sum(0)
    for j in np.argsort(-excess)[:6]:
        print(f"  VAL {j:3d}: excess {excess[j] / max(excess.sum(), 1e-30):.2f} of the map's, origin "
              f"{np.round(origins[j] + cap['origin'], 2)} normal {np.round(cap['val_normal'][j], 2)} "
              f"size {cap['val_size'][j]:.2f} far {cap['val_far'][j]:.2f} VPLs {cap['val_count'][j]:.0f}")


def parse(v):
    """A command-line parameter value: int, else float, else the string."""
    for t in (int, float):
        try:
            return t(v)
        except ValueError:
            pass
    return v


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], {k: parse(v) for k, v in (a.split("=", 1) for a in sys.argv[3:])})
