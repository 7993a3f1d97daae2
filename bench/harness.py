"""Run one method on one view: build the shared passes it needs, prepare it (untimed), render
warm-up and timed frames, read its images back. The runner calls this once per result row;
tests call it directly.

Frame 0 is always a warm-up frame and its images are the row's images, so the written image
does not depend on how many frames are timed (same seed -> same image). With the finish-fenced
stage clock of software GL, frame wall times and stage times come from two separate sets of K
frames (fencing every stage would inflate the wall time of methods with many stages).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import moderngl
import numpy as np

from bench.gl import Frame, GpuScene, SharedPasses, StageProfiler, check_gl, read_rgb
from bench.method import FrameOutput, resolve_params
from bench.scene import Scene, SceneFacts, compute_facts


@dataclass
class RenderResult:
    direct: np.ndarray
    indirect: np.ndarray
    frame_ms: list = field(default_factory=list)        # CPU wall ms per timed frame, GPU finished
    stage_ms: dict = field(default_factory=dict)        # stage -> list of ms per timed frame
    skipped_stages: tuple = ()
    params: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)
    stage_clock: str = ""                               # how stage_ms were measured (profiler.CLOCKS)
    prepare_ms: float = 0.0                             # the method's untimed prepare (precomputation)
    frames_total_ms: float = 0.0                        # wall time of every frame rendered (warm-up included)

    @property
    def combined(self) -> np.ndarray:
        return self.direct + self.indirect


@dataclass(frozen=True)
class TimingBudget:
    """Calibrated timing: after the minimum frame count, stop when `budget_s` of timed frames is
    spent, at `max_frames`, or when the median's 95% interval is within +-`rel_halfwidth`."""
    budget_s: float = 1.0
    max_frames: int = 100
    rel_halfwidth: float = 0.05

    def settled(self, samples, min_frames: int, elapsed_s: float) -> bool:
        from bench.results import timing_settled
        return timing_settled(samples, min_frames, elapsed_s, self.budget_s, self.max_frames, self.rel_halfwidth)


def to_numpy(image, shape) -> np.ndarray:
    if image is None:
        return np.zeros(shape, dtype=np.float32)
    if isinstance(image, moderngl.Texture):
        return read_rgb(image)
    arr = np.asarray(image, dtype=np.float32)
    if arr.shape != shape:
        raise ValueError(f"method returned an image of shape {arr.shape}, expected {shape}")
    return arr


def run_method(ctx: moderngl.Context, method_cls, scene: Scene, camera: str, width: int, height: int,
               params: dict | None = None, seed: int = 0, warmup: int = 1, frames: int = 3,
               facts: SceneFacts | None = None, gpu: GpuScene | None = None,
               shadow_resolution: int = 1024, timing: "TimingBudget | None" = None) -> RenderResult:
    """`frames` timed frames, or with `timing` at least `frames` and then as many as its
    budget and the median's confidence interval call for (see bench.results.timing_settled)."""
    if warmup < 1:
        raise ValueError("warmup must be >= 1 (frame 0 gives the images)")
    if frames < 1:
        raise ValueError("frames must be >= 1")
    facts = facts or compute_facts(scene)
    params = resolve_params(method_cls, params)
    own_gpu = gpu is None
    gpu = gpu or GpuScene(ctx, scene, seed=seed, facts=facts)
    view = gpu.view(camera, width, height)
    passes = SharedPasses(gpu, view, method_cls.needs, shadow_resolution=shadow_resolution)
    method = method_cls()
    shape = (height, width, 3)
    try:
        t_prepare = time.perf_counter()
        method.prepare(gpu, scene, facts, params, view)
        ctx.finish()
        prepare_ms = (time.perf_counter() - t_prepare) * 1e3
        check_gl(ctx, f"method '{method_cls.name}' prepare")
        prof = StageProfiler(ctx, passes.stages + tuple(method_cls.stages))
        result = RenderResult(direct=None, indirect=None, params=params, stage_clock=prof.clock, prepare_ms=prepare_ms)
        skipped: set = set()
        # A finish-fenced stage clock serialises the stages, which a real frame does not: then
        # the frame wall times come from K frames with the profiler off and the stage times
        # from K more frames with it on. Timer queries perturb nothing: one set of K frames.
        separate = prof.clock == "finish_wall"
        index, wall_done, stage_count, timing_start = 0, False, 0, None
        while True:
            timed = index >= warmup
            if timed and timing_start is None:
                timing_start = time.perf_counter()
            if timed and not wall_done:
                # wall frames until the count (or the calibration) is satisfied
                if timing is None:
                    wall_done = len(result.frame_ms) >= frames
                else:
                    wall_done = timing.settled(result.frame_ms, frames, time.perf_counter() - timing_start)
            if timed and wall_done and (stage_count >= frames if separate else True):
                break
            wall_frame = timed and not wall_done
            stage_frame = timed and (wall_frame if not separate else wall_done)
            prof.enabled = not timed or stage_frame
            prof.begin_frame()
            frame = Frame(ctx=ctx, gpu=gpu, view=view, passes=passes, index=index, seed=seed)
            t0 = time.perf_counter()
            passes.render(prof)
            out: FrameOutput = method.render(frame, prof)
            ctx.finish()
            wall_ms = (time.perf_counter() - t0) * 1e3
            result.frames_total_ms += wall_ms
            check_gl(ctx, f"method '{method_cls.name}' frame {index}")
            skipped.update(out.skipped_stages)
            if index == 0:
                result.direct = to_numpy(out.direct, shape)
                result.indirect = to_numpy(out.indirect, shape)
                result.extra = dict(out.extra)
            if wall_frame:
                result.frame_ms.append(wall_ms)
            if stage_frame:
                stage_count += 1
                for stage, ms in prof.collect().items():
                    result.stage_ms.setdefault(stage, []).append(ms)
            index += 1
        if timing is not None:
            result.extra["timing_frames"] = len(result.frame_ms)
            result.extra["timing_budget_s"] = timing.budget_s
        result.skipped_stages = tuple(sorted(skipped))
        for name, img in (("direct", result.direct), ("indirect", result.indirect)):
            if not np.all(np.isfinite(img)):
                bad = int((~np.isfinite(img)).any(axis=2).sum())
                raise FloatingPointError(f"method '{method_cls.name}' produced {bad} non-finite {name} pixels")
        return result
    finally:
        method.release()
        passes.release()
        prof_release = locals().get("prof")
        if prof_release is not None:
            prof_release.release()
        if own_gpu:
            gpu.release()
