"""Where val_clustered's error on `rooms` comes from (issue #23, the method's NOTES.md, "rooms/far was the
CSM step's periodic wrap"): frame 0's internals are captured as in studies/val_clustered_contact.py and,
against each VPL's exact visibility (Mitsuba ray tests), the squared relative error is split by room
(x in [0, 4), [4, 8), [8, 12)) and surface orientation, with the VALs whose light differs most there; then
room 3's back wall (z = -2) by 25 cm bands of x, the first beside the door wall at x = 8.

    python studies/val_clustered_rooms_far.py [VIEW] [param=value ...]   (env RES=320x180; VIEW far)
"""
import sys

import numpy as np

from bench.gl import create_context
from bench.model.corpus import load_scene
from bench.run.config import auto_shadow_resolution
from bench.run.harness import run_method
from studies import val_clustered_contact as vc

AXES = {"+x": (1, 0, 0), "-x": (-1, 0, 0), "+y": (0, 1, 0), "-y": (0, -1, 0), "+z": (0, 0, 1), "-z": (0, 0, -1)}

parse = vc.parse


def main(view, params):
    scene = load_scene("rooms")
    run_method(create_context(), vc.Capture, scene, view, vc.W, vc.H, params, seed=0, frames=1,
               shadow_resolution=auto_shadow_resolution(vc.W, vc.H))
    cap = vc.Capture.captured
    ms = vc.mitsuba_scene(scene, cap["origin"])
    mask = cap["pos"][..., 3] > 0
    rows, cols = np.nonzero(mask)
    x = cap["pos"][rows, cols, :3].astype(np.float64)
    ng, ns = cap["ngeo"][rows, cols, :3].astype(np.float64), cap["nsh"][rows, cols, :3].astype(np.float64)
    xo = x + 1e-4 * np.where((np.einsum("pc,pc->p", ng, ns) < 0)[:, None], -ng, ng)
    mapping, m = cap["val_mapping"], len(cap["val_count"])
    unshadowed, exact = np.zeros((len(x), m, 3)), np.zeros((len(x), m, 3))
    for s in range(0, len(x), 1500):
        sl = slice(s, s + 1500)
        t = vc.transfer(cap, x[sl], ns[sl])
        pp, kk = np.nonzero(t.sum(2) > 0)
        v = np.zeros(t.shape[:2])
        v[pp, kk] = vc.unoccluded(ms, xo[sl][pp], cap["vpl_position"][kk].astype(np.float64) + 1e-4 * cap["vpl_normal"][kk])
        for j in range(m):
            unshadowed[sl, j] = t[:, mapping == j].sum(1)
            exact[sl, j] = (t * v[..., None])[:, mapping == j].sum(1)
    albedo = cap["alb"][rows, cols, :3][:, None] / np.pi ** 2
    method = unshadowed * albedo * cap["vis"][:, rows, cols].T[..., None]     # per VAL, the method's visibility
    exact = exact * albedo
    ref, img = exact.sum(1), method.sum(1)
    q = ((img - ref) ** 2 / (ref ** 2 + 0.01 * np.mean(ref ** 2))).mean(1)
    world = x + cap["origin"]
    room = np.clip(np.floor(world[:, 0] / 4.0).astype(int), 0, 2)
    print(f"rooms/{view} {params}: relMSE of the map against per-VPL exact {q.mean():.4f} (image mean "
          f"{img.mean() / ref.mean():.3f})")
    for r in range(3):
        for name, axis in AXES.items():
            sel = (room == r) & (ns @ np.array(axis, float) > 0.9)
            if not sel.any() or q[sel].sum() < 0.01 * q.sum():
                continue
            print(f"  room {r + 1} normal {name}: {sel.sum():6d} px, error share {q[sel].sum() / q.sum():.3f}, "
                  f"mean exact {ref[sel].mean():.5f} method {img[sel].mean():.5f}")
            diff = (method[sel] - exact[sel]).mean(2).sum(0)
            for j in np.argsort(-np.abs(diff))[:3]:
                print(f"      VAL {j:3d}: method - exact {diff[j]:+.4f} (exact {exact[sel, j].mean(1).sum():.4f}), "
                      f"mean V {cap['vis'][j, rows[sel], cols[sel]].mean():.3f}, origin "
                      f"{np.round(cap['val_origin'][j] + cap['origin'], 2)}, VPLs {cap['val_count'][j]:.0f}")
    wall = (room == 2) & (ns @ np.array(AXES["+z"], float) > 0.9)
    print("  room 3's back wall by x (error share, exact, method):")
    for a in np.arange(8.0, 12.0, 0.25):
        k = wall & (world[:, 0] >= a) & (world[:, 0] < a + 0.25)
        if k.any():
            print(f"    x {a:5.2f}-{a + 0.25:5.2f}: {q[k].sum() / q.sum():.3f}  {ref[k].mean():.5f}  {img[k].mean():.5f}")


if __name__ == "__main__":
    args = sys.argv[1:]
    view = args.pop(0) if args and "=" not in args[0] else "far"
    main(view, {k: parse(v) for k, v in (a.split("=", 1) for a in args)})
