"""One stress case: a method on one view of a (perturbed) scene, rendered through the one row
execution path, bench.run.execute.render_outcome (1 warm-up frame, whose images are the case's,
and 1 timed frame), keeping images with NaN or Inf pixels so the suite counts them.
bench.stress.isolate runs a case in a child process."""
from __future__ import annotations

from dataclasses import dataclass

from bench.model.scene import Scene
from bench.protocol.vocabulary import Status
from bench.run.config import RunConfig
from bench.run.execute import render_outcome

SHADOW_RESOLUTION = 512       # shared shadow maps: 8x the largest image side of the suite, a quarter of the runner's cost


@dataclass
class CaseResult:
    status: str                       # "ok", "skipped: ...", "failed: ..." (bench.protocol.vocabulary.Status)
    images: dict | None = None        # {"direct", "indirect"} raw float32 HxWx3


def case_config(scene: Scene, cls, width: int, height: int, seed: int) -> RunConfig:
    """The RunConfig of one case: 1 warm-up and 1 timed frame, no timing budget, no references, no
    error frames (the suite judges the images of one frame)."""
    return RunConfig(scenes=[scene.name], methods=[cls.name], width=width, height=height, frames=1, warmup=1,
                     seed=seed, references=False, shadow_resolution=SHADOW_RESOLUTION, timing_budget_s=None,
                     error_frames=1)


def run_case(ctx, cls, scene: Scene, view: str, width: int, height: int, params: dict, seed: int) -> CaseResult:
    """One method on one view (the scene uploaded for the case, its shared passes its own)."""
    outcome = render_outcome(ctx, None, case_config(scene, cls, width, height, seed), cls, scene, None, view, params,
                             shared=None, keep_nonfinite=True)
    if outcome["status"] == Status.SKIPPED:
        return CaseResult(Status.skipped(outcome["reason"]))
    if outcome["status"] != Status.OK:
        return CaseResult(Status.failed(outcome["reason"]))
    return CaseResult(Status.OK, {c: outcome["images"][c] for c in ("direct", "indirect")})
