"""ir_shadowed: which (pixel, VPL) pairs its hemicube shadow test gets wrong, against a ray-cast truth.

One frame of the method (frame 0 of `--seed`, the defaults unless `--param NAME=VALUE` overrides them) on a
corpus scene's view; for every pixel of a window (`--window r0:r1,c0:c1`, image rows top-first as in the
EXR; the whole image by default) and every VPL: the method's verdict (vpl_shadow.glsl replayed in numpy on
the read-back hemicube atlas; the replay's image is checked against the method's own, printed) and the
truth (Mitsuba's ray_test between the two points, each moved 2 mm off its surface along its normal).

Prints: the window's mean of the method's image, of the exact-visibility image of the same VPLs and of
the unshadowed one (with `--reference` the run's references/<scene>/<view> folder: the reference's mean
and the relMSE of the method's and of the exact-visibility image against it, on the runner's covered
pixels); the shares of the unshadowed light (luminance) truly visible / passed / leaked (occluded,
passed) / lost (visible, blocked); how many VPLs carry the truly visible light (top 1 / 3 / 10, how many
hold 50% and 90%) and from which surfaces; the leaked light by hemicube face, by the texel's record
(empty; stored distance beyond the receiver, i.e. the texel sees past the blocker; receiver within the
footprint tolerance past it; in a face's outermost texel row, the seams), the share whose offset receiver
point itself sees the hemicube's centre (the normal offset moved it out of the shadow), by the VPL's
surface; and the worst leaking VPLs with the blocker the exact ray hits and the lookup of their brightest
pair (face, uv, stored / receiver distance, texel footprint, receiver offset).

    python -m studies.ir_shadowed_leaks rooms --view far --res 160x120 --window 40:71,70:89 \
        --reference /tmp/h41/rf160/references/rooms/far
    python -m studies.ir_shadowed_leaks rooms --view far --res 160x120 --param normal_offset=0.1

(the references folder from `gibench run --scenes rooms --views far --methods direct,ir_shadowed --res
160x120 --frames 1 --timing-budget 0 --error-frames 1 --reference-spp 128 --defaults-only --out /tmp/h41/rf160`).
"""
from __future__ import annotations

import argparse
from collections import Counter

import numpy as np

from bench.gl import Frame, GpuScene, SharedPasses, StageProfiler, create_context, read_rgb
from bench.model.corpus import load_scene
from bench.protocol.method import resolve_params
from methods.ir_shadowed.method import HEMICUBE_FACES, PLANE_TOLERANCE, InstantRadiosityShadowed
from studies.ladder_over_seeds import parse_overrides
from studies.segment_truth import mitsuba_scene, ray_truth

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
OFFSET = 2e-3  # m: ray ends moved off their surfaces


def render(scene, view_name, width, height, params, seed):
    """Frame 0 of the method; returns the image (rows top-first), GBuffer, VPLs, atlas and settings."""
    ctx = create_context()
    gpu = GpuScene(ctx, scene, seed=seed)
    view = gpu.view(view_name, width, height)
    passes = SharedPasses(gpu, view, InstantRadiosityShadowed.needs)
    method = InstantRadiosityShadowed()
    resolved = resolve_params(InstantRadiosityShadowed, params)
    try:
        method.prepare(gpu, scene, gpu.facts, resolved, view)
        prof = StageProfiler(ctx)
        frame = Frame(ctx=ctx, gpu=gpu, view=view, passes=passes, index=0, seed=seed)
        passes.render(prof)
        out = method.render(frame, prof)
        hc = method.hemicubes
        comps = hc.atlas.components
        atlas = np.frombuffer(hc.atlas.read(), np.float32).reshape(hc.atlas.height, hc.atlas.width, comps)
        return {"indirect": read_rgb(out.indirect), "direct": read_rgb(passes.direct.radiance), "gbuffer": passes.gbuffer.read(),   # rows top-first
                "vpls": method.sampler.read_vpls(), "origin": gpu.origin.astype(np.float64), "atlas": atlas,
                "tiles_x": hc.tiles_x, "resolution": hc.resolution, "lift": hc.lift, "eps": method.eps,
                "params": resolved, "radius": gpu.radius}
    finally:
        method.release()
        passes.release()
        gpu.release()


def basis(n):
    """orthonormal_basis of common.glsl (Duff et al.), n (K, 3) -> t, b."""
    s = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (s + n[:, 2])
    c = n[:, 0] * n[:, 1] * a
    t = np.stack([1 + s * n[:, 0] ** 2 * a, s * c, -s * n[:, 0]], 1)
    b = np.stack([c, s + n[:, 1] ** 2 * a, -n[:, 1]], 1)
    return t, b


def verdicts(f, x, ng):
    """vpl_shadow.glsl for pixels x (P, 3, re-centred) with geometric normals ng and every VPL: a dict of
    (P, K) arrays: visible, face, texel, stored distance, plane record, receiver distance, the tests."""
    v, res, p = f["vpls"], f["resolution"], f["params"]
    yn = v["normal"].astype(np.float64)
    y = v["position"].astype(np.float64) + yn * f["lift"]
    to_vpl = y[None] - x[:, None]
    dist = np.linalg.norm(to_vpl, axis=2)
    wi = to_vpl / dist[..., None]
    texel = 2 * dist / res
    sgn = np.where(np.einsum("pc,pkc->pk", ng, wi) < 0, -1.0, 1.0)
    n = sgn[..., None] * ng[:, None]
    cos_r = np.clip(np.einsum("pkc,pkc->pk", n, wi), 0, 1)
    sin_r = np.sqrt(np.maximum(1 - cos_r ** 2, 0))
    offset = p["normal_offset"] * texel * (0.5 + 1.5 * sin_r)
    q = x[:, None] + n * offset[..., None]
    rel = q - y[None]
    t, b = basis(yn)
    lx, ly, lz = (np.einsum("pkc,kc->pk", rel, a) for a in (t, b, yn))
    ax, ay, az = np.abs(lx), np.abs(ly), np.abs(lz)
    front = (az >= ax) & (az >= ay)
    face = np.where(front, np.where(lz <= 0, -1, 0), np.where(ax >= ay, np.where(lx > 0, 1, 2), np.where(ly > 0, 3, 4)))
    # uv per face: (right, up) / axis
    u = np.select([face == 0, face == 1, face == 2, face == 3, face == 4], [lx / lz, lz / lx, lz / -lx, lx / ly, lx / -ly], 0.0)
    w_ = np.select([face == 0, face == 1, face == 2, face == 3, face == 4], [ly / lz, ly / lx, ly / -lx, lz / ly, lz / -ly], 0.0)
    tx = np.clip(((u * 0.5 + 0.5) * res).astype(np.int64), 0, res - 1)
    ty = np.clip(((w_ * 0.5 + 0.5) * res).astype(np.int64), 0, res - 1)
    k = np.broadcast_to(np.arange(len(y))[None], face.shape)
    tile = k * HEMICUBE_FACES + np.maximum(face, 0)
    ax_ = (tile % f["tiles_x"]) * res + tx
    ay_ = (tile // f["tiles_x"]) * res + ty
    rec = f["atlas"][ay_, ax_].astype(np.float64)
    stored = rec[..., 0]
    length = np.linalg.norm(rel, axis=2)
    far_fail = length > stored + texel
    plane_fail = np.zeros_like(far_fail)
    if p["shadow_test"] == "plane":
        along = np.einsum("pkc,pkc->pk", rec[..., 1:4], rel)
        with np.errstate(divide="ignore", invalid="ignore"):
            plane_fail = (along > 1 + PLANE_TOLERANCE) & (length / along >= stored - texel)
    visible = (face < 0) | ~(far_fail | plane_fail)
    return {"visible": visible, "face": face, "u": u, "w": w_, "stored": stored, "record": rec, "length": length,
            "far_fail": far_fail, "plane_fail": plane_fail, "texel": texel, "offset": offset, "q": q}


def transfer(f, x, nx):
    """(P, K, 3) each VPL's term of vpl_gather.glsl (near field included), visibility aside."""
    from bench.gl.near_field import NEAR_FIELDS
    v, p = f["vpls"], f["params"]
    y, yn, phi = (v[k].astype(np.float64) for k in ("position", "normal", "flux"))
    d = y[None] - x[:, None]
    dist = np.linalg.norm(d, axis=2)
    w = d / dist[..., None]
    cx, cy = np.einsum("pkc,pc->pk", w, nx), -np.einsum("pkc,kc->pk", w, yn)
    area, eps = v["area"].astype(np.float64)[None], f["eps"]
    near = p["near_field"]
    assert near in NEAR_FIELDS
    if near == "footprint":
        d2 = np.maximum(eps ** 2, np.maximum(dist ** 2, p["near_field_scale"] * area / np.pi))
    elif near == "disc_element":
        d2 = np.maximum(eps ** 2, dist ** 2 + area / np.pi)
    else:
        d2 = np.maximum(eps, dist) ** 2
    g = np.where((cx > 0) & (cy > 0), cx * cy / d2, 0.0)
    return g[..., None] * phi[None]


def surface_name(p, n, rooms=False):
    """A coarse label of a point: the plane of its dominant normal axis (and in `rooms` its room)."""
    a = int(np.argmax(np.abs(n)))
    label = f"{'xyz'[a]}={p[a]:.2f}"
    return f"room{int(np.clip(p[0] // 4.0, 0, 2)) + 1} {label}" if rooms else label


def pair_tables(scene, f, sel, chunk=1024):
    """For the pixels `sel` (mask, rows top-first): per pixel the method's, the exact-visibility and the
    unshadowed radiance of the same VPLs, and the leaked / lost pairs (pixel index, VPL, luminance, record)."""
    gb, origin = f["gbuffer"], f["origin"]
    xw_all = gb["position"][sel].astype(np.float64)
    ng_all, nx_all = (gb[k][sel].astype(np.float64) for k in ("geo_normal", "normal"))
    rho_all = gb["albedo"][sel].astype(np.float64)
    v = f["vpls"]
    lit = np.any(v["flux"] != 0, axis=1)
    yw = v["position"].astype(np.float64) + origin
    yn = v["normal"].astype(np.float64)
    mi, msc = mitsuba_scene(scene)
    images = {k: np.zeros((len(xw_all), 3)) for k in ("method", "exact", "unshadowed")}
    sums = Counter()
    leaks, exact_by_vpl = [], np.zeros(len(yw))
    for first in range(0, len(xw_all), chunk):
        part = slice(first, first + chunk)
        xw, ng, nx, rho = xw_all[part], ng_all[part], nx_all[part], rho_all[part]
        ver = verdicts(f, xw - origin, ng)
        term = transfer(f, xw - origin, nx)
        free, prim = ray_truth(mi, msc, xw + OFFSET * nx, yw + OFFSET * yn)
        free &= lit[None]
        lum = (term * rho[:, None] * LUMINANCE).sum(2) / np.pi ** 2
        for name, mask in (("method", ver["visible"]), ("exact", free), ("unshadowed", np.ones_like(free))):
            images[name][part] = (term * mask[..., None]).sum(1) * rho / np.pi ** 2
        relevant = lum > 0
        leak, lost = ver["visible"] & ~free & relevant, ~ver["visible"] & free & relevant
        sums["all"] += lum.sum()
        sums["free"] += lum[free].sum()
        sums["passed"] += lum[ver["visible"]].sum()
        sums["leak"] += lum[leak].sum()
        sums["lost"] += lum[lost].sum()
        exact_by_vpl += np.where(free, lum, 0).sum(0)
        p_, k_ = np.nonzero(leak)
        # the offset receiver's own segment to the hemicube's centre, ray-cast (is the offset the whole story?)
        q = ver["q"][p_, k_] + origin
        c = yw[k_] + yn[k_] * f["lift"]
        d = c - q
        length = np.linalg.norm(d, axis=1)
        offset_free = np.ones(len(q), bool)
        if len(q):
            ray = mi.Ray3f(mi.Point3f(*(mi.Float(q[:, i].astype(np.float32)) for i in range(3))),
                           mi.Vector3f(*(mi.Float((d[:, i] / length).astype(np.float32)) for i in range(3))))
            ray.maxt = mi.Float((length * (1 - 1e-4)).astype(np.float32))
            offset_free = ~np.array(msc.ray_test(ray), bool)
        leaks.append({"pixel": p_ + first, "vpl": k_, "lum": lum[p_, k_], "face": ver["face"][p_, k_],
                      "u": ver["u"][p_, k_], "w": ver["w"][p_, k_], "stored": ver["stored"][p_, k_],
                      "length": ver["length"][p_, k_], "texel": ver["texel"][p_, k_], "prim": prim[p_, k_],
                      "plane": ver["record"][p_, k_, 1:4], "offset": ver["offset"][p_, k_],
                      "offset_free": offset_free})
    leaks = {k: np.concatenate([c[k] for c in leaks]) for k in leaks[0]}
    return images, sums, leaks, exact_by_vpl, yw, yn


def study(scene_name, view, width, height, params, seed, window, top, reference=None):
    from bench.analysis.metrics import relmse
    from bench.analysis.evaluation import coverage_mask
    from bench.model.imageio import read_exr
    scene = load_scene(scene_name)
    f = render(scene, view, width, height, params, seed)
    gb = f["gbuffer"]
    rows, cols = window or (slice(0, height), slice(0, width))
    sel = np.zeros(gb["mask"].shape, bool)
    sel[rows, cols] = True
    sel &= gb["mask"]
    images, sums, leaks, exact_by_vpl, yw, yn = pair_tables(scene, f, sel)
    gpu = f["indirect"][sel]
    agree = np.abs(images["method"] - gpu).max() / max(gpu.max(), 1e-30)
    print(f"== {scene_name}/{view} {width}x{height} seed {seed} {params or 'defaults'}: window rows "
          f"{rows.start}:{rows.stop} cols {cols.start}:{cols.stop}, {sel.sum()} pixels x {len(yw)} VPLs")
    print(f"replayed verdicts reproduce the method's image to {agree:.1e} of its maximum")
    line = (f"window mean (rgb): method {gpu.mean():.5f}, exact visibility of the same VPLs "
            f"{images['exact'].mean():.5f}, unshadowed {images['unshadowed'].mean():.5f}")
    if reference is not None:   # the run's references/<scene>/<view> folder; the covered pixels as the runner's
        refs = {name: read_exr(f"{reference}/{name}.exr")[..., :3]
                for name in ("direct", "indirect_visible", "indirect_unshadowed")}
        full = {k: np.zeros_like(refs["direct"]) for k in images}
        for k in images:
            full[k][sel] = images[k]
        cover = coverage_mask({"combined": f["direct"] + f["indirect"]}, refs)
        win = np.zeros_like(cover)
        win[rows, cols] = True
        ref, m = refs["indirect_visible"], cover & win
        line = (f"window mean (rgb, the runner's covered pixels): method {f['indirect'][m].mean():.5f}, exact "
                f"visibility of the same VPLs {full['exact'][m].mean():.5f}, unshadowed {full['unshadowed'][m].mean():.5f}"
                f", reference {ref[m].mean():.5f}; relMSE against it: method "
                 f"{relmse(f['indirect'], ref, m):.4f}, exact visibility {relmse(full['exact'], ref, m):.4f}")
    print(line)
    total = sums["all"]
    print(f"shares of the unshadowed light (luminance): truly visible {sums['free'] / total:.4f}, passed "
          f"{sums['passed'] / total:.4f}, leaked (occluded, passed) {sums['leak'] / total:.4f}, lost (visible, "
          f"blocked) {sums['lost'] / total:.4f}")
    order = np.sort(exact_by_vpl)[::-1]
    cum = np.cumsum(order) / max(order.sum(), 1e-300)
    n_vis = int((exact_by_vpl > 0).sum())
    print(f"truly visible light by VPL: {n_vis} VPLs light the window; the top 1 / 3 / 10 hold "
          f"{cum[0]:.3f} / {cum[min(2, len(cum) - 1)]:.3f} / {cum[min(9, len(cum) - 1)]:.3f}; "
          f"50% in {int(np.searchsorted(cum, 0.5)) + 1}, 90% in {int(np.searchsorted(cum, 0.9)) + 1}")
    by_surface = Counter()
    for k in np.flatnonzero(exact_by_vpl):
        by_surface[surface_name(yw[k], yn[k], scene_name == "rooms")] += exact_by_vpl[k] / exact_by_vpl.sum()
    print("  truly visible light by the VPL's surface: " + ", ".join(f"{s} {w:.3f}" for s, w in by_surface.most_common(6)))
    lw = leaks["lum"]
    if len(lw) == 0:
        return
    share = lambda m: lw[m].sum() / lw.sum()   # noqa: E731
    face, stored, length = leaks["face"], leaks["stored"], leaks["length"]
    print(f"leaked pairs: {len(lw)}; by hemicube face (0 front, 1-4 sides, -1 behind the VPL's plane): " +
          ", ".join(f"{k}: {share(face == k):.3f}" for k in range(-1, 5) if (face == k).any()))
    edge = np.maximum(np.abs(leaks["u"]), np.abs(leaks["w"])) > 1 - 2 / f["resolution"]
    print(f"  texel empty {share(stored > 1e37):.3f}; stored distance beyond the receiver (the texel sees past the "
          f"blocker) {share(length < stored):.3f}; receiver within the footprint past it {share((length >= stored) & (stored < 1e37)):.3f}; "
          f"in a face's outermost texel row (seams) {share(edge):.3f}")
    print(f"  the receiver's offset point sees the hemicube's centre (ray_test free: the normal offset moved it out "
          f"of the shadow) {share(leaks['offset_free']):.3f}")
    by_vpl = Counter()
    for k, w in zip(leaks["vpl"], lw):
        by_vpl[int(k)] += w / lw.sum()
    by_surface = Counter()
    for k, w in by_vpl.items():
        by_surface[surface_name(yw[k], yn[k], scene_name == "rooms")] += w
    print("  leaked light by the VPL's surface: " + ", ".join(f"{s} {w:.3f}" for s, w in by_surface.most_common(6)))
    tri = scene.vertices[scene.faces]
    print("  worst leaking VPLs (share of the leaked light; position, normal; pairs; blocker the ray hits: its "
          "triangle's centre; for its brightest pair: face, uv, stored / receiver distance, texel footprint, "
          "receiver offset):")
    for k, w in by_vpl.most_common(top):
        pairs = leaks["vpl"] == k
        b, nb = Counter(int(b) for b in leaks["prim"][pairs]).most_common(1)[0]
        i = np.flatnonzero(pairs)[np.argmax(lw[pairs])]
        print(f"   VPL {k:3d} {w:.3f}  y {np.round(yw[k], 3)} n {np.round(yn[k], 2)}  {pairs.sum()} pairs  blocker "
              f"tri {b} at {np.round(tri[b].mean(0), 2)} ({nb})  face {face[i]} uv ({leaks['u'][i]:+.3f}, "
              f"{leaks['w'][i]:+.3f}) stored {stored[i]:.4g} receiver {length[i]:.4g} texel {leaks['texel'][i]:.3g} "
              f"offset {leaks['offset'][i]:.3g}")


def parse_window(text):
    r, c = text.split(",")
    r0, r1 = (int(s) for s in r.split(":"))
    c0, c1 = (int(s) for s in c.split(":"))
    return slice(r0, r1), slice(c0, c1)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("scene")
    p.add_argument("--view", default="main")
    p.add_argument("--res", default="160x120")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--window", default=None, help="r0:r1,c0:c1 (image rows top-first)")
    p.add_argument("--top", type=int, default=8, help="leaking VPLs listed")
    p.add_argument("--reference", default=None, help="the run's references/<scene>/<view> folder (same view and size)")
    p.add_argument("--param", action="append", default=[], help="NAME=VALUE override of ir_shadowed (repeatable)")
    args = p.parse_args(argv)
    width, height = (int(s) for s in args.res.split("x"))
    params = parse_overrides(args.param)
    study(args.scene, args.view, width, height, params, args.seed,
          parse_window(args.window) if args.window else None, args.top, args.reference)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
