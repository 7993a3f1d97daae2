"""Rendering a sequence (issue #25): a method follows a scene in motion frame by frame.

`run_sequence` renders frames 0..N-1 of a bench.model.animation.Sequence in order with one
instance of the method, which sees frame t after frame t-1 and may keep state between them:
* Frame 0: the scene is uploaded and the method prepared (`prepare_ms`, as a static row's).
* A frame where something moved (`Sequence.changes`: camera, light, geometry): the engine's
  part, uploading the frame's scene and its view and building the shared passes' targets, is
  measured apart (`upload_ms`, not the method's); then the method redoes what depends on what
  moved, inside the frame's clock (`update_ms`): `method.update(gpu, scene, facts, params, view,
  changes)`, whose default (MethodBase) is to release and prepare again, the honest cost of a
  method that keeps nothing; a method that can follow a kind of motion more cheaply overrides
  it, keeping its temporal state.
* Every frame renders the shared passes (G-buffer, shadow maps, direct light, RSM: in a moving
  scene they are per frame) and the method, timed together with the update: `frame_ms`.
* A method may declare kinds of motion it cannot follow (`cannot_follow = {"geometry": why}`):
  a sequence that moves one of them is skipped with that reason (SkipRow), before any work.
* Settling frames: a caller that measures how long a method that reuses earlier frames takes to
  settle after the motion (bench.run.sequence_rows: `lag_frames`) passes `unsettled(result)`;
  while it is True after the last frame, the same instance renders more frames at rest (the last
  frame's scene, nothing moved), at most `settle_max`, recorded with `settling=True`. They are not
  frames of the sequence: they exist only so that a lag longer than the frames at rest is
  measured, not bounded.
Images are read back after the clock stops. Nothing here writes files or judges images.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from bench.gl import Frame, GpuScene, SharedPasses, StageProfiler, check_gl
from bench.model.scene import compute_facts
from bench.protocol.method import FrameOutput, SkipRow, resolve_params
from bench.run.harness import to_numpy


@dataclass
class SequenceFrame:
    """One frame's record: what moved, and what it cost."""
    t: int
    changes: tuple
    frame_ms: float            # the method's update (if any) + shared passes + its render
    update_ms: float           # of which redoing what the motion invalidated
    upload_ms: float           # the engine's upload of the frame's scene (not the method's)
    settling: bool = False     # a frame after the sequence's last, at rest, only to measure the lag


@dataclass
class SequenceResult:
    params: dict
    prepare_ms: float
    frames: list = field(default_factory=list)     # SequenceFrame per frame
    images: list = field(default_factory=list)     # (direct, indirect) HxWx3 float32 per frame
    stage_clock: str = ""


def motion_kinds(sequence) -> set:
    """Every kind of motion in the sequence after its first frame."""
    return set().union(*(sequence.changes(t) for t in range(1, sequence.frames)))


def refusal(method_cls, sequence) -> str | None:
    """Why `method_cls` cannot follow `sequence` (its own declaration), or None."""
    declared = getattr(method_cls, "cannot_follow", {}) or {}
    for kind in sorted(motion_kinds(sequence)):
        if kind in declared:
            return f"cannot follow {kind} motion: {declared[kind]}"
    return None


def _update(method, method_cls, gpu, scene, facts, params, view, changes):
    """The method redoes what `changes` invalidated; a plugin without `update` is prepared afresh."""
    update = getattr(method, "update", None)
    if update is not None:
        update(gpu, scene, facts, params, view, frozenset(changes))
        return method
    method.release()
    fresh = method_cls()
    fresh.prepare(gpu, scene, facts, params, view)
    return fresh


def run_sequence(ctx, method_cls, sequence, camera: str, width: int, height: int, params: dict | None = None,
                 seed: int = 0, shadow_resolution: int = 512, allow_nonfinite: bool = False,
                 unsettled=None, settle_max: int = 0) -> SequenceResult:
    """Frames 0..N-1 of `sequence` seen through `camera`, in order, one instance of the method;
    then, while `unsettled(result)`, up to `settle_max` settling frames at rest (the module's docstring)."""
    why = refusal(method_cls, sequence)
    if why is not None:
        raise SkipRow(why)
    params = resolve_params(method_cls, params)
    shape = (height, width, 3)
    gpu = passes = method = prof = None
    facts = None
    result = SequenceResult(params=params, prepare_ms=0.0)
    try:
        last = sequence.frames - 1
        t = 0
        while t < sequence.frames or (unsettled is not None and t <= last + settle_max and unsettled(result)):
            settling = t > last
            scene, changes = (sequence.frame(last), frozenset()) if settling else (sequence.frame(t), sequence.changes(t))
            upload_ms = 0.0
            if t == 0 or changes:
                t_upload = time.perf_counter()
                # a new camera or light keeps the scene's geometry facts; moved geometry needs new ones
                facts = compute_facts(scene) if facts is None or "geometry" in changes else \
                    dataclasses.replace(facts, content_hash=scene.content_hash())
                if passes is not None:
                    passes.release()
                old_gpu = gpu
                gpu = GpuScene(ctx, scene, seed=seed, facts=facts)
                view = gpu.view(camera, width, height)
                passes = SharedPasses(gpu, view, method_cls.needs, shadow_resolution=shadow_resolution)
                ctx.finish()
                upload_ms = (time.perf_counter() - t_upload) * 1e3
            if prof is None:
                prof = StageProfiler(ctx, passes.stages + tuple(method_cls.stages))
                prof.enabled = False   # frame wall times only: a fenced stage clock would serialise the stages
                result.stage_clock = prof.clock
            update_ms = 0.0
            t_frame = time.perf_counter()
            if t == 0:
                method = method_cls()
                t_prepare = time.perf_counter()
                method.prepare(gpu, scene, facts, params, view)
                ctx.finish()
                result.prepare_ms = (time.perf_counter() - t_prepare) * 1e3
                check_gl(ctx, f"method '{method_cls.name}' prepare")
                t_frame = time.perf_counter()   # preparing is not frame 0's time, as in a static row
            elif changes:
                method = _update(method, method_cls, gpu, scene, facts, params, view, changes)
                ctx.finish()
                update_ms = (time.perf_counter() - t_frame) * 1e3
                check_gl(ctx, f"method '{method_cls.name}' update at frame {t}")
            if t > 0 and old_gpu is not None and old_gpu is not gpu:
                old_gpu.release()   # after the method moved to the new scene
                old_gpu = None
            prof.begin_frame()
            passes.render(prof)
            out: FrameOutput = method.render(Frame(ctx=ctx, gpu=gpu, view=view, passes=passes, index=t, seed=seed), prof)
            ctx.finish()
            frame_ms = (time.perf_counter() - t_frame) * 1e3
            check_gl(ctx, f"method '{method_cls.name}' frame {t}")
            direct, indirect = to_numpy(out.direct, shape), to_numpy(out.indirect, shape)
            if not allow_nonfinite:
                for name, img in (("direct", direct), ("indirect", indirect)):
                    if not np.all(np.isfinite(img)):
                        bad = int((~np.isfinite(img)).any(axis=2).sum())
                        raise FloatingPointError(f"method '{method_cls.name}' produced {bad} non-finite {name} "
                                                 f"pixels at frame {t}")
            result.images.append((direct, indirect))
            result.frames.append(SequenceFrame(t, tuple(sorted(changes)), frame_ms, update_ms, upload_ms, settling))
            t += 1
        return result
    finally:
        if method is not None:
            method.release()
        if passes is not None:
            passes.release()
        if prof is not None:
            prof.release()
        if gpu is not None:
            gpu.release()
