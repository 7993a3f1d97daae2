"""The GL side: scene upload and one full frame (shared passes + method) of `direct` and `manylights`.

Each timed call ends with `ctx.finish()`, so the time is the GPU's, not the time to queue
commands. The per-stage GPU times of the timed rounds go to `extra_info` (`stage_ms.<stage>`,
medians in ms), read after each round, outside the timed call.
"""
from __future__ import annotations

import numpy as np
import pytest

from bench.gl import Frame, GpuScene, SharedPasses, StageProfiler, check_gl, read_rgb
from bench.gl.context import park
from bench.protocol.registry import load_method
from bench.model.scene import compute_facts

W, H = 128, 96
SCENE = "cornell_spot"
ROUNDS, WARMUP_ROUNDS = 12, 2


@pytest.fixture(scope="module")
def scene_and_facts():
    from bench.model.corpus import load_scene
    scene = load_scene(SCENE)
    return scene, compute_facts(scene)


@pytest.mark.gl
@pytest.mark.benchmark(group="gl")
def test_gpu_scene_upload(benchmark, gl_ctx, scene_and_facts):
    scene, facts = scene_and_facts
    made = []

    def upload():
        gpu = GpuScene(gl_ctx, scene, seed=0, facts=facts)
        gl_ctx.finish()
        made.append(gpu)
        return gpu

    def release_all(*_):
        while made:
            made.pop().release()

    gpu = benchmark.pedantic(upload, teardown=release_all, rounds=ROUNDS, warmup_rounds=WARMUP_ROUNDS)
    assert gpu.triangle_count == scene.triangle_count
    release_all()
    benchmark.extra_info["triangles"] = scene.triangle_count


class FrameRig:
    """The harness's per-row setup (bench.run.harness.run_method) kept alive so one frame can be timed."""

    def __init__(self, ctx, method_name, scene, facts, camera="main", seed=0):
        self.ctx = ctx
        cls = load_method(method_name)
        self.gpu = GpuScene(ctx, scene, seed=seed, facts=facts)
        self.view = self.gpu.view(camera, W, H)
        self.passes = SharedPasses(self.gpu, self.view, cls.needs)
        self.method = cls()
        self.method.prepare(self.gpu, scene, facts, {k: p.default for k, p in cls.params.items()}, self.view)
        self.prof = StageProfiler(ctx, self.passes.stages + tuple(cls.stages))
        self.seed, self.index, self.out = seed, 0, None
        self.stage_samples: dict[str, list] = {}
        check_gl(ctx, f"preparing {method_name}")

    def frame(self):
        self.prof.begin_frame()
        frame = Frame(ctx=self.ctx, gpu=self.gpu, view=self.view, passes=self.passes, index=self.index,
                      seed=self.seed)
        self.passes.render(self.prof)
        self.out = self.method.render(frame, self.prof)
        self.ctx.finish()
        self.index += 1

    def collect(self, *_):
        for stage, ms in self.prof.collect().items():
            self.stage_samples.setdefault(stage, []).append(ms)

    def release(self):
        self.method.release()
        park(self.ctx)
        self.passes.release()
        self.prof.release()
        self.gpu.release()


@pytest.mark.gl
@pytest.mark.benchmark(group="gl")
@pytest.mark.parametrize("method_name", ["direct", "manylights"])
def test_gl_frame(benchmark, gl_ctx, scene_and_facts, method_name):
    scene, facts = scene_and_facts
    rig = FrameRig(gl_ctx, method_name, scene, facts)
    try:
        benchmark.pedantic(rig.frame, teardown=rig.collect, rounds=ROUNDS, warmup_rounds=WARMUP_ROUNDS)
        if not rig.stage_samples:  # benchmarks disabled: one untimed frame, its stage times
            rig.collect()
        check_gl(gl_ctx, f"{method_name} frame")
        for stage, samples in rig.stage_samples.items():
            benchmark.extra_info[f"stage_ms.{stage}"] = float(np.median(samples))
        benchmark.extra_info.update({"method": method_name, "scene": SCENE, "resolution": f"{W}x{H}",
                                     "triangles": scene.triangle_count})
        assert set(rig.stage_samples) == set(rig.prof.declared) - set(rig.out.skipped_stages)
        direct = read_rgb(rig.out.direct)
        assert direct.shape == (H, W, 3) and direct.max() > 0
        if method_name == "manylights":
            assert read_rgb(rig.out.indirect).max() > 0
    finally:
        rig.release()
