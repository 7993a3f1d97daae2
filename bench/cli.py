"""`gibench` command line: run, list, report, gate, reference, sweep.

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

DEFAULT_SCENES = ("cornell_spot", "hidden_bounce", "big_floor", "sphere_inside", "rooms")
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
    cfg = RunConfig(scenes=_csv(args.scenes), methods=methods, width=width, height=height, frames=args.frames,
                    warmup=args.warmup, seed=args.seed, out=Path(args.out) if args.out else None, force=args.force,
                    views=_csv(args.views) if args.views else None, params=_param_sets(args.param),
                    references=not args.no_reference, reference_spp_cap=args.reference_spp,
                    progress=not args.no_progress)
    df, runner = run(cfg, log=lambda m: print(m, file=sys.stderr))
    print(runner.summary())
    print(f"results: {runner.run_dir / 'results.csv'}")
    return _nothing_useful(runner)


def _nothing_useful(runner) -> int:
    """1 (and one line) when every row of the run failed, else 0."""
    c = runner.counts
    if c["failed"] and not (c["ok"] or c["cached"] or c["resumed"] or c["skipped"]):
        print(f"gibench: every row failed ({c['failed']} rows): nothing was measured", file=sys.stderr)
        return 1
    return 0


def cmd_report(args) -> int:
    run_dir = Path(args.run)
    if not (run_dir / "results.csv").is_file() and not (run_dir / "results.parquet").is_file():
        print(f"gibench: {run_dir} is not a run folder (no results.csv)", file=sys.stderr)
        return 2
    try:
        from reports import build_report
    except ImportError:  # the comparison report is optional; the quick summary always exists
        from bench.summary import write_summary
        _, path = write_summary(run_dir)
    else:
        path = build_report(run_dir, Path(args.out) if args.out else None)
    print(f"report: {path}")
    return 0


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
        reference_spp_cap=args.reference_spp, progress=not args.no_progress)
    print(runner.summary())
    print(f"{len(table)} sweep points, {len(pareto)} on the Pareto fronts")
    print(f"sweep: {runner.run_dir / 'sweep.csv'}")
    print(f"pareto: {runner.run_dir / 'pareto.csv'}")
    return _nothing_useful(runner)


def cmd_gate(args) -> int:
    from bench.gate import compare_runs
    result = compare_runs(_csv(args.baseline), _csv(args.candidate), time_threshold=args.time_threshold,
                          error_threshold=args.error_threshold, alpha=args.alpha,
                          compare_changed_versions=args.compare_changed_versions, relative_to=args.relative_to,
                          correction=args.correction, min_runs=args.min_runs)
    print(result.markdown())
    return result.exit_code


def cmd_reference(args) -> int:
    from reference.api import ReferenceUnavailable, build_references
    from bench.corpus import load_scene
    width, height = args.res
    scenes = [load_scene(s) for s in _csv(args.scenes)]
    try:
        build_references(scenes, width=width, height=height, processes=args.processes, spp_cap=args.spp)
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
        p.add_argument("--scenes", default=",".join(DEFAULT_SCENES), help="corpus names or .toml scene files, comma-separated")
        p.add_argument("--methods", default=",".join(DEFAULT_METHODS))
        p.add_argument("--views", default=None, help="camera names (default: every camera of each scene)")
        p.add_argument("--res", type=_resolution, default=(128, 96), help="WxH (default 128x96)")
        p.add_argument("--frames", type=int, default=5, help="timed frames per row")
        p.add_argument("--warmup", type=int, default=2, help="untimed warm-up frames (>= 1)")
        p.add_argument("--seed", type=int, default=0)
        p.add_argument("--out", default=None, help="run folder (default runs/<timestamp>, runs/latest points to it)")
        p.add_argument("--force", action="store_true", help="re-run rows found in the cache")
        p.add_argument("--no-reference", action="store_true", help="skip Mitsuba references, error metrics and speed-ups")
        p.add_argument("--reference-spp", type=int, default=4096,
                       help="spp cap of the references (they stop earlier, at 1/10 of the best method's MSE)")
        p.add_argument("--no-progress", action="store_true")
    run.add_argument("--param", action="append", help="METHOD.NAME=VALUE[,VALUE...] (repeatable; lists make a grid)")
    run.set_defaults(func=cmd_run)
    sweep.set_defaults(func=cmd_sweep)

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
    b.add_argument("--res", type=_resolution, default=(128, 96))
    b.add_argument("--spp", type=int, default=1024)
    b.add_argument("--processes", type=int, default=2)
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
