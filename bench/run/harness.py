"""Run one method on one view: build the shared passes it needs, prepare it (untimed), render
warm-up and timed frames, read its images back. The runner calls this once per result row;
tests call it directly.

Frame 0 is always a warm-up frame and its images are the row's images, so the written image
does not depend on how many frames are timed (same seed -> same image). With the finish-fenced
stage clock of software GL, frame wall times and stage times come from two separate sets of K
frames (fencing every stage would inflate the wall time of methods with many stages).

Shared passes rendered once per view: the runner builds a view's shared passes (GBuffer, shadow
maps, direct light, RSM) once, with the union of the needs of the view's rows, and measures
their stages once (`measure_shared_passes`: the same calibrated timing as a row). `run_method`
given that `SharedViewPasses` renders only the method in each frame; each timed frame's
`frame_ms` is the method's own wall time plus the medians of the shared stages the method needs,
and `stage_ms` holds those stages' samples from the shared measurement beside the method's own,
so a row's frame time still counts everything a frame of that method costs. The row's `extra`
records the reuse (`shared_passes_reused`, `shared_ms` = the added constant, `own_frame_ms`,
`shared_frames`): frame_ms = own_frame_ms + shared_ms (medians). A timing budget is spent in
frame time (each frame charged its shared cost too), so it bounds a row's frames as before.
Without it (tests, direct calls, a method with `reuses_shared_passes = False`) each frame
renders the passes as before.

Error frames (`error_frames` = K > 1): the row's instance, prepared once, renders frames 0, 1,
2, ... in order, as an application does after a cut: its per-frame random streams and any
temporal state it keeps evolve from frame 0, and frames 0..K-1 depend only on the seed, not on
how many frames the calibrated timing goes on to render. So the first K of them give the error
over frames: each is read back after its timed region closes (the read-back and the statistics
are not in frame_ms, nor in the time the timing budget counts), and when the timing stops
before K frames, the same instance renders the rest untimed (the profiler off). Frame 0 is the
row's own image. Per image component (`indirect`, `combined`) `FrameStatistics` keeps, per
pixel, the mean, the unbiased variance over the K frames and the flicker D = mean over
consecutive pairs of (f_{k+1} - f_k)^2; the row gets them as images
(`<component>_frames_{mean,var,flicker}`, bench.protocol.vocabulary) and records K in
`extra.error_frames` and the frames rendered for them alone in `extra.error_frames_rendered`. A
method that declares its frames identical at the row's parameters (`frames_identical`: direct,
manylights' centroid sum) needs two of the K, compared bit for bit (a false declaration fails
the row), and counts the others as copies of them: the statistics are exactly those of K
identical frames. Nothing timed changes: frame_ms and stage_ms are those of the timed frames;
the statistics' own wall time (read-backs, sums and the untimed frames) is `error_frames_ms`.
(Until issue #29's second pass the K frames came from a second, fresh instance: the same
frames, rendered twice.)
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import moderngl
import numpy as np

from bench.gl import Frame, GpuScene, SharedPasses, StageProfiler, check_gl, read_rgb
from bench.gl.passes import stages_for_needs
from bench.gl.profiler import default_clock
from bench.protocol.method import FrameOutput, resolve_params
from bench.protocol.results import timing_settled
from bench.protocol.vocabulary import FRAME_STAT_COMPONENTS, frame_stat_image
from bench.model.scene import Scene, SceneFacts, compute_facts


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
    frame_stats: dict = field(default_factory=dict)     # error frames: image name -> HxWx3 float32 (FRAME_STAT_IMAGES)
    error_frames_ms: float = 0.0                        # wall time of the error frames' statistics (read-backs, sums, untimed frames)

    @property
    def combined(self) -> np.ndarray:
        return self.direct + self.indirect


class FrameStatistics:
    """Per-pixel statistics of a stream of frames of one image component: the mean, the unbiased
    variance (K - 1 denominator) and the flicker, the mean over consecutive pairs of the squared
    difference. Sums in float64 shifted by the first frame, so frames that are all the same give
    exactly that frame as the mean and exactly 0 as the variance and the flicker."""

    def __init__(self):
        self.count = 0
        self.first = self.previous = None
        self.sum_d = self.sum_d2 = self.sum_step2 = None

    def add(self, image) -> None:
        x = np.asarray(image, dtype=np.float64)
        if self.first is None:
            self.first = x
            self.sum_d, self.sum_d2, self.sum_step2 = np.zeros_like(x), np.zeros_like(x), np.zeros_like(x)
        else:
            d = x - self.first
            self.sum_d += d
            self.sum_d2 += d * d
            self.sum_step2 += (x - self.previous) ** 2
        self.previous = x
        self.count += 1

    def images(self) -> dict:
        """{"mean", "var", "flicker"} as HxWx3 float32; needs at least two frames."""
        k = self.count
        if k < 2:
            raise ValueError(f"frame statistics need at least 2 frames, got {k}")
        mean = self.first + self.sum_d / k
        var = np.maximum((self.sum_d2 - self.sum_d * self.sum_d / k) / (k - 1), 0.0)
        return {"mean": mean.astype(np.float32), "var": var.astype(np.float32),
                "flicker": (self.sum_step2 / (k - 1)).astype(np.float32)}


class ErrorFrames:
    """The error over frames of one row (the module's docstring): frames 0..K-1 of its instance,
    read back as they are rendered. A method that declares identical frames needs two of them,
    compared bit for bit; the others count as copies."""

    def __init__(self, method_cls, params: dict, count: int, allow_nonfinite: bool):
        self.method_name, self.count, self.allow_nonfinite = method_cls.name, int(count), allow_nonfinite
        self.identical = self.count > 1 and bool(getattr(method_cls, "frames_identical", lambda p: False)(params))
        self.needed = (min(self.count, 2) if self.identical else self.count) if self.count > 1 else 0
        self.stats = {c: FrameStatistics() for c in FRAME_STAT_COMPONENTS}
        self.first = None
        self.seconds = 0.0      # wall time spent here (read-backs and sums)
        self.rendered = 0       # frames rendered for the statistics alone (after the timed frames)

    def wants(self, index: int) -> bool:
        return index < self.needed

    def add(self, index: int, direct: np.ndarray, indirect: np.ndarray) -> None:
        if not self.allow_nonfinite and not (np.all(np.isfinite(direct)) and np.all(np.isfinite(indirect))):
            raise FloatingPointError(f"method '{self.method_name}' produced non-finite pixels in error frame {index}")
        images = {"indirect": indirect, "combined": direct + indirect}   # as RenderResult.combined
        if self.identical:
            if self.first is None:
                self.first = images
            elif not all(np.array_equal(self.first[c], images[c], equal_nan=True) for c in FRAME_STAT_COMPONENTS):
                raise RuntimeError(f"method '{self.method_name}' declares identical frames (frames_identical) at "
                                   f"these parameters, but its frame {index} differs from frame 0")
        for component, acc in self.stats.items():
            acc.add(images[component])

    def images(self) -> dict:
        """{frame_stat_image(component, statistic): HxWx3 float32} over the K frames."""
        for _ in range(self.count - self.needed):
            for component, acc in self.stats.items():
                acc.add(self.first[component])
        return {frame_stat_image(c, name): img for c, acc in self.stats.items() for name, img in acc.images().items()}


@dataclass(frozen=True)
class TimingBudget:
    """Calibrated timing: after the minimum frame count, stop when `budget_s` of timed frames is
    spent, at `max_frames`, or when the median's 95% interval is within +-`rel_halfwidth`."""
    budget_s: float = 1.0
    max_frames: int = 100
    rel_halfwidth: float = 0.05

    def settled(self, samples, min_frames: int, elapsed_s: float) -> bool:
        return timing_settled(samples, min_frames, elapsed_s, self.budget_s, self.max_frames, self.rel_halfwidth)


@dataclass
class SharedViewPasses:
    """A view's shared passes, rendered, with their cost measured once (`measure_shared_passes`)."""
    passes: SharedPasses
    stage_ms: dict                                      # shared stage -> ms per timed frame
    stage_clock: str = ""
    frames_total_ms: float = 0.0                        # wall time of every frame rendered (warm-up included)
    timing_budget_s: float | None = None

    @property
    def frames(self) -> int:
        return min((len(v) for v in self.stage_ms.values()), default=0)

    def median_ms(self, stage: str) -> float:
        return float(np.median(self.stage_ms[stage]))

    def cost_ms(self, needs) -> dict:
        """Median ms of each shared stage a method with `needs` pays (stages_for_needs)."""
        return {stage: self.median_ms(stage) for stage in stages_for_needs(needs)}

    def summary(self) -> dict:
        """What the manifest records of this view's measurement."""
        return {"needs": sorted(self.passes.needs), "stage_clock": self.stage_clock, "frames": self.frames,
                "median_ms": {k: round(self.median_ms(k), 4) for k in self.stage_ms},
                "frames_total_ms": round(self.frames_total_ms, 3), "timing_budget_s": self.timing_budget_s}


def measure_shared_passes(ctx: moderngl.Context, passes: SharedPasses, warmup: int = 1, frames: int = 3,
                          timing: "TimingBudget | None" = None) -> SharedViewPasses:
    """Render `passes` for `warmup` untimed frames, then time each shared stage over `frames`
    frames, or with `timing` over at least `frames` and as many more as its budget and the
    median's interval (of the per-frame sum of the stages) call for, as run_method times a row.
    Each stage is timed by the StageProfiler's clock (finish-fenced wall time on software GL)."""
    if warmup < 1:
        raise ValueError("warmup must be >= 1")
    if frames < 1:
        raise ValueError("frames must be >= 1")
    prof = StageProfiler(ctx, passes.stages)
    out = SharedViewPasses(passes=passes, stage_ms={s: [] for s in passes.stages}, stage_clock=prof.clock,
                           timing_budget_s=None if timing is None else timing.budget_s)
    totals: list = []
    try:
        index, timing_start = 0, None
        while True:
            timed = index >= warmup
            if timed:
                if timing_start is None:
                    timing_start = time.perf_counter()
                elif (len(totals) >= frames if timing is None
                      else timing.settled(totals, frames, time.perf_counter() - timing_start)):
                    break
            prof.begin_frame()
            t0 = time.perf_counter()
            passes.render(prof)
            ctx.finish()
            out.frames_total_ms += (time.perf_counter() - t0) * 1e3
            check_gl(ctx, f"shared passes frame {index}")
            if timed:
                ms = prof.collect()
                for stage in passes.stages:
                    out.stage_ms[stage].append(ms[stage])
                totals.append(sum(ms[s] for s in passes.stages))
            index += 1
    finally:
        prof.release()
    return out


def to_numpy(image, shape) -> np.ndarray:
    if image is None:
        return np.zeros(shape, dtype=np.float32)
    if isinstance(image, moderngl.Texture):
        return read_rgb(image)
    arr = np.asarray(image, dtype=np.float32)
    if arr.shape != shape:
        raise ValueError(f"method returned an image of shape {arr.shape}, expected {shape}")
    return arr


def _check_shared(ctx, shared: SharedViewPasses, method_cls, scene: Scene, gpu, camera: str, width: int,
                  height: int, seed: int, shadow_resolution: int) -> None:
    """The lent passes must be exactly the ones run_method would build for this row."""
    passes = shared.passes
    what = f"method '{method_cls.name}': the shared passes given"
    if gpu is not None and passes.gpu is not gpu:
        raise ValueError(f"{what} belong to another GpuScene")
    if passes.gpu.scene is not scene and passes.gpu.scene.content_hash() != scene.content_hash():
        raise ValueError(f"{what} are of scene '{passes.gpu.scene.name}', the row renders '{scene.name}'")
    if shared.stage_clock != default_clock(ctx):
        raise ValueError(f"{what} were timed by clock {shared.stage_clock}, the row's is {default_clock(ctx)}")
    if passes.gpu.seed != int(seed):
        raise ValueError(f"{what} were built with seed {passes.gpu.seed}, the row has seed {seed}")
    view = passes.view
    if (view.name, view.width, view.height) != (camera, int(width), int(height)):
        raise ValueError(f"{what} are of view {view.name} {view.width}x{view.height}, "
                         f"the row renders {camera} {width}x{height}")
    why = passes.serves(method_cls.needs)
    if why is not None:
        raise ValueError(f"{what} {why}")
    if passes.shadows is not None and passes.shadows.resolution != int(shadow_resolution):
        raise ValueError(f"{what} have {passes.shadows.resolution}^2 shadow tiles, the row asks for "
                         f"{shadow_resolution}^2")
    missing = [s for s in stages_for_needs(method_cls.needs) if not shared.stage_ms.get(s)]
    if missing:
        raise ValueError(f"{what} have no measured time for stage(s) {missing}")


def run_method(ctx: moderngl.Context, method_cls, scene: Scene, camera: str, width: int, height: int,
               params: dict | None = None, seed: int = 0, warmup: int = 1, frames: int = 3,
               facts: SceneFacts | None = None, gpu: GpuScene | None = None,
               shadow_resolution: int = 1024, timing: "TimingBudget | None" = None,
               shared: SharedViewPasses | None = None, allow_nonfinite: bool = False,
               error_frames: int = 1) -> RenderResult:
    """`frames` timed frames, or with `timing` at least `frames` and then as many as its
    budget and the median's confidence interval call for (see bench.protocol.results.timing_settled).

    `shared`: this view's shared passes, already rendered and measured (measure_shared_passes).
    The frames then render only the method (the passes are not rendered again), each timed
    frame's frame_ms adds the medians of the shared stages the method needs to its own wall time,
    and stage_ms carries those stages' samples from the shared measurement. A method class with
    `reuses_shared_passes = False` ignores `shared` and renders passes of its own every frame.
    Images with NaN or Inf pixels raise FloatingPointError, unless `allow_nonfinite` (the stress
    suite, which counts them).

    `error_frames` K > 1: frames 0..K-1 of the instance, read back outside the timed regions and
    completed untimed when the timing stops earlier (the module's docstring), give `frame_stats`;
    1 reads none."""
    if warmup < 1:
        raise ValueError("warmup must be >= 1 (frame 0 gives the images)")
    if frames < 1:
        raise ValueError("frames must be >= 1")
    if not 1 <= int(error_frames) <= 64:
        raise ValueError(f"error_frames={error_frames} outside [1, 64]")
    if shared is not None and not getattr(method_cls, "reuses_shared_passes", True):
        shared = None
    if shared is not None:
        _check_shared(ctx, shared, method_cls, scene, gpu, camera, width, height, seed, shadow_resolution)
        gpu = shared.passes.gpu
    facts = facts or compute_facts(scene)
    params = resolve_params(method_cls, params)
    own_gpu = gpu is None
    gpu = gpu or GpuScene(ctx, scene, seed=seed, facts=facts)
    if shared is None:
        view = gpu.view(camera, width, height)
        passes = SharedPasses(gpu, view, method_cls.needs, shadow_resolution=shadow_resolution)
        shared_ms: dict = {}
    else:
        passes, view = shared.passes, shared.passes.view
        shared_ms = shared.cost_ms(method_cls.needs)   # added to each timed frame of the method
    shared_total_ms = float(sum(shared_ms.values()))
    own_stages = passes.stages if shared is None else ()
    method = method_cls()
    shape = (height, width, 3)
    try:
        t_prepare = time.perf_counter()
        method.prepare(gpu, scene, facts, params, view)
        ctx.finish()
        prepare_ms = (time.perf_counter() - t_prepare) * 1e3
        check_gl(ctx, f"method '{method_cls.name}' prepare")
        prof = StageProfiler(ctx, own_stages + tuple(method_cls.stages))
        result = RenderResult(direct=None, indirect=None, params=params, stage_clock=prof.clock, prepare_ms=prepare_ms)
        skipped: set = set()
        errors = ErrorFrames(method_cls, params, int(error_frames), allow_nonfinite)
        errors_before_timing_s = 0.0   # the statistics' time before the timed frames began (not the budget's)
        # A finish-fenced stage clock serialises the stages, which a real frame does not: then
        # the frame wall times come from K frames with the profiler off and the stage times
        # from K more frames with it on. Timer queries perturb nothing: one set of K frames.
        separate = prof.clock == "finish_wall"
        index, wall_done, stage_count, timing_start = 0, False, 0, None
        own_ms: list = []   # the method's own wall ms per timed frame (frame_ms minus the shared cost)
        while True:
            timed = index >= warmup
            if timed and timing_start is None:
                timing_start = time.perf_counter()
                errors_before_timing_s = errors.seconds
            if timed and not wall_done:
                # wall frames until the count (or the calibration) is satisfied
                if timing is None:
                    wall_done = len(result.frame_ms) >= frames
                else:
                    # the budget is spent in frame time: a lent pass's measured cost counts in each frame
                    # (the error frames' read-backs are not frame time)
                    spent_s = (time.perf_counter() - timing_start - (errors.seconds - errors_before_timing_s)
                               + len(result.frame_ms) * shared_total_ms / 1e3)
                    wall_done = timing.settled(result.frame_ms, frames, spent_s)
            if timed and wall_done and (stage_count >= frames if separate else True):
                break
            wall_frame = timed and not wall_done
            stage_frame = timed and (wall_frame if not separate else wall_done)
            prof.enabled = not timed or stage_frame
            prof.begin_frame()
            frame = Frame(ctx=ctx, gpu=gpu, view=view, passes=passes, index=index, seed=seed)
            if shared is not None:
                passes.restore_state(method_cls.needs)  # as if the passes had just been rendered
            t0 = time.perf_counter()
            if shared is None:
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
                result.extra["first_frame_ms"] = wall_ms   # the warm-up frame (a method may converge there)
            if errors.wants(index):
                t_read = time.perf_counter()
                if index == 0:
                    errors.add(index, result.direct, result.indirect)
                else:
                    errors.add(index, to_numpy(out.direct, shape), to_numpy(out.indirect, shape))
                errors.seconds += time.perf_counter() - t_read
            if wall_frame:
                result.frame_ms.append(wall_ms + shared_total_ms)
                own_ms.append(wall_ms)
            if stage_frame:
                stage_count += 1
                for stage, ms in prof.collect().items():
                    result.stage_ms.setdefault(stage, []).append(ms)
            index += 1
        if timing is not None:
            result.extra["timing_frames"] = len(result.frame_ms)
            result.extra["timing_budget_s"] = timing.budget_s
        if shared is not None:
            # the shared stages first (execution order), their samples from the view's measurement
            result.stage_ms = {**{s: list(shared.stage_ms[s]) for s in shared_ms}, **result.stage_ms}
            result.extra.update({"shared_passes_reused": True, "shared_ms": shared_total_ms,
                                 "own_frame_ms": float(np.median(own_ms)), "shared_frames": shared.frames})
        result.skipped_stages = tuple(sorted(skipped))
        for name, img in (("direct", result.direct), ("indirect", result.indirect)):
            if not allow_nonfinite and not np.all(np.isfinite(img)):
                bad = int((~np.isfinite(img)).any(axis=2).sum())
                raise FloatingPointError(f"method '{method_cls.name}' produced {bad} non-finite {name} pixels")
        result.extra["error_frames"] = int(error_frames)
        if errors.needed:
            # the error frames the timing did not reach: the same instance goes on, untimed
            t_rest = time.perf_counter()
            prof.enabled = False
            while errors.wants(index):
                prof.begin_frame()
                frame = Frame(ctx=ctx, gpu=gpu, view=view, passes=passes, index=index, seed=seed)
                if shared is not None:
                    passes.restore_state(method_cls.needs)
                else:
                    passes.render(prof)
                out = method.render(frame, prof)
                ctx.finish()
                check_gl(ctx, f"method '{method_cls.name}' error frame {index}")
                errors.add(index, to_numpy(out.direct, shape), to_numpy(out.indirect, shape))
                errors.rendered += 1
                index += 1
            result.frame_stats = errors.images()
            errors.seconds += time.perf_counter() - t_rest
            result.error_frames_ms = errors.seconds * 1e3
            result.extra["error_frames_rendered"] = errors.rendered
        return result
    finally:
        if method is not None:
            method.release()
        if shared is None:
            passes.release()
        prof_release = locals().get("prof")
        if prof_release is not None:
            prof_release.release()
        if own_gpu:
            gpu.release()
