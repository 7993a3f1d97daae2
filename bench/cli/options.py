"""What the commands share: the default corpus and methods, the one validation layer of the
command line, and the run options of `run` and `sweep` (a sweep is a run over parameter grids).

Every option is checked while the command line is parsed, by an argparse `type=` built here
from a declared range or grammar (`int_in`, `float_in`, `resolution`, `name_list`, `non_empty`,
`param_item`), so a bad value never becomes a default nor reaches the runner: it is one line
naming the option and the value, exit 2, before any work and before any folder is made
(`OneLineParser`). What needs more than one option or the registry (an unknown method, a
repeated parameter set, --workers with --scheduler) is refused the same way by `refuse`.
"""
from __future__ import annotations

import argparse
import json
import math
import sys

from bench.model.scene import SceneError, check_path_name
from bench.protocol.method import resolve_params
from bench.protocol.registry import MethodLoadError, list_methods, load_method
from bench.protocol.vocabulary import canonical_params
from reference.api import MIN_SPP

# The purpose-built procedural scenes (each isolates one difficulty) and real scenes, the FLC
# paper's kind of comparison (sponza, sibenik, conference: real interiors of 66k-331k triangles).
DEFAULT_SCENES = ("cornell_spot", "hidden_bounce", "big_floor", "sphere_inside", "rooms", "lit_wall_corner",
                  "cornell_box", "sponza", "sibenik", "conference")
# `--quick`: a first useful report in minutes: the default corpus under a time budget (the plan keeps
# every method's defaults first, then the ladders' ends, then their middles: bench.run.budget), a
# short timing budget, fewer reference samples and error frames
QUICK_BUDGET_S = 300.0
# --quick chooses rows for 75% of its budget (a run's default margin: 15%): its rows are timed over
# 3-4 frames for 0.3 s, and a shared host's speed drifts by up to 1.7x within the hour (the probe read
# 0.022-0.040 s on one machine): with 15%, quick runs took 4m58s and 5m10s for a 5-minute budget
QUICK_BUDGET_MARGIN = 0.25
# the scenes in motion of the default run (after its scenes, at RunConfig.sequence_width x height)
DEFAULT_SEQUENCES = ("rooms_light_sweep", "sponza_camera_walk", "cornell_spot_moving_block")
REFERENCE_SPP = 1024        # reference spp cap of `run` and `sweep`
QUICK_REFERENCE_SPP = 256   # --quick: a first report; the reference floor shows as wider intervals
ERROR_FRAMES = 8            # untimed frames per row for bias, variance and flicker (RunConfig.error_frames)
QUICK_ERROR_FRAMES = 4      # --quick
DEFAULT_RESOLUTION = (320, 180)   # the design point of the interleaved screen-space methods starts here
DEFAULT_METHODS = ("direct", "ir_unshadowed", "ir_shadowed", "manylights", "flc", "ssdo", "dss", "val_clustered", "pbgi",
                   "visibility_gates")

# The declared range of every numeric option (inclusive). Image sides, frames and warm-up match
# RunConfig.validate and StressConfig.resolve, workers bench.run.cluster.open_client.
IMAGE_SIDE_RANGE = (8, 8192)
SHADOW_RESOLUTION_RANGE = (16, 8192)   # --shadow-resolution: one tile of the shared atlas (GL's 16384 limit)
FRAMES_RANGE = (1, 10000)
WARMUP_RANGE = (1, 1000)               # frame 0 is the warm-up that gives the images
SEED_RANGE = (0, 2**31 - 1)            # a seed seeds numpy's SeedSequence (>= 0) and fits a GLSL int
REFERENCE_SPP_RANGE = (MIN_SPP, 1 << 20)   # a variance needs two samples
TIMING_BUDGET_RANGE_S = (0.0, 3600.0)  # 0: exactly --frames frames
WORKERS_RANGE = (1, 256)
ERROR_FRAMES_RANGE = (1, 64)           # bench.run.config.ERROR_FRAMES_RANGE; 1: no error frames
BUDGET_RANGE_S = (1.0, 7 * 86400.0)    # bench.run.config.BUDGET_RANGE_S
SEQUENCE_FRAMES_RANGE = (2, 1000)      # bench.run.config.SEQUENCE_FRAMES_RANGE
CASE_TIMEOUT_RANGE_S = (0.0, 86400.0)  # stress --timeout, above 0
FUZZ_EXAMPLES_RANGE = (1, 1_000_000)


class OneLineParser(argparse.ArgumentParser):
    """argparse whose errors are one line naming the option (not the usage block), exit 2, and
    whose options say their declared range in their help."""

    def error(self, message):
        self.exit(2, f"{self.prog}: {' '.join(message.split())} (see {self.prog} --help)\n")

    def add_argument(self, *args, **kwargs):
        bounds = getattr(kwargs.get("type"), "bounds", None)
        if bounds:
            kwargs["help"] = f"{kwargs.get('help') or ''} ({bounds})".lstrip()
        return super().add_argument(*args, **kwargs)


def refuse(message: str):
    """Bad input found after parsing: one line naming the culprit, exit 2, before any work."""
    print(f"gibench: {' '.join(str(message).split())}", file=sys.stderr)
    raise SystemExit(2)


# ---------------------------------------------------------------------------- option types
def int_in(low: int, high: int, what: str = ""):
    """An argparse `type=`: an integer in [low, high]."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{what + ' ' if what else ''}must be an integer in [{low}, {high}], "
                                             f"got {text!r}")
        return value
    parse.bounds = f"an integer in [{low}, {high}]"
    return parse


def sequence_list(text: str) -> list[str]:
    """An argparse `type=`: corpus sequence names, comma-separated (`all`: every one, `none`: none)."""
    from bench.model.corpus.sequences import SEQUENCES
    if text.strip() == "all":
        return list(SEQUENCES)
    if text.strip() == "none":
        return []
    return name_list("sequence", choices=tuple(SEQUENCES))(text)


sequence_list.bounds = "corpus sequence names (gibench list sequences), all or none"


def duration(text: str) -> float:
    """An argparse `type=`: a duration ('90s', '10m', '1h30m', seconds) within BUDGET_RANGE_S, or
    'none' (math.inf: no budget, for a script whose default has one)."""
    from bench.run.budget import parse_duration
    if str(text).strip().lower() == "none":
        return math.inf
    try:
        value = parse_duration(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    low, high = BUDGET_RANGE_S
    if not low <= value <= high:
        raise argparse.ArgumentTypeError(f"must be a duration from {low:g} s to {high / 86400:g} days, got {text!r}")
    return value


duration.bounds = "a duration (90s, 10m, 1h30m) or none"


def float_in(low: float, high: float, low_open: bool = False, high_open: bool = False):
    """An argparse `type=`: a finite number in [low, high] (an open end with `low_open` / `high_open`)."""
    bounds = f"{']' if low_open else '['}{low:g}, {high:g}{'[' if high_open else ']'}"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        above = low < value if low_open else low <= value
        below = value < high if high_open else value <= high
        if not (math.isfinite(value) and above and below):
            raise argparse.ArgumentTypeError(f"must be a number in {bounds}, got {text!r}")
        return value
    parse.bounds = f"a number in {bounds}"
    return parse


def resolution(text: str) -> tuple[int, int]:
    """WxH, each side in IMAGE_SIDE_RANGE."""
    low, high = IMAGE_SIDE_RANGE
    try:
        w, h = (int(t) for t in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"resolution must be WxH, got {text!r}") from None
    if not (low <= w <= high and low <= h <= high):
        raise argparse.ArgumentTypeError(f"resolution must be WxH with W and H in [{low}, {high}], got {text!r}")
    return w, h


resolution.bounds = "W and H in [%d, %d]" % IMAGE_SIDE_RANGE


shadow_resolution = int_in(*SHADOW_RESOLUTION_RANGE, what="shadow resolution")


def non_empty(text: str) -> str:
    """An argparse `type=`: a string that is not blank (an empty --out or --scheduler is refused,
    never read as "not given")."""
    if not text.strip():
        raise argparse.ArgumentTypeError("must not be empty")
    return text


def name_list(what: str, path_safe: bool = False, choices=None):
    """An argparse `type=`: a comma-separated list of `what`s, at least one, no empty item, none
    twice; each a name safe in a path (bench.model.scene.check_path_name) when `path_safe`, or one
    of `choices`."""
    def parse(text: str) -> list[str]:
        items = [t.strip() for t in text.split(",")]
        if not any(items):
            raise argparse.ArgumentTypeError(f"no {what} given")
        if "" in items:
            raise argparse.ArgumentTypeError(f"an empty {what} in {text!r}")
        for i, item in enumerate(items):
            if item in items[:i]:
                raise argparse.ArgumentTypeError(f"{what} {item!r} is given twice")
            if choices is not None and item not in choices:
                raise argparse.ArgumentTypeError(f"unknown {what} {item!r} (known: {', '.join(choices)})")
            if path_safe:
                try:
                    check_path_name(item, f"{what} name")
                except SceneError as exc:
                    raise argparse.ArgumentTypeError(str(exc)) from None
        return items
    return parse


def csv(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


# ---------------------------------------------------------------------------- --param
def _parse_value(text: str):
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def param_item(text: str) -> tuple[str, str, list]:
    """An argparse `type=` for one --param: METHOD.NAME=VALUE[,VALUE...] -> (method, name, values)."""
    lhs, eq, rhs = text.partition("=")
    method, dot, name = lhs.partition(".")
    if not (eq and dot and method.strip() and name.strip()):
        raise argparse.ArgumentTypeError(f"expects METHOD.NAME=VALUE[,VALUE...], got {text!r}")
    texts = [v.strip() for v in rhs.split(",")]
    for i, value in enumerate(texts):
        if value in texts[:i]:
            raise argparse.ArgumentTypeError(f"{lhs.strip()}: value {value!r} is given twice in {text!r}")
    return method.strip(), name.strip(), [_parse_value(v) for v in texts]


def param_sets(items) -> dict:
    """`--param flc.N_avg=128` (one value) or `--param flc.N_avg=64,128,256` (a grid): {method: [sets]}.
    Items are strings or `param_item` tuples; a malformed item, a value given twice or a knob
    given in two --param options (the second would silently replace the first) is refused."""
    grid: dict = {}
    for item in items or []:
        try:
            method, name, values = param_item(item) if isinstance(item, str) else item
        except argparse.ArgumentTypeError as exc:
            refuse(f"--param {exc}")
        if name in grid.get(method, {}):
            refuse(f"--param {method}.{name} is given twice; give its values in one list ({method}.{name}=A,B)")
        grid.setdefault(method, {})[name] = values
    out = {}
    for method, knobs in grid.items():
        sets = [{}]
        for name, values in knobs.items():
            sets = [dict(s, **{name: v}) for s in sets for v in values]
        out[method] = sets
    return out


def distinct_param_sets(params: dict) -> None:
    """Refuse two parameter sets of one method that resolve to the same values (`n_avg=64,64.0`):
    they would write two rows under one row key. Range errors are the runner's (ParamError)."""
    for method, sets in params.items():
        try:
            cls = load_method(method)
        except MethodLoadError:
            continue   # recorded as a failed row by the runner
        seen: dict = {}
        for pset in sets:
            try:
                key = canonical_params(resolve_params(cls, pset))
            except ValueError:
                continue   # the runner names the bad value
            if key in seen:
                refuse(f"--param {method}: the sets {canonical_params(seen[key])} and {canonical_params(pset)} "
                       f"are the same parameters")
            seen[key] = pset


# ---------------------------------------------------------------------------- checks after parsing
def known_methods(methods: list[str]) -> bool:
    """False (and a one-line message) when a method name is not registered."""
    unknown = [m for m in methods if m not in list_methods()]
    if unknown:
        print(f"gibench: unknown method(s) {', '.join(unknown)}; registered: {', '.join(list_methods())}", file=sys.stderr)
    return not unknown


def one_cluster(workers, scheduler) -> None:
    """Refuse --workers with --scheduler (a local cluster or an existing one, not both)."""
    if workers is not None and scheduler is not None:
        refuse(f"give --workers N or --scheduler ADDRESS, not both (got --workers {workers} --scheduler {scheduler})")


def nothing_useful(runner) -> int:
    """1 (and one line) when every row of the run failed, else 0."""
    c = runner.counts
    if c["failed"] and not (c["ok"] or c["cached"] or c["resumed"] or c["skipped"]):
        print(f"gibench: every row failed ({c['failed']} rows): nothing was measured", file=sys.stderr)
        return 1
    return 0


# ---------------------------------------------------------------------------- shared options
scene_list = name_list("scene")   # corpus names (with :KEY=VALUE options) or scene-file paths
method_list = name_list("method", path_safe=True)
view_list = name_list("view", path_safe=True)
seed = int_in(*SEED_RANGE)
reference_spp = int_in(*REFERENCE_SPP_RANGE)
workers = int_in(*WORKERS_RANGE)


def add_run_options(p, scenes_default) -> None:
    """The options `run` and `sweep` share."""
    p.add_argument("--scenes", type=scene_list, default=scenes_default,
                   help="corpus names or .toml scene files, comma-separated (default: " + ",".join(DEFAULT_SCENES) + ")")
    p.add_argument("--methods", type=method_list, default=",".join(DEFAULT_METHODS))
    p.add_argument("--views", type=view_list, default=None, help="camera names (default: every camera of each scene)")
    p.add_argument("--res", type=resolution, default=DEFAULT_RESOLUTION,
                   help="WxH (default %dx%d)" % DEFAULT_RESOLUTION)
    p.add_argument("--frames", type=int_in(*FRAMES_RANGE), default=3,
                   help="timed frames per row (the minimum, with a timing budget)")
    p.add_argument("--warmup", type=int_in(*WARMUP_RANGE), default=1,
                   help="untimed warm-up frames (>= 1; frame 0 gives the images)")
    p.add_argument("--seed", type=seed, default=0)
    p.add_argument("--out", type=non_empty, default=None,
                   help="run folder (default runs/<timestamp>, runs/latest points to it)")
    p.add_argument("--force", action="store_true", help="re-run rows found in the cache")
    p.add_argument("--no-reference", action="store_true", help="skip Mitsuba references, error metrics and speed-ups")
    p.add_argument("--reference-spp", type=reference_spp, default=None,
                   help="spp cap of the references (default 1024, 256 with run --quick; they stop earlier, at 1/10 of the best "
                        "method's MSE; a floor above that shows as wider intervals and lower-bound speed-ups). "
                        "4096 takes ~4x the reference time")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--error-frames", type=int_in(*ERROR_FRAMES_RANGE), default=None, metavar="K",
                   help="after the timed frames, K untimed frames of a fresh instance of each method give its error "
                        "over frames: bias2, variance, flicker and mse_accumulated columns (default %d, %d with run "
                        "--quick; 1: none)" % (ERROR_FRAMES, QUICK_ERROR_FRAMES))
    p.add_argument("--shadow-resolution", type=shadow_resolution, default=None, metavar="N",
                   help="side of each light's shadow map tile (default: the smallest power of two >= the image's "
                        "longer side, within 256..2048)")
