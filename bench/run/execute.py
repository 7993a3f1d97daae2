"""Executing one row: the one function every execution path renders rows through.

`render_outcome` renders a method on a view (bench.run.harness.run_method: prepare untimed,
warm-up and timed frames, images read back, then `cfg.error_frames` untimed frames of a fresh
instance whose per-pixel statistics come back as images too) and writes nothing: the serial runner
(bench.run.serial), a Dask worker (bench.run.cluster) and the stress suite (bench.stress) all
call it and then record the outcome their own way. `SharedPassCache` holds a view's shared
passes (GBuffer, shadow maps, direct light, RSM), rendered and measured once and lent to every
row of the view, in the serial runner's process and in each worker process alike.
"""
from __future__ import annotations

import json
import os
import resource
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.gl import SharedPasses
from bench.gl.passes import RSM_RESOLUTION, expand_needs, shared_variant
from bench.protocol import results as store
from bench.protocol.method import SkipRow
from bench.protocol.vocabulary import Status, failure_reason
from bench.run.config import RunConfig, effective_shadow_resolution, timing_budget
from bench.run.harness import SharedViewPasses, measure_shared_passes, run_method


def reset_peak_rss() -> None:
    """Start a new peak-RSS window (Linux: writing 5 to clear_refs resets VmHWM); no-op elsewhere."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass


def peak_rss_mb() -> float:
    """The process's peak resident memory since the last reset_peak_rss (MB; the lifetime peak
    where the window cannot be reset)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def build_shared_passes(ctx, gpu, cfg: RunConfig, view: str, needs) -> SharedViewPasses:
    """One view's shared passes for `needs` (the union over the view's rows), built, rendered and
    measured once with the rows' timing settings."""
    passes = SharedPasses(gpu, gpu.view(view, cfg.width, cfg.height), needs,
                          shadow_resolution=effective_shadow_resolution(cfg))
    try:
        return measure_shared_passes(ctx, passes, warmup=cfg.warmup, frames=cfg.frames, timing=timing_budget(cfg))
    except BaseException:
        passes.release()
        raise


def render_outcome(ctx, gpu, cfg: RunConfig, cls, scene, facts, view: str, params: dict, shared=None,
                   keep_nonfinite: bool = False) -> dict:
    """Render one row, writing nothing: {"status": "ok", "measured": row fields, "images": {...}},
    {"status": "skipped", "reason"} or {"status": "failed", "reason"}. `gpu`: the scene uploaded
    (None: uploaded for this row); `shared`: the view's shared passes, rendered and measured once
    (SharedPassCache), None renders them in each frame of the row. `keep_nonfinite`: images with
    NaN or Inf pixels are returned as they are (the stress suite counts them) instead of failing."""
    reset_peak_rss()
    try:
        result = run_method(ctx, cls, scene, view, cfg.width, cfg.height, params, seed=cfg.seed,
                            warmup=cfg.warmup, frames=cfg.frames, facts=facts,
                            shadow_resolution=effective_shadow_resolution(cfg), gpu=gpu, timing=timing_budget(cfg),
                            shared=shared, allow_nonfinite=keep_nonfinite, error_frames=cfg.error_frames)
    except SkipRow as exc:
        return {"status": Status.SKIPPED, "reason": str(exc)}
    except Exception as exc:
        ctx.error  # clear a pending GL error so the next method starts clean
        if os.environ.get("GIBENCH_DEBUG"):
            traceback.print_exc()
        return {"status": Status.FAILED, "reason": failure_reason(exc)}
    med, iqr = store.summarize_samples(result.frame_ms)
    measured = {"frame_ms": med, "frame_ms_iqr": iqr, "status": Status.OK,
                "skipped_stages": json.dumps(list(result.skipped_stages)),
                "samples.frame_ms": json.dumps([round(v, 4) for v in result.frame_ms]),
                "samples.stage_ms": json.dumps({k: [round(v, 4) for v in vs] for k, vs in result.stage_ms.items()})}
    gpu_total = 0.0
    for stage, samples in result.stage_ms.items():
        m, _ = store.summarize_samples(samples)
        measured[f"stage_ms.{stage}"] = m
        gpu_total += m
    for stage in result.skipped_stages:
        measured.setdefault(f"stage_ms.{stage}", float("nan"))
    measured.update({"gpu_ms": gpu_total, "stage_clock": result.stage_clock, "prepare_ms": result.prepare_ms,
                     "frames_total_ms": result.frames_total_ms, "error_frames_ms": result.error_frames_ms,
                     "peak_rss_mb": peak_rss_mb()})
    for k, v in result.extra.items():
        if isinstance(v, (int, float, str, bool)):
            measured[f"extra.{k}"] = v
    images = {"direct": np.asarray(result.direct, np.float32), "indirect": np.asarray(result.indirect, np.float32),
              "combined": np.asarray(result.combined, np.float32)}
    images.update(result.frame_stats)   # the error frames' statistics (error_frames > 1), written beside them
    return {"status": Status.OK, "measured": measured, "images": images}


@dataclass
class SharedBuild:
    """What building a view's shared passes cost: for the run's phases and its manifest."""
    view_key: str                # "scene/view"
    variant: str
    seconds: float               # wall time of the build (rendering and measuring included)
    frames_ms: float             # of which rendering frames
    summary: dict | None         # the measurement (SharedViewPasses.summary()), None when it failed
    failure: str | None = None


class SharedPassCache:
    """The shared passes of the current view, one set per variant (a direct pass without shadow
    maps is another set), built at the first row that needs them and lent to the view's other
    rows. The key holds every input of the passes (scene content, seed, view, resolution, shadow
    and RSM sizes: none is per frame); a new view releases the previous view's passes.

    `expect(needs)` (the serial runner, which knows a view's rows ahead) builds each variant once
    with the union of the needs of the rows about to render; a worker, which sees rows one by one,
    rebuilds held passes with the union when a row needs a pass they lack. A build that fails is
    not retried for the view: its rows render passes of their own, as without reuse.
    """

    def __init__(self):
        self.held: dict = {}        # key + (variant,) -> SharedViewPasses or None (failed)
        self.view: tuple | None = None
        self.expected: dict = {}    # variant -> union of needs of the current view's pending rows

    @staticmethod
    def view_key(scene, seed: int, cfg: RunConfig, view: str) -> tuple:
        return (scene.content_hash(), int(seed), view, cfg.width, cfg.height, effective_shadow_resolution(cfg),
                RSM_RESOLUTION)

    def open_view(self, key: tuple) -> None:
        if key != self.view:
            self.release()
            self.view = key

    def expect(self, key: tuple, classes) -> None:
        """Open view `key` and note the union of the needs of `classes` (its rows about to render)."""
        self.open_view(key)
        self.expected = {}
        for cls in classes:
            if not getattr(cls, "reuses_shared_passes", True):
                continue
            try:
                needs = expand_needs(cls.needs)
            except ValueError:  # the row fails with this message in run_method
                continue
            variant = shared_variant(needs)
            self.expected[variant] = self.expected.get(variant, frozenset()) | needs

    def get(self, ctx, gpu, cfg: RunConfig, view: str, cls) -> tuple:
        """(the view's shared passes for `cls` or None, SharedBuild if this call built them or None)."""
        if not getattr(cls, "reuses_shared_passes", True):
            return None, None
        try:
            needs = expand_needs(cls.needs)
            variant = shared_variant(needs)
        except ValueError:
            return None, None
        self.open_view(self.view_key(gpu.scene, gpu.seed, cfg, view))
        key = self.view + (variant,)
        if key in self.held:
            current = self.held[key]
            if current is None or current.passes.serves(needs) is None:
                return current, None
            needs = needs | (current.passes.needs - {"precompute"})
            self.held.pop(key).passes.release()
        needs = needs | self.expected.get(variant, frozenset())
        t0 = time.perf_counter()
        label = f"{gpu.scene.name}/{view}"
        try:
            shared = build_shared_passes(ctx, gpu, cfg, view, needs)
        except Exception as exc:
            ctx.error   # clear a pending GL error: the view's rows render passes of their own
            self.held[key] = None
            return None, SharedBuild(label, variant, time.perf_counter() - t0, 0.0, None, failure_reason(exc))
        self.held[key] = shared
        build = SharedBuild(label, variant, time.perf_counter() - t0, shared.frames_total_ms, shared.summary())
        return shared, build

    def release(self) -> None:
        for shared in self.held.values():
            if shared is not None:
                shared.passes.release()
        self.held = {}
        self.expected = {}
        self.view = None
