"""The VPL family's near field over the corpus (issue #23): bias, variance and spikes of each bound.

Every VPL method (ir_unshadowed, ir_shadowed, val_clustered, visibility_gates) sums one transfer
term, bench/gl/shaders/vpl_records.glsl's vpl_transfer, whose 1/d^2 must be bounded near a
VPL (bench.gl.vpl.NEAR_FIELDS). This study renders a method with each near field over the given
scenes and seeds and compares the `indirect` image with the matching Mitsuba reference
(indirect_unshadowed for ir_unshadowed, indirect_visible for the methods with visibility):

  relmse       mean over seeds of the single-frame relMSE (bench.analysis.metrics.relmse)
  mean_ratio   image mean / reference mean on covered pixels, mean over seeds (bias in the mean)
  accum        relMSE of the mean image over the seeds (what averaging frames reaches: the bias)
  top20        share of a frame's squared error held by its 20 worst pixels (mean over seeds)
  max_ref      brightest pixel of the image over the reference's brightest (max over seeds)

    python -m studies.vpl_near_field --scenes cornell_box,sponza --methods ir_unshadowed \\
        --configs clamp:1e-4,disc_element,footprint:1,footprint:0.25 --counts 64,256,1024 --seeds 4

Configs: `clamp:EPS_REL` (max(eps, d)^2, eps relative to the scene radius), `disc_element`
(d^2 + A/pi), `footprint:S` (max(d^2, S A/pi)). Prints one Markdown table; `--out` also writes it.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from bench.analysis.metrics import relmse
from bench.gl import GpuScene, create_context
from bench.model.corpus import load_scene
from bench.model.scene import compute_facts
from bench.protocol.registry import load_method
from bench.run.config import auto_shadow_resolution
from bench.run.harness import run_method
from reference.api import get_reference

MATCHING = {"ir_unshadowed": "indirect_unshadowed", "ir_shadowed": "indirect_visible",
            "val_clustered": "indirect_visible", "visibility_gates": "indirect_visible", "dss": "indirect_unshadowed"}
COUNT_PARAM = {"ir_unshadowed": "vpl_count", "ir_shadowed": "vpl_count", "val_clustered": "vpl_count",
               "visibility_gates": "vpl_count", "dss": "surfel_count"}


EPS_PARAM = {"dss": "eps_rel"}   # the others: clamp_distance_rel


def parse_config(text: str, method: str) -> dict:
    kind, _, value = text.partition(":")
    if kind == "clamp":
        return {"near_field": "clamp", EPS_PARAM.get(method, "clamp_distance_rel"): float(value or 1e-4)}
    if kind == "disc_element":
        return {"near_field": "disc_element"}
    if kind == "footprint":
        return {"near_field": "footprint", "near_field_scale": float(value or 1.0)}
    raise SystemExit(f"unknown near-field config {text!r} (clamp:EPS_REL, disc_element, footprint:S)")


def frame_figures(image: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> dict:
    err = ((image.astype(np.float64) - ref) ** 2).sum(axis=2)[mask]
    total = float(err.sum())
    top = float(np.sort(err)[-20:].sum()) if err.size else 0.0
    ref_mean = float(ref[mask].mean()) if mask.any() else 0.0
    return {"relmse": float(relmse(image, ref, mask)),
            "mean_ratio": float(image[mask].mean()) / ref_mean if ref_mean > 0 else float("nan"),
            "top20": top / total if total > 0 else 0.0,
            "max_ref": float(image[mask].max()) / max(float(ref[mask].max()), 1e-30) if mask.any() else float("nan")}


def study(scenes, methods, configs, counts, seeds, width, height, spp, log=print) -> list[dict]:
    ctx = create_context()
    rows = []
    for scene_name in scenes:
        scene = load_scene(scene_name)
        facts = compute_facts(scene)
        gpu = GpuScene(ctx, scene, seed=0, facts=facts)
        try:
            for view in sorted(scene.cameras):
                refs = {}
                for method in methods:
                    component = MATCHING[method]
                    if component not in refs:
                        r = get_reference(scene, view, width, height, component, spp_cap=spp)
                        refs[component] = (r.mean.astype(np.float64), r.coverage)
                    ref, mask = refs[component]
                    cls = load_method(method)
                    for config in configs:
                        for count in counts:
                            params = dict(parse_config(config, method), **{COUNT_PARAM[method]: count})
                            images, figures = [], []
                            for seed in range(seeds):
                                res = run_method(ctx, cls, scene, view, width, height, params, seed=seed, warmup=1,
                                                 frames=1, facts=facts, gpu=gpu,
                                                 shadow_resolution=auto_shadow_resolution(width, height))
                                images.append(res.indirect.astype(np.float64))
                                figures.append(frame_figures(res.indirect, ref, mask))
                            accum = float(relmse(np.mean(images, axis=0), ref, mask))
                            row = {"scene": f"{scene_name}/{view}", "method": method, "config": config, "count": count,
                                   "relmse": np.mean([f["relmse"] for f in figures]),
                                   "relmse_sd": np.std([f["relmse"] for f in figures]),
                                   "mean_ratio": np.mean([f["mean_ratio"] for f in figures]),
                                   "accum": accum, "top20": np.mean([f["top20"] for f in figures]),
                                   "max_ref": np.max([f["max_ref"] for f in figures])}
                            rows.append(row)
                            log(f"{row['scene']:22s} {method:16s} {config:16s} {count:5d}  relmse {row['relmse']:.4g} "
                                f"(sd {row['relmse_sd']:.2g}) mean {row['mean_ratio']:.3f} accum {accum:.4g} "
                                f"top20 {row['top20']:.2f} max/ref {row['max_ref']:.2f}")
        finally:
            gpu.release()
    return rows


def markdown(rows: list[dict]) -> str:
    lines = ["| view | method | near field | N | relMSE (sd) | mean ratio | accumulated relMSE | top-20 share | max/ref |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['method']} | {r['config']} | {r['count']} | {r['relmse']:.3g} "
                     f"({r['relmse_sd']:.2g}) | {r['mean_ratio']:.3f} | {r['accum']:.3g} | {r['top20']:.2f} | "
                     f"{r['max_ref']:.2f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", required=True)
    p.add_argument("--methods", default="ir_unshadowed")
    p.add_argument("--configs", default="clamp:1e-4,disc_element,footprint:1")
    p.add_argument("--counts", default="256")
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--res", default="320x180")
    p.add_argument("--spp", type=int, default=1024, help="reference spp cap (cached)")
    p.add_argument("--out", default=None)
    args = p.parse_args(argv)
    width, height = (int(v) for v in args.res.split("x"))
    rows = study(args.scenes.split(","), args.methods.split(","), args.configs.split(","),
                 [int(c) for c in args.counts.split(",")], args.seeds, width, height, args.spp,
                 log=lambda m: print(m, file=sys.stderr, flush=True))
    table = markdown(rows)
    print(table)
    if args.out:
        Path(args.out).write_text(table + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
