"""A method's quality ladder over seeds: does a rung buy less error than the one before it, beyond noise?

Issue #23 asks that along a method's ladder (`Method.ladder`, fast -> accurate) the error never rises by
more than 10% from one rung to the next "beyond noise". One seed's frames cannot tell: `val_clustered`
draws its VPLs once per seed (the paper's fixed pattern), so its error frames are one draw, and its
seed-0 ladder on sponza read 1.72, 0.80, 0.61, 0.85 where six seeds give 1.20, 0.77, 0.71, 0.70. This
study renders every rung at seeds 0..S-1 (one frame each, the image a fresh instance gives) and
compares the `indirect` image with the matching Mitsuba reference (studies.vpl_near_field.MATCHING):

  relmse     mean over seeds of the single-frame relMSE, with its 95% interval over seeds
  mean       image mean / reference mean, mean over seeds
  top20      share of a frame's squared error in its 20 worst pixels, mean over seeds
  step       relMSE of this rung over the previous rung's, the ratio of the seed means, with a 95%
             interval from the seeds' paired differences (the same seed's VPLs on both rungs
             cancel much of the noise); `RISE` when the ratio's lower bound exceeds 1.10, i.e. a rise
             of more than 10% that the seeds cannot explain

    python -m studies.ladder_over_seeds --scenes sponza,lost_empire --methods val_clustered --seeds 6

`--param NAME=VALUE` (repeatable) sets a parameter on every rung. Prints one Markdown table; `--out`
also writes it.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from bench.gl import GpuScene, create_context
from bench.model.corpus import load_scene
from bench.model.scene import compute_facts
from bench.protocol.registry import load_method
from bench.run.config import auto_shadow_resolution
from bench.run.harness import run_method
from reference.api import get_reference
from studies.vpl_near_field import MATCHING, frame_figures

Z95 = 1.96
RISE_LIMIT = 1.10   # issue #23: no rung more than 10% above the one before


def step_figures(previous: np.ndarray, current: np.ndarray) -> dict:
    """The ratio of the seed means of two rungs' per-seed errors (paired by seed) and its 95% interval
    (delta method on the mean paired difference: ratio = 1 + mean(d) / mean(previous))."""
    previous, current = np.asarray(previous, float), np.asarray(current, float)
    if previous.shape != current.shape or previous.size == 0:
        raise ValueError("the two rungs need the same seeds")
    base = float(previous.mean())
    if not base > 0.0:
        return {"ratio": float("nan"), "low": float("nan"), "high": float("nan"), "rise": False}
    d = current - previous
    half = Z95 * float(d.std(ddof=1)) / np.sqrt(d.size) / base if d.size > 1 else float("inf")
    ratio = 1.0 + float(d.mean()) / base
    return {"ratio": ratio, "low": ratio - half, "high": ratio + half, "rise": bool(ratio - half > RISE_LIMIT)}


def parse_overrides(items) -> dict:
    """`k=v` strings -> {k: v} (numbers as numbers), the same on every rung."""
    out = {}
    for item in items or ():
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise SystemExit(f"--param {item!r}: expected NAME=VALUE")
        for cast in (int, float):
            try:
                out[key] = cast(value)
                break
            except ValueError:
                continue
        else:
            out[key] = {"true": True, "false": False}.get(value.lower(), value)
    return out


def study(scenes, methods, seeds: int, width: int, height: int, spp: int, log=print, overrides=None) -> list[dict]:
    if seeds < 2:
        raise ValueError(f"--seeds must be at least 2 for an interval over seeds, got {seeds}")
    ctx = create_context()
    rows = []
    for scene_name in scenes:
        scene = load_scene(scene_name)
        facts = compute_facts(scene)
        gpu = GpuScene(ctx, scene, seed=0, facts=facts)
        try:
            for view in sorted(scene.cameras):
                for method in methods:
                    if method not in MATCHING:
                        raise SystemExit(f"method {method!r} has no matching reference here (one of {sorted(MATCHING)})")
                    r = get_reference(scene, view, width, height, MATCHING[method], spp_cap=spp)
                    ref, mask = r.mean.astype(np.float64), r.coverage
                    cls = load_method(method)
                    previous = None
                    for rung, params in enumerate(cls.ladder or ({},)):
                        figures = []
                        for seed in range(seeds):
                            res = run_method(ctx, cls, scene, view, width, height, {**params, **(overrides or {})},
                                             seed=seed, warmup=1, frames=1, facts=facts, gpu=gpu,
                                             shadow_resolution=auto_shadow_resolution(width, height))
                            figures.append(frame_figures(res.indirect, ref, mask))
                        errors = np.array([f["relmse"] for f in figures])
                        row = {"scene": f"{scene_name}/{view}", "method": method, "rung": rung,
                               "params": ",".join(f"{k}={v}" for k, v in params.items()) or "(defaults)",
                               "per_seed": errors, "relmse": float(errors.mean()),
                               "ci": Z95 * float(errors.std(ddof=1)) / np.sqrt(errors.size),
                               "mean_ratio": float(np.mean([f["mean_ratio"] for f in figures])),
                               "top20": float(np.mean([f["top20"] for f in figures])),
                               "step": step_figures(previous, errors) if previous is not None else None}
                        previous = errors
                        rows.append(row)
                        step = row["step"]
                        log(f"{row['scene']:18s} {method:16s} rung {rung} {row['params']:40s} relmse {row['relmse']:.4g} "
                            f"+- {row['ci']:.2g} mean {row['mean_ratio']:.3f} top20 {row['top20']:.2f}"
                            + (f" step {step['ratio']:.3f} [{step['low']:.3f}, {step['high']:.3f}]"
                               f"{' RISE' if step['rise'] else ''}" if step else ""))
        finally:
            gpu.release()
    return rows


def markdown(rows: list[dict]) -> str:
    lines = ["| view | method | rung | relMSE +- 95% (per seed) | mean ratio | top-20 share | step over previous rung [95%] |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        seeds = ", ".join(f"{e:.3g}" for e in r["per_seed"])
        s = r["step"]
        step = (f"{s['ratio']:.3f} [{s['low']:.3f}, {s['high']:.3f}]{' **RISE**' if s['rise'] else ''}" if s else "")
        lines.append(f"| {r['scene']} | {r['method']} | {r['params']} | {r['relmse']:.3g} +- {r['ci']:.2g} ({seeds}) | "
                     f"{r['mean_ratio']:.3f} | {r['top20']:.2f} | {step} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", required=True)
    p.add_argument("--methods", default="val_clustered")
    p.add_argument("--seeds", type=int, default=6)
    p.add_argument("--res", default="320x180")
    p.add_argument("--spp", type=int, default=512, help="reference spp cap (cached)")
    p.add_argument("--param", action="append", help="NAME=VALUE on every rung (repeatable)")
    p.add_argument("--out", default=None)
    args = p.parse_args(argv)
    width, height = (int(v) for v in args.res.split("x"))
    rows = study(args.scenes.split(","), args.methods.split(","), args.seeds, width, height, args.spp,
                 log=lambda m: print(m, file=sys.stderr, flush=True), overrides=parse_overrides(args.param))
    table = markdown(rows)
    print(table)
    if args.out:
        Path(args.out).write_text(table + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
