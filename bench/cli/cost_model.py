"""`gibench cost-model RUNS... [--write]`: fit the cost model's prior from measured run folders and
say how well it predicts them (bench.run.cost); `--write` replaces the shipped prior
(bench/run/cost_prior.json) with it, its provenance (runs, rows, date, machine) recorded."""
from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import statistics
import sys
from pathlib import Path

from bench.run import cost


def add_parser(sub) -> None:
    p = sub.add_parser("cost-model", help="fit the run cost model's prior from run folders (--write ships it)")
    p.add_argument("runs", nargs="+", help="run folders whose rows were rendered (not from cache) on this machine")
    p.add_argument("--write", action="store_true", help=f"write the fitted prior to {cost.PRIOR_FILE.name}")
    p.set_defaults(func=main)


def main(args) -> int:
    samples = {}
    for run in args.runs:
        if not (Path(run) / "manifest.json").is_file():
            raise FileNotFoundError(f"{run}: not a run folder (no manifest.json)")
        samples[run] = cost.samples_from_run(Path(run))
    train = [s for group in samples.values() for s in group]
    if not train:
        print("gibench: no rendered row with timings in these runs: nothing to fit", file=sys.stderr)
        return 1
    provenance = {"runs": {Path(r).name: len(s) for r, s in samples.items()}, "rows": len(train),
                  "fitted": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d"),
                  "machine": f"{platform.machine()}, {os.cpu_count()} cores",
                  "command": "gibench cost-model " + " ".join(Path(r).name for r in args.runs) + " --write"}
    model = cost.CostModel.fit(train, cost.reference_metas(), provenance)
    runs = [cost.run_phases(Path(r)) for r in args.runs]
    runs = [r for r in runs if r is not None]
    if runs:   # set-up (against the scenes' triangles) and metrics per pixel, from the runs' manifests
        triangles = [max(r["triangles"], 1) for r in runs]
        if max(triangles) >= 2 * min(triangles):
            model.setup = cost.fit_linear([{"triangles": r["triangles"]} for r in runs], [r["setup_s"] for r in runs])
        else:   # runs of one corpus size say nothing of how set-up grows with it: a constant
            model.setup = cost.Linear(const=statistics.median(r["setup_s"] for r in runs))
        # the reference model (seconds per sample from the cached references' own Mitsuba time, to the
        # spp cap) against the references phase the last cold run measured (refinement stopping below
        # the cap, scene conversion, EXRs): predicted by this fit, not by the plan the run had (its
        # ratio, applied to a refitted per-sample cost, counted the correction twice: a quick run's
        # references took 84 s for 43 predicted)
        measured = [m for m in (cost.run_reference_seconds(model, Path(r)) for r in args.runs) if m is not None]
        if len(measured) >= 2:   # a scale on the samples and a start once per run (Mitsuba's import, its
            # kernels' compilation, the scenes in motion's few references): a quick run's 5 small views
            # took 48 s, the default run's 11 views 302 s
            fit = cost.fit_linear([{"samples": p} for _, p in measured], [a for a, _ in measured])
            model.reference_scale, model.reference_start_s = fit.coef.get("samples", 0.0) or 1.0, fit.const
        elif measured:
            model.reference_scale = measured[-1][0] / measured[-1][1]
        scales = [r["sequence_scale"] * r["sequences_ratio"] for r in runs if r.get("sequences_ratio")]
        if scales:   # the sequence rows' model against the sequence rows the last of these runs measured
            # (the sequence rows' prediction changed with the planner: older runs' ratios are of another model)
            model.sequence_scale = scales[-1]
        per_pixel = [r["metrics_s_per_pixel"] for r in runs if r.get("metrics_s_per_pixel")]
        if per_pixel:
            model.metrics_s_per_pixel = statistics.median(per_pixel)
    model.provenance["probe"] = fitting_machine_probe(runs)
    for run, group in samples.items():
        ratios = [p / a for p, a in (predicted_and_actual(model, s) for s in group) if a > 0]
        predicted = sum(predicted_and_actual(model, s)[0] for s in group)
        actual = sum(predicted_and_actual(model, s)[1] for s in group)
        if ratios:
            print(f"{run}: {len(group)} rows, rendering predicted {predicted:.0f} s, measured {actual:.0f} s "
                  f"(x{predicted / actual:.2f}); per row median x{statistics.median(ratios):.2f}")
    if args.write:
        cost.PRIOR_FILE.write_text(json.dumps(model.to_json(), indent=1, sort_keys=True) + "\n")
        print(f"wrote {cost.PRIOR_FILE}")
    return 0


def fitting_machine_probe(runs: list[dict]) -> dict:
    """The speed of the machine the runs were made on (bench.run.probe), which a plan on another
    machine scales the prior by: the median of what the runs' plans measured, or, for runs made
    before plans measured it, measured now (the runs must be this machine's, as the command says)."""
    from bench.run.probe import machine_probe
    probes = [r["probe"] for r in runs if isinstance(r.get("probe"), dict)]
    if probes:
        keys = sorted(set().union(*probes))
        return {k: statistics.median(p[k] for p in probes if isinstance(p.get(k), (int, float))) for k in keys}
    from bench.gl.context import create_context
    return machine_probe(create_context())


def predicted_and_actual(model: cost.CostModel, s: cost.Sample) -> tuple[float, float]:
    """A measured row's rendering seconds (preparation, timed and error frames, the rest) and the model's."""
    p = model.row(s.method, s.terms, frames=s.frames, warmup=s.warmup, timing_budget_s=s.timing_budget_s,
                  error_frames=s.error_frames, renders=s.error_renders, images=s.images, judged=False,
                  stage_frames=s.stage_frames)
    predicted = p["precompute"] + p["timing"] + p["error_frames"] + p["rows_other"]
    return predicted, s.prepare_s + s.frames_total_s + (s.error_s or 0.0) + (s.other_s or 0.0)
