"""val_clustered variants against the visible one-bounce reference (relMSE, image mean / reference) at one
frame, seed 0 (issue #23, NOTES.md). usage: python studies/val_clustered_variants.py SCENE[/VIEW],... 'name:k=v;k=v' ...
(env RES=320x180, SPP=512 reference spp cap, SAVE=folder for the images as .npy)"""
import os, sys, json, time
import numpy as np
from bench.gl import create_context
from bench.model.corpus import load_scene
from bench.run.harness import run_method
from bench.analysis.metrics import relmse
from reference.api import get_reference
from methods.val_clustered.method import ClusteredVirtualAreaLights as M

W, H = map(int, os.environ.get("RES", "320x180").split("x"))
SPP = int(os.environ.get("SPP", "512"))
SAVE = os.environ.get("SAVE")

def parse(v):
    for t in (int, float):
        try: return t(v)
        except ValueError: pass
    return v

variants = []
for a in sys.argv[2:]:
    name, _, kv = a.partition(":")
    variants.append((name, {k: parse(v) for k, v in (p.split("=") for p in kv.split(";") if p)}))
if not variants:
    variants = [("default", {})]
ctx = create_context()
for sv in sys.argv[1].split(","):
    sname, _, view = sv.partition("/")
    scene = load_scene(sname)
    views = [view] if view else list(scene.cameras)
    for v in views:
        ref = get_reference(scene, v, W, H, "indirect_visible", spp_cap=SPP)
        r, cov = ref.mean, ref.coverage
        d0 = relmse(np.zeros_like(r), r, cov)
        for name, params in variants:
            t0 = time.time()
            res = run_method(ctx, M, scene, v, W, H, params, seed=0, frames=1, shadow_resolution=512)
            img = res.indirect
            e = relmse(img, r, cov)
            mean = img[cov].mean() / r[cov].mean()
            fm = np.median(res.frame_ms)
            print(f"{sname}/{v:5s} {name:14s} relmse {e:8.4f} (direct {d0:.3f}) mean {mean:.3f} ms {fm:7.1f}  [{time.time()-t0:.0f}s]", flush=True)
            if SAVE:
                os.makedirs(SAVE, exist_ok=True)
                np.save(f"{SAVE}/{sname}_{v}_{name}.npy", img)
                np.save(f"{SAVE}/{sname}_{v}_ref.npy", r)
