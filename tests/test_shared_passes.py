"""Shared passes rendered once per view and lent to every method and rung (issue #14): the same
images as rendering them in each frame, their measured cost in every row's frame time, and no
method writing them."""
import json

import numpy as np
import pytest

from bench.gl import GpuScene, SharedPasses
from bench.gl.passes import shared_variant, stages_for_needs
from bench.kit.rendered_checks import changed_textures, snapshot
from bench.run.harness import measure_shared_passes, run_method
from bench.protocol.registry import list_methods, load_method
from tests.conftest import make_grid_box, make_open_box
from tests.fixtures.conformance import verdicts_of

W, H, SHADOW = 64, 48, 256


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))


def count_shared_renders(monkeypatch) -> dict:
    """{'n': how many times SharedPasses.render has run since}: the real render, counted."""
    calls = {"n": 0}
    real = SharedPasses.render

    def counting(self, prof):
        calls["n"] += 1
        return real(self, prof)

    monkeypatch.setattr(SharedPasses, "render", counting)
    return calls


def lend(ctx, gpu, needs, frames=2):
    passes = SharedPasses(gpu, gpu.view("main", W, H), needs, shadow_resolution=SHADOW)
    return measure_shared_passes(ctx, passes, warmup=1, frames=frames)


def union_needs(*classes):
    out = frozenset()
    for cls in classes:
        out |= frozenset(cls.needs)
    return out


def test_two_methods_with_lent_passes_give_the_images_of_their_own(gl_ctx):
    """manylights (no RSM) and ir_unshadowed (RSM) on one view, both reading passes built once
    with the union of their needs, give bit for bit the frame-0 images of run_method alone."""
    scene = make_grid_box(n=3)
    classes = [load_method("manylights"), load_method("ir_unshadowed")]
    alone = {cls.name: run_method(gl_ctx, cls, scene, "main", W, H, warmup=1, frames=1, shadow_resolution=SHADOW)
             for cls in classes}
    gpu = GpuScene(gl_ctx, scene)
    try:
        shared = lend(gl_ctx, gpu, union_needs(*classes))
        assert shared.passes.rsm is not None
        for cls in classes + classes[:1]:   # manylights again after a method that used the RSM
            got = run_method(gl_ctx, cls, scene, "main", W, H, warmup=1, frames=1, shadow_resolution=SHADOW,
                             gpu=gpu, shared=shared)
            assert np.array_equal(got.direct, alone[cls.name].direct), cls.name
            assert np.array_equal(got.indirect, alone[cls.name].indirect), cls.name
            assert got.indirect.max() > 0
        shared.passes.release()
    finally:
        gpu.release()


def test_every_method_only_reads_the_shared_passes(gl_ctx):
    """Protocol: with the passes lent, every registered method (default parameters) leaves every
    shared texture as it found it, and its images are those of a row with passes of its own: the
    conformance suite's `shared_passes` check (bench.kit), which every method must pass."""
    ran = []
    for name in list_methods():
        cls = load_method(name)
        check = verdicts_of(name)["shared_passes"]
        assert check.ok, f"method '{name}' {check.reason}"
        if cls.reuses_shared_passes:
            assert "shared textures unchanged, the same images as with its own" in check.reason, (name, check.reason)
        else:
            assert "declares reuses_shared_passes = False" in check.reason, (name, check.reason)
        ran.append(name)
    assert sorted(ran) == sorted(list_methods()), f"only {ran} ran"


@pytest.mark.parametrize("clock", ["gl_query", "finish_wall"])
def test_a_rows_frame_time_includes_the_shared_cost(gl_ctx, monkeypatch, clock):
    """`direct` has no stage of its own: its stages are the shared measurement's, its frame time
    is its own (a finish) plus their medians; manylights adds the same constant to its own."""
    monkeypatch.setenv("GIBENCH_STAGE_CLOCK", clock)
    scene = make_open_box()
    direct, manylights = load_method("direct"), load_method("manylights")
    gpu = GpuScene(gl_ctx, scene)
    try:
        shared = lend(gl_ctx, gpu, union_needs(direct, manylights, load_method("ir_unshadowed")), frames=3)
        assert set(shared.stage_ms) == {"gbuffer_shadow", "direct_light", "rsm"}
        assert shared.stage_clock == clock and shared.frames == 3
        for cls in (direct, manylights):
            r = run_method(gl_ctx, cls, scene, "main", W, H, warmup=1, frames=3, shadow_resolution=SHADOW,
                           gpu=gpu, shared=shared)
            paid = stages_for_needs(cls.needs)
            assert paid == ("gbuffer_shadow", "direct_light")   # not the RSM, which neither needs
            assert r.extra["shared_passes_reused"] is True and r.extra["shared_frames"] == 3
            assert r.extra["shared_ms"] == pytest.approx(sum(float(np.median(shared.stage_ms[s])) for s in paid),
                                                         rel=1e-12)
            for s in paid:
                assert r.stage_ms[s] == shared.stage_ms[s]
            assert list(r.stage_ms)[:2] == list(paid) and "rsm" not in r.stage_ms
            assert set(r.stage_ms) - set(paid) == set(cls.stages)
            assert len(r.frame_ms) == 3 and all(ms >= r.extra["shared_ms"] for ms in r.frame_ms)
            assert float(np.median(r.frame_ms)) == pytest.approx(r.extra["own_frame_ms"] + r.extra["shared_ms"],
                                                                 rel=1e-12)
        # direct: its own stages are none, so its GPU total is exactly the shared cost it pays
        r = run_method(gl_ctx, direct, scene, "main", W, H, warmup=1, frames=2, shadow_resolution=SHADOW,
                       gpu=gpu, shared=shared)
        gpu_total = sum(float(np.median(v)) for v in r.stage_ms.values())
        assert gpu_total == pytest.approx(r.extra["shared_ms"], rel=1e-12)
        shared.passes.release()
    finally:
        gpu.release()


def test_lent_passes_are_not_rendered_again(gl_ctx, monkeypatch):
    monkeypatch.setenv("GIBENCH_STAGE_CLOCK", "finish_wall")
    scene = make_open_box()
    direct = load_method("direct")
    gpu = GpuScene(gl_ctx, scene)
    calls = count_shared_renders(monkeypatch)
    try:
        shared = lend(gl_ctx, gpu, direct.needs, frames=2)
        assert calls["n"] == 3   # one warm-up + two timed frames
        run_method(gl_ctx, direct, scene, "main", W, H, warmup=2, frames=3, shadow_resolution=SHADOW,
                   gpu=gpu, shared=shared)
        assert calls["n"] == 3

        class WritesShared(direct):
            reuses_shared_passes = False   # what a method that writes the passes declares

        r = run_method(gl_ctx, WritesShared, scene, "main", W, H, warmup=1, frames=2, shadow_resolution=SHADOW,
                       gpu=gpu, shared=shared)
        assert calls["n"] == 3 + 1 + 2 * 2   # its own passes in each frame (wall frames + stage frames)
        assert "shared_passes_reused" not in r.extra
        shared.passes.release()
    finally:
        gpu.release()


def test_passes_that_cannot_serve_a_row_are_refused(gl_ctx):
    scene = make_open_box()
    direct = load_method("direct")
    gpu = GpuScene(gl_ctx, scene)
    try:
        shared = lend(gl_ctx, gpu, direct.needs, frames=1)
        with pytest.raises(ValueError, match="view main 64x48, the row renders main 32x24"):
            run_method(gl_ctx, direct, scene, "main", 32, 24, gpu=gpu, shared=shared, shadow_resolution=SHADOW)
        with pytest.raises(ValueError, match="256\\^2 shadow tiles"):
            run_method(gl_ctx, direct, scene, "main", W, H, gpu=gpu, shared=shared, shadow_resolution=512)
        with pytest.raises(ValueError, match="are of scene 'open_box', the row renders 'grid_box'"):
            run_method(gl_ctx, direct, make_grid_box(n=2), "main", W, H, gpu=gpu, shared=shared,
                       shadow_resolution=SHADOW)
        with pytest.raises(ValueError, match="lack the shared pass"):
            run_method(gl_ctx, load_method("ir_unshadowed"), scene, "main", W, H, gpu=gpu, shared=shared,
                       shadow_resolution=SHADOW)
        # the direct pass is shadowed exactly when shadow maps are built: no superset serves both
        assert shared_variant({"direct"}) != shared_variant({"direct", "shadow_map"})
        assert "shadowed differently" in shared.passes.serves({"direct"})
        assert shared.passes.serves({"gbuffer"}) is None and shared.passes.serves(direct.needs) is None
        shared.passes.release()
    finally:
        gpu.release()


def test_runner_renders_each_views_shared_passes_once(tmp_path, monkeypatch):
    """Two methods, two rungs of one: one shared measurement for the view (warm-up + K frames),
    recorded in the manifest, whose medians every row adds to its own frame time."""
    from bench.run.serial import RunConfig, run
    calls = count_shared_renders(monkeypatch)
    cfg = RunConfig(scenes=[make_open_box()], methods=["direct", "manylights"], width=32, height=24, frames=2,
                    warmup=1, out=tmp_path / "run", references=False, progress=False,
                    params={"manylights": [{}, {"emission": "flc"}]})
    df, runner = run(cfg, log=lambda m: None)
    assert list(df.status) == ["ok", "ok", "ok"]
    assert calls["n"] == 1 + 2
    manifest = json.loads((runner.run_dir / "manifest.json").read_text())
    measured = manifest["shared_passes"]["open_box/main"]["standard"]
    assert measured["frames"] == 2 and set(measured["median_ms"]) == {"gbuffer_shadow", "direct_light"}
    for rec in df.to_dict("records"):
        assert rec["extra.shared_passes_reused"] is True or rec["extra.shared_passes_reused"] == 1
        for stage, med in measured["median_ms"].items():
            assert rec[f"stage_ms.{stage}"] == pytest.approx(med, abs=1e-4)
        assert rec["extra.shared_ms"] == pytest.approx(sum(measured["median_ms"].values()), abs=1e-3)
        assert rec["frame_ms"] == pytest.approx(rec["extra.own_frame_ms"] + rec["extra.shared_ms"], rel=1e-9)
        assert len(json.loads(rec["samples.stage_ms"])["gbuffer_shadow"]) == 2
    phases = manifest["phases_s"]
    assert phases["timing"] > 0 and manifest["harness_overhead"] >= 0


def test_a_method_writing_the_shared_passes_is_caught(gl_ctx):
    """The snapshot the protocol test compares sees a write (here: the broken plugin of the
    conformance fixtures, which clears the direct pass)."""
    from tests.fixtures.plugins.writes_shared.method import WritesShared as ClearsDirect
    direct = load_method("direct")
    scene = make_open_box()
    gpu = GpuScene(gl_ctx, scene)
    try:
        shared = lend(gl_ctx, gpu, direct.needs, frames=1)
        before = snapshot(shared.passes)
        run_method(gl_ctx, ClearsDirect, scene, "main", W, H, warmup=1, frames=1, shadow_resolution=SHADOW,
                   gpu=gpu, shared=shared)
        assert changed_textures(before, snapshot(shared.passes)) == ["direct.radiance"]
        shared.passes.release()
    finally:
        gpu.release()


def test_a_rows_timing_budget_is_spent_in_frame_time(gl_ctx):
    """Calibrated timing with lent passes charges each frame's shared cost to the budget, so a
    budget bounds the frames of a row as it did when each frame rendered the passes."""
    from bench.run.harness import SharedViewPasses, TimingBudget
    scene = make_open_box()
    direct = load_method("direct")
    gpu = GpuScene(gl_ctx, scene)
    try:
        measured = lend(gl_ctx, gpu, direct.needs, frames=1)
        # the same rendered passes, with a stated cost of 0.8 s per frame
        costly = SharedViewPasses(passes=measured.passes, stage_ms={"gbuffer_shadow": [500.0], "direct_light": [300.0]},
                                  stage_clock=measured.stage_clock)
        never_tight = TimingBudget(budget_s=1.0, max_frames=100, rel_halfwidth=-1.0)
        r = run_method(gl_ctx, direct, scene, "main", W, H, warmup=1, frames=1, shadow_resolution=SHADOW,
                       gpu=gpu, shared=costly, timing=never_tight)
        assert r.extra["shared_ms"] == 800.0
        assert len(r.frame_ms) == 2 and r.extra["timing_frames"] == 2   # 0.8 s < 1 s <= 1.6 s
        measured.passes.release()
    finally:
        gpu.release()
