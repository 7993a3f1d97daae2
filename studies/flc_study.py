"""FLC's single-frame study at its defaults (issue 10), the tables of methods/flc/NOTES.md from one command:

    python -m studies.flc_study --res 320x180 --seeds 8 --jitter-frames 4 \\
        cornell_spot hidden_bounce big_floor rooms rooms:far sphere_inside lit_wall_corner cornell_box

Per scene[:view], one FLC frame per seed (0 .. seeds-1) at the defaults (or `--param k=v`):
- against jittered `manylights` with the flc lobe (the sum FLC estimates; big_floor's on
  `flc_analysis.refined_scene(scene, 0.5)`, its 80 m floor is 2 triangles): the image-mean ratio, its
  relative spread across seeds (std / mean), the per-pixel relMSE (`bench.analysis.metrics.relmse`) and
  what a black image (`direct`) scores; skipped with `--jitter-frames 0` (on the real scenes
  `manylights` sums 10^5 triangles at every pixel: use a small `--res` there);
- against the Mitsuba unshadowed one-bounce reference (cached; rendered on a miss): relmse.indirect
  mean and max over the seeds and `direct`'s;
- FLC's own stages (regular + divergent + upscale_blur), median over the seeds, ms.
With `--n-avg 64,128,...` it sweeps N_avg instead and prints, per scene, at each value the Mitsuba
error and the relMSE against jittered `manylights` (mean over the seeds; the latter skipped with
`--jitter-frames 0`), FLC's own time and its log-log slope against N_avg.
"""
from __future__ import annotations

import argparse
import json

import numpy as np

from bench.analysis import metrics
from bench.gl.context import create_context
from bench.model.corpus import load_scene
from bench.model.scene import compute_facts
from bench.run.harness import run_method
from methods.flc.method import ForwardLightCuts
from methods.manylights.method import ManyLights
from reference.api import get_reference
from reference.env import ReferenceUnavailable
from studies.flc_analysis import refined_scene, single_frame_study

OWN_STAGES = ForwardLightCuts.stages


def _own_ms(result) -> float:
    return sum(float(np.median(result.stage_ms[k])) for k in OWN_STAGES if k in result.stage_ms)


def _mitsuba(scene, view, width, height):
    try:
        return get_reference(scene, view, width, height, "indirect_unshadowed", spp_cap=1024)
    except ReferenceUnavailable:
        return None


def study_view(ctx, name: str, view: str, width: int, height: int, seeds, params: dict, jitter_frames: int) -> dict:
    """The figures of one view (see the module docstring), from `flc_analysis.single_frame_study`."""
    scene = load_scene(name)
    study = single_frame_study(ctx, scene, view, width, height, seeds, params, jitter_frames=jitter_frames,
                               reference_scene=_reference_scene(scene, name),
                               mitsuba=_mitsuba(scene, view, width, height))
    out: dict = {"scene": name, "view": view, "own_ms": float(np.median(study["splat_ms"]))}
    if "ratio" in study:
        out.update(ml_ratio=study["ratio_mean"], ml_spread=study["ratio_spread"],
                   ml_relmse=float(study["relmse_pixel"].mean()), ml_relmse_black=study["relmse_pixel_black"])
    if "mitsuba_relmse" in study:
        out.update(mitsuba_relmse=float(study["mitsuba_relmse"].mean()),
                   mitsuba_relmse_max=float(study["mitsuba_relmse"].max()),
                   mitsuba_relmse_direct=study["mitsuba_relmse_direct"])
    return out


def _reference_scene(scene, name: str):
    """big_floor's 80 m floor is 2 triangles: `manylights` (one VPL per triangle) runs on it cut finer."""
    return refined_scene(scene, 0.5) if name == "big_floor" else scene


def _manylights(ctx, scene, name: str, view: str, width: int, height: int, jitter_frames: int) -> np.ndarray:
    """Jittered `manylights` with the flc lobe: the sum FLC estimates (big_floor's on its refined scene)."""
    ref_scene = _reference_scene(scene, name)
    return run_method(ctx, ManyLights, ref_scene, view, width, height,
                      {"emission": "flc", "jitter_frames": jitter_frames}, seed=99, frames=1,
                      facts=compute_facts(ref_scene)).indirect.astype(np.float64)


def _falls(errors) -> bool:
    return all(a > b for a, b in zip(errors, errors[1:]))


def sweep_view(ctx, name: str, view: str, width: int, height: int, seeds, params: dict, n_avgs,
               jitter_frames: int = 0) -> dict:
    """At each N_avg: Mitsuba relmse.indirect (mean over seeds), the per-pixel relMSE against jittered
    `manylights` with the flc lobe (the sum FLC estimates; with `jitter_frames` > 0), FLC's own time,
    and the time's log-log slope against N_avg."""
    scene = load_scene(name)
    facts = compute_facts(scene)
    ref = _mitsuba(scene, view, width, height)
    ml = _manylights(ctx, scene, name, view, width, height, jitter_frames) if jitter_frames > 0 else None
    errors, ml_errors, times = [], [], []
    for n in n_avgs:
        e, m, t = [], [], []
        for s in seeds:
            r = run_method(ctx, ForwardLightCuts, scene, view, width, height, dict(params, n_avg=n), seed=s,
                           frames=1, facts=facts)
            if ref is not None:
                e.append(metrics.relmse(r.indirect, ref.mean, ref.coverage))
            if ml is not None:
                m.append(metrics.relmse(r.indirect, ml))
            t.append(_own_ms(r))
        errors.append(float(np.mean(e)) if e else float("nan"))
        ml_errors.append(float(np.mean(m)) if m else float("nan"))
        times.append(float(np.median(t)))
    slope = float(np.polyfit(np.log(n_avgs), np.log(times), 1)[0])
    out = {"scene": name, "view": view, "n_avg": list(n_avgs), "mitsuba_relmse": errors, "own_ms": times,
           "time_slope": slope, "error_falls_every_step": _falls(errors)}
    if ml is not None:
        out.update(ml_relmse=ml_errors, ml_error_falls_every_step=_falls(ml_errors))
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="python -m studies.flc_study", description=__doc__.splitlines()[0])
    ap.add_argument("views", nargs="+", help="scene or scene:view")
    ap.add_argument("--res", default="320x180")
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--jitter-frames", type=int, default=4, help="jittered manylights frames (0: skip)")
    ap.add_argument("--n-avg", default="", help="comma-separated N_avg values: sweep instead")
    ap.add_argument("--param", action="append", default=[], help="flc parameter k=v (JSON value)")
    args = ap.parse_args(argv)
    width, height = (int(v) for v in args.res.lower().split("x"))
    params = {}
    for item in args.param:
        key, _, value = item.partition("=")
        try:
            params[key] = json.loads(value)
        except json.JSONDecodeError:
            params[key] = value
    ctx = create_context()
    seeds = range(args.seeds)
    for item in args.views:
        name, _, view = item.partition(":")
        view = view or "main"
        if args.n_avg:
            row = sweep_view(ctx, name, view, width, height, seeds, params, [int(v) for v in args.n_avg.split(",")],
                             args.jitter_frames)
        else:
            row = study_view(ctx, name, view, width, height, seeds, params, args.jitter_frames)
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
