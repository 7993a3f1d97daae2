"""The runner: images and results, the row cache, resume, failures, skipped rows, determinism."""
import json

import numpy as np
import pandas as pd
import pytest

from bench.model.imageio import read_exr
from bench.run.serial import RunConfig, run
from tests.conftest import make_grid_box, make_open_box


def cfg(tmp_path, out="run", **kw):
    base = dict(scenes=[make_open_box()], methods=["direct", "manylights"], width=32, height=24, frames=2,
                warmup=1, out=tmp_path / out, references=False, progress=False)
    base.update(kw)
    return RunConfig(**base)


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))


def test_run_writes_contract(tmp_path):
    df, runner = run(cfg(tmp_path), log=lambda m: None)
    d = runner.run_dir
    assert (d / "manifest.json").is_file() and (d / "results.csv").is_file() and (d / "results.parquet").is_file()
    manifest = json.loads((d / "manifest.json").read_text())
    assert manifest["machine"]["gl_renderer"] and manifest["scene_facts"]["open_box"]["triangle_count"] == 6
    csv = pd.read_csv(d / "results.csv")
    for col in ("scene", "view", "method", "params", "seed", "width", "height", "frame_ms", "gpu_ms",
                "status", "method_version", "stage_ms.gbuffer_shadow", "stage_ms.gather"):
        assert col in csv.columns, col
    assert list(csv.status) == ["ok", "ok"]
    assert np.isnan(csv.set_index("method").loc["direct", "stage_ms.gather"])
    for method in ("direct", "manylights"):
        for comp in ("direct", "indirect", "combined"):
            img = read_exr(d / "images" / "open_box" / "main" / method / f"{comp}.exr")
            assert img.shape == (24, 32, 3)
    ind = read_exr(d / "images/open_box/main/manylights/indirect.exr")
    assert ind.max() > 0 and read_exr(d / "images/open_box/main/direct/indirect.exr").max() == 0
    samples = json.loads(csv.set_index("method").loc["manylights", "samples.stage_ms"])
    assert len(samples["gather"]) == 2
    summary = (d / "summary.md").read_text()
    assert "| open_box | main | manylights |" in summary and (d / "summary.html").is_file()


def test_second_identical_run_reruns_nothing(tmp_path):
    run(cfg(tmp_path, out="a"), log=lambda m: None)
    df, runner = run(cfg(tmp_path, out="b"), log=lambda m: None)
    assert list(df.status) == ["cached", "cached"] and runner.counts["ok"] == 0
    assert "nothing re-run" in runner.summary()
    a = read_exr(tmp_path / "a/images/open_box/main/manylights/combined.exr")
    b = read_exr(tmp_path / "b/images/open_box/main/manylights/combined.exr")
    assert np.array_equal(a, b)
    df, runner = run(cfg(tmp_path, out="c", force=True), log=lambda m: None)
    assert list(df.status) == ["ok", "ok"]
    # a changed parameter or albedo is a different row: rendered
    df, _ = run(cfg(tmp_path, out="d", params={"manylights": [{"emission": "flc"}]}), log=lambda m: None)
    assert list(df.status) == ["cached", "ok"]
    df, _ = run(cfg(tmp_path, out="e", scenes=[make_open_box(intensity=3.0)]), log=lambda m: None)
    assert list(df.status) == ["ok", "ok"]


def test_same_seed_same_images_without_cache(tmp_path):
    scene = make_grid_box(4)
    common = dict(scenes=[scene], methods=["manylights"], params={"manylights": [{"jitter_frames": 4}]})
    run(cfg(tmp_path, out="a", seed=7, **common), log=lambda m: None)
    run(cfg(tmp_path, out="b", seed=7, force=True, **common), log=lambda m: None)
    run(cfg(tmp_path, out="c", seed=8, force=True, **common), log=lambda m: None)
    imgs = [read_exr(next((tmp_path / o / "images/grid_box/main").glob("manylights*")) / "indirect.exr")
            for o in "abc"]
    assert np.array_equal(imgs[0], imgs[1]) and not np.array_equal(imgs[0], imgs[2])


def test_failures_are_recorded_and_others_go_on(tmp_path, monkeypatch):
    from bench.protocol import registry
    from importlib.metadata import EntryPoint
    real = registry.entry_points
    broken = EntryPoint("broken", "no_such_module_abc:Broken", registry.GROUP)
    monkeypatch.setattr(registry, "entry_points", lambda group: list(real(group=group)) + [broken])
    df, runner = run(cfg(tmp_path, methods=["broken", "direct"],
                         params={"direct": [{}]}), log=lambda m: None)
    status = dict(zip(df.method, df.status))
    assert status["broken"].startswith("failed: method 'broken' failed to load")
    assert status["direct"] == "ok"
    # an out-of-range parameter is bad input, found before the first row (issue #15: it used to fail
    # its rows one by one while the run "succeeded")
    with pytest.raises(ValueError, match="jitter_frames"):
        run(cfg(tmp_path, out="p", params={"manylights": [{"jitter_frames": 0}]}), log=lambda m: None)
    assert not (tmp_path / "p" / "results.csv").exists()


def test_skipped_rows(tmp_path):
    df, runner = run(cfg(tmp_path, params={"manylights": [{"max_triangles": 2}]}), log=lambda m: None)
    status = dict(zip(df.method, df.status))
    assert status["manylights"].startswith("skipped:") and runner.counts["skipped"] == 1


def interrupt_the_second_row(monkeypatch):
    """Patch the runner so that its second row raises KeyboardInterrupt; returns the real _run_row."""
    from bench.run import serial as runner_mod
    calls = {"n": 0}
    real = runner_mod.Runner._run_row

    def interrupt_second(self, *a, **k):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return real(self, *a, **k)

    monkeypatch.setattr(runner_mod.Runner, "_run_row", interrupt_second)
    return real


def test_interrupted_run_resumes(tmp_path, monkeypatch):
    from bench.run import serial as runner_mod
    real = interrupt_the_second_row(monkeypatch)
    with pytest.raises(KeyboardInterrupt):
        run(cfg(tmp_path, out="r"), log=lambda m: None)
    assert len(pd.read_csv(tmp_path / "r/results.csv")) == 1  # the finished row was saved
    monkeypatch.setattr(runner_mod.Runner, "_run_row", real)
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "other-cache"))  # no help from the cache
    df, runner = run(cfg(tmp_path, out="r"), log=lambda m: None)
    assert runner.counts["resumed"] == 1 and runner.counts["ok"] == 1 and len(df) == 2


# ---------------------------------------------------------------------------- issue #15: merge, force, bad input
def test_rerun_into_the_same_folder_keeps_other_rows(tmp_path):
    """Fewer methods or another resolution used to drop the earlier rows and orphan their images."""
    run(cfg(tmp_path, out="r"), log=lambda m: None)
    df, _ = run(cfg(tmp_path, out="r", methods=["direct"], width=40, height=32), log=lambda m: None)
    assert len(df) == 3
    got = {(r["method"], r["width"]): r for r in df.to_dict("records")}
    assert set(got) == {("direct", 32), ("manylights", 32), ("direct", 40)}
    for rec in got.values():  # every row's images exist at its own size
        img = read_exr(tmp_path / "r" / rec["image_dir"] / "combined.exr")
        assert img.shape == (rec["height"], rec["width"], 3)
    assert got[("direct", 32)]["image_dir"] != got[("direct", 40)]["image_dir"]
    on_disk = pd.read_csv(tmp_path / "r/results.csv")
    assert len(on_disk) == 3
    # the same command again replaces its own rows, nothing else
    df, runner = run(cfg(tmp_path, out="r", methods=["direct"], width=40, height=32), log=lambda m: None)
    assert len(df) == 3 and runner.counts["resumed"] == 1


def test_interrupted_forced_run_resumes(tmp_path, monkeypatch):
    """--force re-renders, but an interrupted forced run resumes like any other."""
    from bench.run import serial as runner_mod
    run(cfg(tmp_path, out="f"), log=lambda m: None)
    real = interrupt_the_second_row(monkeypatch)
    with pytest.raises(KeyboardInterrupt):
        run(cfg(tmp_path, out="f", force=True), log=lambda m: None)
    monkeypatch.setattr(runner_mod.Runner, "_run_row", real)
    df, runner = run(cfg(tmp_path, out="f", force=True), log=lambda m: None)
    assert runner.counts == {"ok": 1, "cached": 0, "resumed": 1, "failed": 0, "skipped": 0}
    # a finished forced run, run again with --force, re-renders everything
    df, runner = run(cfg(tmp_path, out="f", force=True), log=lambda m: None)
    assert runner.counts["ok"] == 2 and runner.counts["resumed"] == 0


def test_params_are_checked_before_the_first_row(tmp_path):
    with pytest.raises(ValueError, match="--param given for method\\(s\\) flc not in this run"):
        run(cfg(tmp_path, out="p", params={"flc": [{}]}), log=lambda m: None)
    with pytest.raises(ValueError, match="unknown parameter"):
        run(cfg(tmp_path, out="p", params={"manylights": [{}, {"no_such_knob": 1}]}), log=lambda m: None)
    assert not (tmp_path / "p").exists()


def test_unusable_out_is_one_line(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="is a file, not a run folder"):
        run(cfg(tmp_path, out="file"), log=lambda m: None)
    with pytest.raises(ValueError, match="not a writable folder"):
        run(cfg(tmp_path, out="file/sub"), log=lambda m: None)


def test_all_black_view_warns(tmp_path):
    from bench.model.scene import Camera
    scene = make_open_box()
    away = Scene_with_camera(scene, Camera([0, 1, 3.5], [0, 1, 10], fov_y_deg=20))
    logs = []
    run(cfg(tmp_path, out="k", scenes=[away]), log=logs.append)
    warnings = [m for m in logs if "all-black" in m]
    assert len(warnings) == 1 and "open_box/main" in warnings[0]  # once per view, not once per method
    logs.clear()
    run(cfg(tmp_path, out="k2"), log=logs.append)
    assert not [m for m in logs if "all-black" in m]


def test_view_lit_only_by_the_bounce_does_not_warn(tmp_path):
    """hidden_bounce's camera sees no directly lit surface: `direct` is black by design there."""
    logs = []
    run(cfg(tmp_path, out="hb", scenes=["hidden_bounce"], methods=["direct", "manylights"]), log=logs.append)
    assert not [m for m in logs if "all-black" in m]


def Scene_with_camera(scene, camera):
    from bench.model.scene import Scene
    return Scene.build(scene.name, scene.vertices, scene.faces, scene.albedo, scene.lights, {"main": camera},
                       normals=scene.normals)


def test_corrupt_results_tables_are_detected(tmp_path):
    from bench.protocol.results import ResultsError, load_results
    run(cfg(tmp_path, out="t"), log=lambda m: None)
    d = tmp_path / "t"
    good = load_results(d)
    # a CSV cut mid-line, with the parquet intact: the parquet (its checksum holds) is used
    csv = (d / "results.csv").read_bytes()
    (d / "results.csv").write_bytes(csv[:-40])
    assert len(load_results(d)) == len(good)
    # both damaged: an error naming the folder, not a short row
    (d / "results.parquet").write_bytes(b"PAR1 junk")
    with pytest.raises(ResultsError, match="neither results.parquet nor results.csv"):
        load_results(d)
    # without checksums (an older gibench, or files written by hand)
    (d / "results.checksums.json").unlink()
    (d / "results.parquet").unlink()
    with pytest.raises(ResultsError, match="cut mid-line"):
        load_results(d)
    good.to_csv(d / "results.csv", index=False)
    good.iloc[:1].to_parquet(d / "results.parquet", index=False)
    with pytest.raises(ResultsError, match="disagree"):
        load_results(d)
    # and a run into that folder says so instead of dropping the rows, before writing anything (#27)
    before = {f.name: f.read_bytes() for f in d.iterdir() if f.is_file()}
    with pytest.raises(ResultsError):
        run(cfg(tmp_path, out="t"), log=lambda m: None)
    assert {f.name: f.read_bytes() for f in d.iterdir() if f.is_file()} == before


def test_ladders_expand_to_rungs_and_param_overrides_them(tmp_path, monkeypatch):
    from bench.run.config import expand_param_sets
    import bench.run.config as runner_mod

    class Laddered:
        ladder = ({"n": 1}, {}, {"n": 9})
    monkeypatch.setattr(runner_mod, "load_method", lambda name: Laddered)
    base = dict(scenes=["x"], methods=["m"])
    assert expand_param_sets(RunConfig(**base), "m") == [{}]                     # defaults only
    assert expand_param_sets(RunConfig(**base, ladders=True), "m") == [{"n": 1}, {}, {"n": 9}]
    assert expand_param_sets(RunConfig(**base, ladders=True, params={"m": [{"n": 4}]}), "m") == [{"n": 4}]


def test_timing_settles_by_interval_budget_or_cap():
    from bench.protocol.results import median_ci, timing_settled
    steady = [10.0] * 8
    noisy = [10.0, 30.0] * 4
    assert not timing_settled(steady[:2], 3, 0.0, 1.0, 100, 0.05)          # never before the minimum
    assert timing_settled(steady, 3, 0.0, 1.0, 100, 0.05)                  # tight interval
    assert not timing_settled(noisy, 3, 0.1, 1.0, 100, 0.05)               # wide interval, budget left
    assert timing_settled(noisy, 3, 1.5, 1.0, 100, 0.05)                   # budget spent
    assert timing_settled(noisy, 3, 0.1, 1.0, 8, 0.05)                     # frame cap
    lo, hi = median_ci(list(range(100)))
    assert lo < 49.5 < hi and hi - lo < 25


def test_calibrated_row_records_frames_phases_and_overhead(tmp_path):
    df, runner = run(cfg(tmp_path, methods=["direct"], frames=3, timing_budget_s=0.2), log=lambda m: None)
    rec = df.iloc[0]
    samples = json.loads(rec["samples.frame_ms"])
    assert len(samples) >= 3 and rec["extra.timing_frames"] == len(samples)
    # a sample = the method's own frame + the view's shared passes (measured once, outside the row)
    own = [v - rec["extra.shared_ms"] for v in samples]
    assert rec["extra.shared_passes_reused"] and min(own) >= -1e-3
    assert rec["prepare_ms"] >= 0 and rec["frames_total_ms"] >= sum(own) - 1e-3
    assert 0 <= rec["harness_overhead"] < 1 and rec["row_wall_ms"] > 0
    manifest = json.loads((runner.run_dir / "manifest.json").read_text())
    phases = manifest["phases_s"]
    assert phases["timing"] > 0 and phases["scene_upload"] >= 0 and "references" in phases
    assert 0 <= manifest["harness_overhead"] < 1
    assert rec["peak_rss_mb"] > 10 and list(manifest["peak_rss_mb"].values()) == [pytest.approx(rec["peak_rss_mb"], abs=0.1)]


def test_rows_of_a_scene_share_one_upload(tmp_path, monkeypatch):
    import bench.gl
    made = []
    real = bench.gl.GpuScene

    def counting(*a, **k):
        made.append(1)
        return real(*a, **k)
    monkeypatch.setattr(bench.gl, "GpuScene", counting)
    df, _ = run(cfg(tmp_path), log=lambda m: None)
    assert list(df.status) == ["ok", "ok"] and len(made) == 1


def test_shadow_resolution_follows_the_view():
    from bench.run.config import auto_shadow_resolution, effective_shadow_resolution
    assert auto_shadow_resolution(320, 180) == 512 and auto_shadow_resolution(1280, 720) == 2048
    assert auto_shadow_resolution(64, 48) == 256 and auto_shadow_resolution(513, 10) == 1024
    assert effective_shadow_resolution(RunConfig(scenes=["x"], methods=["m"], shadow_resolution=128)) == 128


def test_run_config_refuses_names_that_leave_the_run_folder():
    """Methods and views become folders of the run: a RunConfig built in code is checked as the CLI checks."""
    with pytest.raises(ValueError, match="method name"):
        RunConfig(scenes=["cornell_spot"], methods=["evil/../../x"]).validate()
    with pytest.raises(ValueError, match="view name"):
        RunConfig(scenes=["cornell_spot"], methods=["direct"], views=["../up"]).validate()
    with pytest.raises(ValueError, match="reference spp cap"):
        RunConfig(scenes=["cornell_spot"], methods=["direct"], reference_spp_cap=0).validate()
