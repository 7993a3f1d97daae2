"""What the commands share: the default corpus and methods, option parsers, and the run options
of `run` and `sweep` (a sweep is a run over parameter grids)."""
from __future__ import annotations

import argparse
import json
import sys

from bench.protocol.registry import list_methods

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


def csv(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def resolution(text: str) -> tuple[int, int]:
    try:
        w, h = text.lower().split("x")
        return int(w), int(h)
    except ValueError:
        raise argparse.ArgumentTypeError(f"resolution must be WxH, got {text!r}") from None


def shadow_resolution(text: str) -> int:
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


def param_sets(items: list[str]) -> dict:
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


def known_methods(methods: list[str]) -> bool:
    """False (and a one-line message) when a method name is not registered."""
    unknown = [m for m in methods if m not in list_methods()]
    if unknown:
        print(f"gibench: unknown method(s) {', '.join(unknown)}; registered: {', '.join(list_methods())}", file=sys.stderr)
    return not unknown


def nothing_useful(runner) -> int:
    """1 (and one line) when every row of the run failed, else 0."""
    c = runner.counts
    if c["failed"] and not (c["ok"] or c["cached"] or c["resumed"] or c["skipped"]):
        print(f"gibench: every row failed ({c['failed']} rows): nothing was measured", file=sys.stderr)
        return 1
    return 0


def add_run_options(p, scenes_default) -> None:
    """The options `run` and `sweep` share."""
    p.add_argument("--scenes", default=scenes_default,
                   help="corpus names or .toml scene files, comma-separated (default: " + ",".join(DEFAULT_SCENES) + ")")
    p.add_argument("--methods", default=",".join(DEFAULT_METHODS))
    p.add_argument("--views", default=None, help="camera names (default: every camera of each scene)")
    p.add_argument("--res", type=resolution, default=DEFAULT_RESOLUTION, help="WxH (default %dx%d)" % DEFAULT_RESOLUTION)
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
    p.add_argument("--shadow-resolution", type=shadow_resolution, default=None, metavar="N",
                   help="side of each light's shadow map tile (default: the smallest power of two >= the image's "
                        "longer side, within 256..2048)")
