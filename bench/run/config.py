"""What a run is asked to do (RunConfig) and the settings derived from it: the shadow-map size of
its views, the parameter sets of each method, its timing budget, where its caches live."""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from bench.model.scene import check_path_name
from bench.protocol.registry import load_method
from bench.run.harness import TimingBudget


ERROR_FRAMES_RANGE = (1, 64)   # RunConfig.error_frames, `--error-frames`
BUDGET_RANGE_S = (1.0, 7 * 86400.0)   # RunConfig.budget_s, `--budget`
SEQUENCE_FRAMES_RANGE = (2, 1000)     # RunConfig.sequence_frames, `--sequence-frames`


def cache_root() -> Path:
    """The row, reference and metric caches: $GIBENCH_CACHE_DIR, else ~/.cache/gibench."""
    return Path(os.environ.get("GIBENCH_CACHE_DIR", Path.home() / ".cache" / "gibench"))


@dataclass
class RunConfig:
    scenes: list
    methods: list
    width: int = 128
    height: int = 96
    frames: int = 5
    warmup: int = 2
    seed: int = 0
    out: Path | None = None
    force: bool = False
    views: list | None = None                       # camera names; None: every camera of a scene
    params: dict = field(default_factory=dict)      # method -> list of param dicts (a grid of rows)
    references: bool = True                         # fetch/build Mitsuba references and metrics
    reference_spp_cap: int = 4096                   # refinement stops earlier, at 1/10 of the best MSE
    progress: bool = True
    shadow_resolution: int | None = None            # shadow map tile side; None: from the view (auto_shadow_resolution)
    ladders: bool = False                           # methods without --param run their quality ladder
    timing_budget_s: float | None = None            # calibrated timing (>= `frames` frames), None: `frames` exactly
    scheduler: str | None = None                    # a dask.distributed scheduler address (bench.run.cluster)
    workers: int | None = None                      # or a LocalCluster of this many worker processes
    error_frames: int = 8                           # untimed frames of a fresh instance per row (bias, variance, flicker); 1: none
    budget_s: float | None = None                   # the run's time budget: rows that do not fit are skipped (bench.run.budget)
    # the rows are chosen to fill (1 - margin) of the budget: the rest absorbs this machine's timing
    # noise (10-20% run to run), so a run ends the rows it chose and a second run of the command
    # takes them all from the cache (the run's clock still stops rows at the whole budget)
    budget_margin: float = 0.15
    sequences: list = field(default_factory=list)   # corpus sequences (scenes in motion), rendered after the scenes
    # 6 + 6 frames: the three sequences fit a cold default run (bench.sh, 28 minutes) beside every
    # view's defaults; a lag longer than the rest is measured by the settling frames
    sequence_frames: int = 6                        # frames of motion of each sequence
    sequence_rest: int = 6                          # then frames at rest (a reusing method's lag)
    sequence_settle: int = 64                       # at most this many more at rest while a row's error has not settled (its lag)
    sequence_width: int = 160                       # sequences render (and are referenced) at this size:
    sequence_height: int = 90                       # a reference per frame costs what a view's does
    sequence_reference_spp: int = 256               # per-frame references' spp cap (and at most the run's)

    def validate(self) -> None:
        for name, value, low, high in (("width", self.width, 8, 8192), ("height", self.height, 8, 8192),
                                       ("frames", self.frames, 1, 10000), ("warmup", self.warmup, 1, 1000),
                                       ("error_frames", self.error_frames, ERROR_FRAMES_RANGE[0], ERROR_FRAMES_RANGE[1])):
            if not (low <= int(value) <= high):
                raise ValueError(f"{name}={value} outside [{low}, {high}]")
        if self.timing_budget_s is not None and not (0.0 <= float(self.timing_budget_s) <= 3600.0):
            raise ValueError(f"timing budget {self.timing_budget_s} s outside [0, 3600]")
        if self.budget_s is not None and not (0.0 < float(self.budget_s) <= BUDGET_RANGE_S[1]):
            raise ValueError(f"budget {self.budget_s} s outside (0, {BUDGET_RANGE_S[1]:.0f}]")
        if not 0.0 <= float(self.budget_margin) < 1.0:
            raise ValueError(f"budget_margin={self.budget_margin} outside [0, 1)")
        if not self.scenes and not self.sequences:
            raise ValueError("no scene given")
        if not SEQUENCE_FRAMES_RANGE[0] <= int(self.sequence_frames) <= SEQUENCE_FRAMES_RANGE[1]:
            raise ValueError(f"sequence_frames={self.sequence_frames} outside {list(SEQUENCE_FRAMES_RANGE)}")
        if not 0 <= int(self.sequence_rest) <= SEQUENCE_FRAMES_RANGE[1]:
            raise ValueError(f"sequence_rest={self.sequence_rest} outside [0, {SEQUENCE_FRAMES_RANGE[1]}]")
        if not 0 <= int(self.sequence_settle) <= SEQUENCE_FRAMES_RANGE[1]:
            raise ValueError(f"sequence_settle={self.sequence_settle} outside [0, {SEQUENCE_FRAMES_RANGE[1]}]")
        if not self.methods:
            raise ValueError("no method given")
        if int(self.reference_spp_cap) < 2:
            raise ValueError(f"reference spp cap {self.reference_spp_cap} must be >= 2")
        if int(self.seed) < 0:
            raise ValueError(f"seed={self.seed} must be >= 0")
        if self.workers is not None and not 1 <= int(self.workers) <= 256:
            raise ValueError(f"workers={self.workers} outside [1, 256]")
        # names that become folders of the run (a RunConfig built in code skips the CLI's checks)
        for method in self.methods:
            check_path_name(method, "method name")
        for view in self.views or ():
            check_path_name(view, "view name")


def auto_shadow_resolution(width: int, height: int) -> int:
    """Shadow map tile side matched to the view: the smallest power of two >= the image's longer
    side, within [256, 2048]. A cube face spans 90 degrees, a camera about 40-70, so a shadow texel
    then subtends about one screen pixel: shadow edges as sharp as the image can show, while a
    fixed 1024 made the shared shadow pass most of a frame on real scenes at 320x180 (12 faces of
    1024^2 on llvmpipe).

    A directional light's map spans the scene's bounding sphere, so the rule matches its texel to
    a pixel only at about the scene's size: sponza's sun at 320x180 has 8 cm texels against ~7 cm
    pixels at the camera's distance to the scene's centre, but the steep sun stretches them 2.7x
    on the walls, and the shadow lines there are the bulk of `direct`'s relMSE against Mitsuba
    (10.9 at 512^2, 3.1 at 2048^2 for a 7x longer frame on llvmpipe, `gibench run --scenes sponza
    --methods direct --shadow-resolution N`; a tight light-space fit would gain only 10-16% on
    sponza, whose plan is nearly square in light space). RunConfig.shadow_resolution sets it."""
    side = max(int(width), int(height), 1)
    return int(min(max(1 << (side - 1).bit_length(), 256), 2048))


def effective_shadow_resolution(cfg: RunConfig) -> int:
    return int(cfg.shadow_resolution) if cfg.shadow_resolution else auto_shadow_resolution(cfg.width, cfg.height)


def timing_budget(cfg: RunConfig) -> TimingBudget | None:
    """The run's calibrated timing, None for exactly `frames` frames."""
    return None if cfg.timing_budget_s is None else TimingBudget(budget_s=float(cfg.timing_budget_s))


def sequence_config(cfg: RunConfig) -> RunConfig:
    """The settings a run's sequence rows render and are judged at: the sequence size, per-frame
    references capped at sequence_reference_spp (and at the run's cap)."""
    import dataclasses
    return dataclasses.replace(cfg, width=int(cfg.sequence_width), height=int(cfg.sequence_height),
                               reference_spp_cap=min(int(cfg.reference_spp_cap), int(cfg.sequence_reference_spp)))


def sequence_param_sets(cfg: RunConfig, method: str) -> list[dict]:
    """A method's parameter sets on the sequences: its --param grid, else its defaults alone (motion
    is measured at the operating point; the ladders are the static views' curves)."""
    return [dict(s) for s in cfg.params.get(method) or [{}]]


def expand_param_sets(cfg: RunConfig, method: str) -> list[dict]:
    """Parameter sets of `method` in this run: its --param grid, else (with `ladders`) its quality
    ladder (fast -> accurate, the defaults among the rungs), else the defaults alone."""
    sets = cfg.params.get(method)
    if sets:
        return [dict(s) for s in sets]
    if cfg.ladders:
        try:
            ladder = load_method(method).ladder
        except Exception:  # a method that fails to load becomes a failed row of its own
            ladder = ()
        if ladder:
            return [dict(s) for s in ladder]
    return [{}]
