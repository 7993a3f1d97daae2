"""`gibench reference build`: Mitsuba references of whole scenes, in parallel processes."""
from __future__ import annotations

import sys

from bench.cli import options

DEFAULT_WORKERS = 2


def add_parser(sub) -> None:
    p = sub.add_parser("reference", help="Mitsuba references")
    rsub = p.add_subparsers(dest="reference_command", required=True)
    b = rsub.add_parser("build", help="precompute references for scenes, in parallel processes")
    b.add_argument("--scenes", type=options.scene_list, default=",".join(options.DEFAULT_SCENES))
    b.add_argument("--res", type=options.resolution, default=options.DEFAULT_RESOLUTION)
    b.add_argument("--spp", type=options.reference_spp, default=1024)
    b.add_argument("--workers", type=options.workers, default=None, metavar="N",
                   help="Dask LocalCluster of N processes (default %d), each rendering whole references" % DEFAULT_WORKERS)
    b.add_argument("--scheduler", type=options.non_empty, default=None, metavar="ADDRESS",
                   help="an existing dask.distributed cluster instead")
    b.set_defaults(func=main)


def main(args) -> int:
    from bench.run.cluster import build_references   # Dask starts only for this command
    from reference.api import ReferenceUnavailable
    options.one_cluster(args.workers, args.scheduler)
    width, height = args.res
    try:
        build_references(args.scenes, width=width, height=height, spp_cap=args.spp, scheduler=args.scheduler,
                         workers=args.workers if args.workers is not None else DEFAULT_WORKERS)
    except ReferenceUnavailable as exc:
        print(f"gibench: {str(exc).splitlines()[0] if str(exc) else 'Mitsuba 3 is unavailable'}", file=sys.stderr)
        return 1
    return 0
