"""val_clustered's stage times at the paper's setting and at the defaults (issue #23, NOTES.md):
per-stage minima over 3 frames after a warm-up, each setting twice, in one process.
usage: python studies/val_clustered_cost.py SCENE,... (env RES=320x180)"""
import os
import sys

from bench.gl import create_context
from bench.model.corpus import load_scene
from bench.run.harness import run_method
from methods.val_clustered.method import ClusteredVirtualAreaLights as M

PAPER = {"val_origin": "centre", "near_ignore": 0.5, "cssm_kernel": "lod", "fourier_terms": 4, "interleave": 8,
         "csm_depth_range": "unit"}
W, H = map(int, os.environ.get("RES", "320x180").split("x"))

ctx = create_context()
for sname in sys.argv[1].split(","):
    scene = load_scene(sname)
    for name, params in (("paper", PAPER), ("defaults", {})) * 2:
        r = run_method(ctx, M, scene, "main", W, H, params, seed=0, frames=3, warmup=1)
        stages = {k: min(v) for k, v in r.stage_ms.items() if k in M.stages}
        print(f"{sname} {name:8s} stages {sum(stages.values()):6.0f} ms  "
              + " ".join(f"{k} {v:.0f}" for k, v in stages.items()), flush=True)
