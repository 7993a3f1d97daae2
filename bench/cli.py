"""`gibench` command line: run, list, report, gate, reference, sweep, stress.

Exit codes: 0 success; 1 nothing useful produced (every row of a run failed), a gate
regression, or a missing dependency (Mitsuba); 2 bad input (one line naming the culprit: a
scene, a parameter, an unusable --out, a corrupt results table, a gate that compared nothing);
130 interrupted (re-run the same command to resume, with or without --force).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

# The purpose-built procedural scenes (each isolates one difficulty) and real scenes, the FLC
# paper's kind of comparison (sponza, sibenik, conference: real interiors of 66k-331k triangles).
DEFAULT_SCENES = ("cornell_spot", "hidden_bounce", "big_floor", "sphere_inside", "rooms", "lit_wall_corner",
                  "cornell_box", "sponza", "sibenik", "conference")
# `--quick`: a first useful report in minutes: two procedural scenes and one real one, the fast and
# the default rung of each ladder, a short timing budget
QUICK_SCENES = ("cornell_spot", "rooms", "sponza")
REFERENCE_SPP = 1024        # reference spp cap of `run` and `sweep`
QUICK_REFERENCE_SPP = 256   # --quick: a first report; the reference floor shows as wider intervals
SHADOW_RESOLUTION_RANGE = (16, 8192)   # --shadow-resolution: one tile of the shared atlas (GL's 16384 limit)
DEFAULT_RESOLUTION = (320, 180)   # the design point of the interleaved screen-space methods starts here
DEFAULT_METHODS = ("direct", "ir_unshadowed", "ir_shadowed", "manylights", "flc", "ssdo", "dss", "val_clustered", "pbgi",
                   "visibility_gates")


def _csv(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def _resolution(text: str) -> tuple[int, int]:
    try:
        w, h = text.lower().split("x")
        return int(w), int(h)
    except ValueError:
        raise argparse.ArgumentTypeError(f"resolution must be WxH, got {text!r}") from None


def _shadow_resolution(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"shadow resolution must be an integer, got {text!r}") from None
    if not SHADOW_RESOLUTION_RANGE[0] <= value <= SHADOW_RESOLUTION_RANGE[1]:
        raise argparse.ArgumentTypeError(f"shadow resolution must be in {SHADOW_RESOLUTION_RANGE[0]}.."
                                         f"{SHADOW_RESOLUTION_RANGE[1]}, got {value}")
    return value


def _parse_value(text: str):
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def _param_sets(items: list[str]) -> dict:
    """`--param flc.N_avg=128` (one value) or `--param flc.N_avg=64,128,256` (a grid)."""
    grid: dict = {}
    for item in items or []:
        if "=" not in item or "." not in item.split("=", 1)[0]:
            raise SystemExit(f"gibench: --param expects METHOD.NAME=VALUE[,VALUE...], got {item!r}")
        lhs, rhs = item.split("=", 1)
        method, name = lhs.split(".", 1)
        grid.setdefault(method, {})[name] = [_parse_value(v) for v in rhs.split(",")]
    out = {}
    for method, knobs in grid.items():
        sets = [{}]
        for name, values in knobs.items():
            sets = [dict(s, **{name: v}) for s in sets for v in values]
        out[method] = sets
    return out


def cmd_list(args) -> int:
    if args.what == "methods":
        from bench.registry import MethodLoadError, entry_point_target, list_methods, load_method
        for name in list_methods():
            if args.verbose:
                try:
                    cls = load_method(name)
                    print(f"{name:16s} {cls.summary}")
                except MethodLoadError as exc:
                    print(f"{name:16s} (fails to load: {exc})")
            else:
                print(f"{name:16s} {entry_point_target(name)}")
        return 0
    from bench.corpus import list_scenes
    for entry in list_scenes():
        print(f"{entry.name:18s} {entry.triangle_count:>10,d} tris  {entry.purpose}")
    return 0


def _known_methods(methods: list[str]) -> bool:
    """False (and a one-line message) when a method name is not registered."""
    from bench.registry import list_methods
    unknown = [m for m in methods if m not in list_methods()]
    if unknown:
        print(f"gibench: unknown method(s) {', '.join(unknown)}; registered: {', '.join(list_methods())}", file=sys.stderr)
    return not unknown


def cmd_run(args) -> int:
    from bench.runner import RunConfig, run
    methods = _csv(args.methods)
    if not _known_methods(methods):
        return 2
    width, height = args.res
    params = _param_sets(args.param)
    scenes = _csv(args.scenes) if args.scenes else list(QUICK_SCENES if args.quick else DEFAULT_SCENES)
    budget = args.timing_budget if args.timing_budget is not None else (0.3 if args.quick else 1.0)
    if args.quick and not args.defaults_only:
        params = _quick_rungs(methods, params)
    cfg = RunConfig(scenes=scenes, methods=methods, width=width, height=height, frames=args.frames,
                    warmup=args.warmup, seed=args.seed, out=Path(args.out) if args.out else None, force=args.force,
                    views=_csv(args.views) if args.views else None, params=params,
                    references=not args.no_reference,
                    reference_spp_cap=args.reference_spp or (QUICK_REFERENCE_SPP if args.quick else REFERENCE_SPP),
                    progress=not args.no_progress, ladders=not args.defaults_only,
                    timing_budget_s=budget if budget > 0 else None, scheduler=args.scheduler, workers=args.workers,
                    shadow_resolution=args.shadow_resolution)
    df, runner = run(cfg, log=lambda m: print(m, file=sys.stderr))
    print(runner.summary())
    print(f"results: {runner.run_dir / 'results.csv'}")
    return _nothing_useful(runner)


def _quick_rungs(methods: list[str], params: dict) -> dict:
    """--quick: the fastest rung and the defaults of each ladder (a two-point curve), unless --param sets them."""
    from bench.registry import MethodLoadError, load_method
    out = dict(params)
    for m in methods:
        if m in out:
            continue
        try:
            ladder = load_method(m).ladder
        except MethodLoadError:
            continue
        if ladder:
            out[m] = [dict(ladder[0])] + ([{}] if dict(ladder[0]) else [])
    return out


def _nothing_useful(runner) -> int:
    """1 (and one line) when every row of the run failed, else 0."""
    c = runner.counts
    if c["failed"] and not (c["ok"] or c["cached"] or c["resumed"] or c["skipped"]):
        print(f"gibench: every row failed ({c['failed']} rows): nothing was measured", file=sys.stderr)
        return 1
    return 0


def cmd_report(args) -> int:
    run_dir = Path(args.run)
    if not any((run_dir / f).is_file() for f in ("results.csv", "results.parquet", "stress.csv")):
        print(f"gibench: {run_dir} is not a run folder (no results.csv or stress.csv)", file=sys.stderr)
        return 2
    try:
        from reports import build_report
    except ImportError:  # the comparison report is optional; the quick summary always exists
        from bench.summary import write_summary
        _, path = write_summary(run_dir)
    else:
        import time
        t0 = time.perf_counter()
        path = build_report(run_dir, Path(args.out) if args.out else None)
        _record_phase(run_dir, "report", time.perf_counter() - t0)
    print(f"report: {path}")
    return 0


def _record_phase(run_dir: Path, phase: str, seconds: float) -> None:
    """Add a phase's wall time to the run's manifest (the run records its own phases)."""
    from bench import results as store
    path = run_dir / "manifest.json"
    try:
        manifest = json.loads(path.read_text())
    except (OSError, ValueError):
        return
    manifest.setdefault("phases_s", {})[phase] = round(seconds, 3)
    store.atomic_write_text(path, json.dumps(manifest, indent=2, default=str))


def cmd_sweep(args) -> int:
    from bench.sweep import run_sweep
    methods = _csv(args.methods)
    if not _known_methods(methods):
        return 2
    width, height = args.res
    table, pareto, runner = run_sweep(
        _csv(args.scenes), methods, log=lambda m: print(m, file=sys.stderr), width=width, height=height,
        frames=args.frames, warmup=args.warmup, seed=args.seed, out=Path(args.out) if args.out else None,
        force=args.force, views=_csv(args.views) if args.views else None, references=not args.no_reference,
        reference_spp_cap=args.reference_spp or REFERENCE_SPP, progress=not args.no_progress,
        shadow_resolution=args.shadow_resolution)
    print(runner.summary())
    print(f"{len(table)} sweep points, {len(pareto)} on the Pareto fronts")
    print(f"sweep: {runner.run_dir / 'sweep.csv'}")
    print(f"pareto: {runner.run_dir / 'pareto.csv'}")
    return _nothing_useful(runner)


def cmd_stress(args) -> int:
    """The numerical stability stress suite (bench.stress): exit 1 when a row fails."""
    from bench.stress import STRESS_SCENES, StressConfig, run_stress, summary_text
    methods = _csv(args.methods)
    if not _known_methods(methods):
        return 2
    width, height = args.res if args.res else (None, None)
    cfg = StressConfig(scenes=_csv(args.scenes) if args.scenes else list(STRESS_SCENES), methods=methods,
                       width=width, height=height, quick=args.quick, out=Path(args.out) if args.out else None,
                       seed=args.seed, views=_csv(args.views) if args.views else None, references=not args.no_reference,
                       reference_spp=args.reference_spp, isolate=args.isolate, case_timeout=args.timeout,
                       fuzz_examples=args.fuzz_examples, families=_csv(args.only) if args.only else None)
    df, suite = run_stress(cfg, log=lambda m: print(m, file=sys.stderr))
    print(summary_text(df))
    print(f"stress table: {suite.run_dir / 'stress.csv'}")
    if (suite.run_dir / "stress.html").is_file():
        print(f"stress report: {suite.run_dir / 'stress.html'}")
    return 1 if (df["verdict"] == "fail").any() else 0


def cmd_gate(args) -> int:
    from bench.gate import compare_runs
    result = compare_runs(_csv(args.baseline), _csv(args.candidate), time_threshold=args.time_threshold,
                          error_threshold=args.error_threshold, alpha=args.alpha,
                          compare_changed_versions=args.compare_changed_versions, relative_to=args.relative_to,
                          correction=args.correction, min_runs=args.min_runs)
    print(result.markdown())
    return result.exit_code


def cmd_reference(args) -> int:
    from reference.api import ReferenceUnavailable
    from bench.distributed import build_references
    width, height = args.res
    try:
        build_references(_csv(args.scenes), width=width, height=height, spp_cap=args.spp, scheduler=args.scheduler,
                         workers=args.workers)
    except ReferenceUnavailable as exc:
        print(f"gibench: {str(exc).splitlines()[0] if str(exc) else 'Mitsuba 3 is unavailable'}", file=sys.stderr)
        return 1
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="gibench", description="Benchmark real-time diffuse GI against Mitsuba 3.")
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run methods over scenes")
    sweep = sub.add_parser("sweep", help="run methods across their quality knobs: time-vs-error curves, Pareto fronts")
    for p in (run, sweep):  # a sweep is a run over parameter grids: the same options
        p.add_argument("--scenes", default=None if p is run else ",".join(DEFAULT_SCENES),
                       help="corpus names or .toml scene files, comma-separated (default: "
                            + ",".join(DEFAULT_SCENES) + ")")
        p.add_argument("--methods", default=",".join(DEFAULT_METHODS))
        p.add_argument("--views", default=None, help="camera names (default: every camera of each scene)")
        p.add_argument("--res", type=_resolution, default=DEFAULT_RESOLUTION,
                       help="WxH (default %dx%d)" % DEFAULT_RESOLUTION)
        p.add_argument("--frames", type=int, default=3, help="timed frames per row (the minimum, with a timing budget)")
        p.add_argument("--warmup", type=int, default=1, help="untimed warm-up frames (>= 1; frame 0 gives the images)")
        p.add_argument("--seed", type=int, default=0)
        p.add_argument("--out", default=None, help="run folder (default runs/<timestamp>, runs/latest points to it)")
        p.add_argument("--force", action="store_true", help="re-run rows found in the cache")
        p.add_argument("--no-reference", action="store_true", help="skip Mitsuba references, error metrics and speed-ups")
        p.add_argument("--reference-spp", type=int, default=None,
                       help="spp cap of the references (default 1024, 256 with run --quick; they stop earlier, at 1/10 of the best "
                            "method's MSE; a floor above that shows as wider intervals and lower-bound speed-ups). "
                            "4096 takes ~4x the reference time")
        p.add_argument("--no-progress", action="store_true")
        p.add_argument("--shadow-resolution", type=_shadow_resolution, default=None, metavar="N",
                       help="side of each light's shadow map tile (default: the smallest power of two >= the image's "
                            "longer side, within 256..2048)")
    run.add_argument("--param", action="append", help="METHOD.NAME=VALUE[,VALUE...] (repeatable; lists make a grid)")
    run.add_argument("--timing-budget", type=float, default=None, metavar="SECONDS",
                     help="calibrated timing: after --frames frames, time more until the median's 95%% interval is "
                          "within 5%% or SECONDS of frames are spent (default 1.0, 0.3 with --quick; 0: exactly --frames)")
    run.add_argument("--workers", type=int, default=None, metavar="N",
                     help="run rows and references as Dask tasks on a local cluster of N processes (timed rows "
                          "still one at a time per machine)")
    run.add_argument("--scheduler", default=None, metavar="ADDRESS",
                     help="run rows and references on an existing dask.distributed cluster (tcp://host:8786)")
    run.add_argument("--quick", action="store_true",
                     help="a first report in minutes: scenes " + ",".join(QUICK_SCENES)
                          + " (unless --scenes), the fastest and the default rung of each ladder, timing budget 0.3 s, "
                          "references capped at %d spp (unless --reference-spp)" % QUICK_REFERENCE_SPP)
    run.add_argument("--defaults-only", action="store_true",
                     help="run each method at its defaults only (default: its quality ladder, fast -> accurate, "
                          "one time-vs-error curve per method; a method given --param runs those sets instead)")
    run.set_defaults(func=cmd_run)
    sweep.set_defaults(func=cmd_sweep)

    p = sub.add_parser("stress", help="numerical stability stress suite: perturbed scenes, parameter extremes, fuzzing")
    p.add_argument("--scenes", default=None, help="corpus names or .toml scene files, comma-separated "
                                                  "(default: the procedural scenes of bench.stress.STRESS_SCENES)")
    p.add_argument("--methods", default=",".join(DEFAULT_METHODS))
    p.add_argument("--views", default=None, help="camera to perturb, first found per scene (default: main)")
    p.add_argument("--res", type=_resolution, default=None, help="WxH (default 64x48; 32x24 with --quick)")
    p.add_argument("--quick", action="store_true", help="the CI subset: few perturbations, 32x24, 16 spp references")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="run folder (default runs/stress-<timestamp>)")
    p.add_argument("--no-reference", action="store_true", help="skip the Mitsuba references (no reference rows, no error)")
    p.add_argument("--reference-spp", type=int, default=None, help="reference samples per pixel (default 64; 16 with --quick)")
    p.add_argument("--isolate", choices=("none", "params", "all"), default=None,
                   help="cases run in a child process with a timeout (default: params; none with --quick)")
    p.add_argument("--timeout", type=float, default=300.0, help="seconds per isolated case")
    p.add_argument("--fuzz-examples", type=int, default=None, help="hypothesis examples (default 500; 50 with --quick)")
    p.add_argument("--only", default=None, help="perturbation families, comma-separated (default: all of "
                                                "determinism,scale,translate,degenerate,grazing,params,invalid,fuzz)")
    p.set_defaults(func=cmd_stress)

    p = sub.add_parser("list", help="list methods or scenes")
    p.add_argument("what", choices=("methods", "scenes"))
    p.add_argument("-v", "--verbose", action="store_true", help="methods: import each to show its summary")
    p.set_defaults(func=cmd_list)

    p = sub.add_parser("report", help="build the HTML report of a run")
    p.add_argument("run", help="run folder (e.g. runs/latest)")
    p.add_argument("--out", default=None)
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("gate", help="compare two runs; non-zero exit on a regression")
    p.add_argument("baseline", help="run folder, or comma-separated run folders (repetitions; timing needs >= 3)")
    p.add_argument("candidate", help="run folder, or comma-separated run folders (interleave them with the baseline's)")
    p.add_argument("--time-threshold", type=float, default=0.10)
    p.add_argument("--error-threshold", type=float, default=0.05)
    p.add_argument("--alpha", type=float, default=0.05)
    p.add_argument("--compare-changed-versions", action="store_true",
                   help="also compare rows whose method version changed (a PR editing a method), marked 'method changed'")
    p.add_argument("--relative-to", default=None, metavar="METHOD",
                   help="gate times relative to METHOD's time on the same view in the same run (cancels machine load)")
    p.add_argument("--correction", choices=("holm", "bh"), default="holm",
                   help="multiple-testing correction over rows: holm (family-wise error, default) or bh (FDR)")
    p.add_argument("--min-runs", type=int, default=3, help="runs per side needed to test timing (default 3, >= 2)")
    p.set_defaults(func=cmd_gate)

    p = sub.add_parser("reference", help="Mitsuba references")
    rsub = p.add_subparsers(dest="reference_command", required=True)
    b = rsub.add_parser("build", help="precompute references for scenes, in parallel processes")
    b.add_argument("--scenes", default=",".join(DEFAULT_SCENES))
    b.add_argument("--res", type=_resolution, default=DEFAULT_RESOLUTION)
    b.add_argument("--spp", type=int, default=1024)
    b.add_argument("--workers", type=int, default=2, metavar="N",
                   help="Dask LocalCluster of N processes (default 2), each rendering whole references")
    b.add_argument("--scheduler", default=None, metavar="ADDRESS", help="an existing dask.distributed cluster instead")
    b.set_defaults(func=cmd_reference)

    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print("gibench: interrupted; re-run the same command to resume", file=sys.stderr)
        return 130
    except (ValueError, FileNotFoundError, KeyError) as exc:
        # Bad input: one line naming the culprit, no traceback.
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"gibench: {' '.join(str(msg).split())}", file=sys.stderr)
        return 2
    except OSError as exc:  # the disk refused (full, read-only, permissions): one line, no traceback
        where = f" ({exc.filename})" if getattr(exc, "filename", None) else ""
        print(f"gibench: {exc.strerror or exc}{where}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
