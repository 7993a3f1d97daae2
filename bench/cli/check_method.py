"""`gibench check-method NAME [--scenes ...] [--res WxH]`: the conformance suite every method must
pass (bench.kit.conformance), one PASS/FAIL line per check; exit 1 on a failure."""
from __future__ import annotations

from bench.cli import options
from bench.kit.conformance import CHECKS, DEFAULT_RESOLUTION, DEFAULT_SCENES, CheckSettings, check_method


def add_parser(sub) -> None:
    p = sub.add_parser("check-method", help="run the conformance suite on a registered method (small scenes)")
    p.add_argument("name", help="a registered method (gibench list methods)")
    p.add_argument("--scenes", type=options.scene_list, default=list(DEFAULT_SCENES),
                   help="corpus names or .toml scene files the rendering checks use, comma-separated (default: "
                        f"{','.join(DEFAULT_SCENES)}; the energy check always adds sphere_inside)")
    p.add_argument("--res", type=options.resolution, default=DEFAULT_RESOLUTION,
                   help="WxH of the check rows (default %dx%d)" % DEFAULT_RESOLUTION)
    p.add_argument("--seed", type=options.seed, default=0)
    p.set_defaults(func=main)


def main(args) -> int:
    if not options.known_methods([args.name]):
        return 2
    width, height = args.res
    settings = CheckSettings(scenes=tuple(args.scenes), width=width, height=height, seed=args.seed)
    verdicts = check_method(args.name, settings=settings)
    for v in verdicts:
        print(v.line(), flush=True)
    failed = [v.check for v in verdicts if not v.ok]
    print(f"{args.name}: {len(CHECKS) - len(failed)} of {len(CHECKS)} checks passed"
          + (f"; failed: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0
