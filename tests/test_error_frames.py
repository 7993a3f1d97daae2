"""Issue #24: the error frames (frames 0..K-1 of each row's instance, read back outside the timed
regions) and the error over
frames they give: bias2, variance, flicker and mse_accumulated, with intervals over pixels.

(a) the identity E[single-frame MSE] = bias2 + variance, and each column against its closed form,
    on test methods of known per-pixel statistics (independent frames, and frames that reuse the
    previous frame's noise: temporal reuse);
(b) deterministic methods (`direct`, `manylights`, `pbgi` not amortised) have variance and
    flicker exactly 0 through a real run; a stochastic one (`ir_unshadowed`) does not;
(c) the row cache keeps the statistics: the same K is a hit with identical columns, another K
    renders again, an entry without them is a miss.
"""
import json
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from bench.analysis.evaluation import decomposition, evaluate_row
from bench.model.imageio import read_exr
from bench.protocol.method import FrameOutput, MethodBase
from bench.protocol.vocabulary import (DECOMPOSITION_COMPONENTS, DECOMPOSITION_METRICS, FRAME_STAT_IMAGES,
                                       error_metric_names, frame_stat_image)
from bench.run.harness import FrameStatistics, run_method
from bench.run.serial import RunConfig, run
from tests.conftest import cli_run_config, make_open_box

W, H, K = 80, 60, 8   # 4,800 pixels: intervals of about 1.5% of the variance


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))


# ---------------------------------------------------------------------------- (a) known statistics
def fields(h=H, w=W):
    """The test methods' per-pixel mean mu and noise sd sigma, and the target r they are judged
    against (biased on the right half of the image, unbiased on the left)."""
    y, x = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
    base = np.stack([0.2 + 0.3 * x, 0.3 + 0.1 * y, 0.25 + 0.2 * x * y], axis=-1)
    mu = base
    sigma = 0.02 + 0.06 * np.stack([y, x, 1 - x], axis=-1)
    r = base - 0.03 * (x > 0.5)[..., None]
    return mu, sigma, r


def noise(index: int, h=H, w=W) -> np.ndarray:
    """Standard normal noise seeded by the frame index (the same draw for the same frame)."""
    return np.random.default_rng([24, index + 1]).standard_normal((h, w, 3))


class KnownNoise(MethodBase):
    """Frame k = mu + sigma n_k, n_k independent across frames: bias mu - r, variance sigma^2."""
    name = "known_noise"
    summary = "test method of known statistics"

    def prepare(self, gpu, scene, facts, params, view):
        self.mu, self.sigma, _ = fields(view.height, view.width)

    def frame_noise(self, index):
        return noise(index, *self.mu.shape[:2])

    def render(self, frame, prof):
        return FrameOutput(direct=None, indirect=(self.mu + self.sigma * self.frame_noise(frame.index)).astype(np.float32))


class ReusedNoise(KnownNoise):
    """Temporal reuse: frame k = mu + sigma (n_k + n_{k-1}) / sqrt(2), n_{k-1} kept from the
    previous frame (a fresh instance draws it). Variance sigma^2, correlation 1/2 between
    consecutive frames: flicker sigma^2 / 2, and E[V] = sigma^2 (1 - 1/K) over K frames."""
    name = "reused_noise"

    def prepare(self, gpu, scene, facts, params, view):
        super().prepare(gpu, scene, facts, params, view)
        self.previous = None

    def frame_noise(self, index):
        if self.previous is None:
            self.previous = noise(index - 1, *self.mu.shape[:2])
        current = noise(index, *self.mu.shape[:2])
        out = (current + self.previous) / np.sqrt(2.0)
        self.previous = current
        return out


def reference(r, s):
    """A noisy reference of mean r and variance s (of its mean), seeded apart from the frames."""
    return r + np.sqrt(s) * np.random.default_rng([24, 10_000]).standard_normal(r.shape)


def judge(stats, r, s, frames=K, row_image=None):
    """The decomposition columns of `indirect` against reference r (variance s)."""
    R = reference(r, s).astype(np.float32)
    zeros = np.zeros_like(R)
    image = row_image if row_image is not None else stats[frame_stat_image("indirect", "mean")]
    images = {"direct": zeros, "indirect": image, "combined": image}
    refs = {"direct": zeros, "indirect_unshadowed": R, "indirect_visible": R}
    variances = {"direct": zeros, "indirect_unshadowed": s.astype(np.float32), "indirect_visible": s.astype(np.float32)}
    return evaluate_row(images, refs, ref_variances=variances, frame_stats=stats, error_frames=frames), R


def within(out, metric, truth, component="indirect"):
    value, ci = out[f"{metric}.{component}"], out[f"{metric}_ci.{component}"]
    assert np.isfinite(ci) and ci > 0, metric
    assert abs(value - truth) <= ci, f"{metric}: {value:.6g} vs closed form {truth:.6g}, interval {ci:.3g}"


def test_identity_and_closed_forms_on_independent_frames(gl_ctx):
    """E[single-frame MSE] = bias2 + variance (bench.analysis.evaluation's docstring), and each
    column against its closed form within its 95% interval over pixels."""
    result = run_method(gl_ctx, KnownNoise, make_open_box(), "main", W, H, frames=1, error_frames=K)
    assert result.extra["error_frames"] == K and set(result.frame_stats) == set(FRAME_STAT_IMAGES)
    mu, sigma, r = fields()
    s = np.full_like(r, 1e-4)   # the reference's own noise, removed by every column
    out, R = judge(result.frame_stats, r, s, row_image=result.indirect)
    bias2, var = float(np.mean((mu - r) ** 2)), float(np.mean(sigma ** 2))
    within(out, "bias2", bias2)
    within(out, "variance", var)
    within(out, "flicker", var)                       # independent frames: flicker = variance
    within(out, "mse_accumulated", bias2 + var / K)   # what averaging K frames reaches
    weight = 1.0 / (R.astype(np.float64) ** 2 + 0.01 * np.mean(R.astype(np.float64) ** 2))
    within(out, "rel_variance", float(np.mean(sigma ** 2 * weight)))
    # relative to a noiseless reference (a noisy one shares its noise between the error and the
    # weight: a second-order bias, bench.analysis.evaluation)
    exact, _ = judge(result.frame_stats, r, np.zeros_like(r))
    weight = 1.0 / (r ** 2 + 0.01 * np.mean(r ** 2))
    within(exact, "rel_bias2", float(np.mean((mu - r) ** 2 * weight)))
    within(exact, "rel_variance", float(np.mean(sigma ** 2 * weight)))
    within(exact, "rel_flicker", float(np.mean(sigma ** 2 * weight)))
    within(exact, "rel_mse_accumulated", float(np.mean(((mu - r) ** 2 + sigma ** 2 / K) * weight)))
    # the identity: bias2 + variance is exactly the K frames' mean single-frame MSE net of the
    # reference's noise, whose expectation is the closed form
    frames = [mu + sigma * noise(k) for k in range(K)]
    single = np.mean([np.mean((f.astype(np.float32).astype(np.float64) - R) ** 2 - s) for f in frames])
    assert out["bias2.indirect"] + out["variance.indirect"] == pytest.approx(single, rel=1e-4)
    ci = float(np.hypot(out["bias2_ci.indirect"], out["variance_ci.indirect"]))
    assert abs(out["bias2.indirect"] + out["variance.indirect"] - (bias2 + var)) <= ci
    # and the row's own single-frame MSE (frame 0, the timed instance's image) is one draw of it
    per_pixel = np.mean((result.indirect.astype(np.float64) - R) ** 2 - s, axis=2).ravel()
    assert out["mse.indirect"] - float(s.mean()) == pytest.approx(per_pixel.mean(), rel=1e-5)
    assert abs(per_pixel.mean() - (bias2 + var)) <= 1.96 * per_pixel.std(ddof=1) / np.sqrt(per_pixel.size)
    # the row's image is frame 0, which the fresh instance renders again
    assert np.array_equal(result.indirect, (mu + sigma * noise(0)).astype(np.float32))


def test_temporal_reuse_flickers_less_than_its_variance(gl_ctx):
    result = run_method(gl_ctx, ReusedNoise, make_open_box(), "main", W, H, frames=3, error_frames=K)
    mu, sigma, r = fields()
    out, _ = judge(result.frame_stats, r, np.zeros_like(r))
    var = float(np.mean(sigma ** 2))
    within(out, "flicker", var / 2)
    within(out, "variance", var * (1 - 1 / K))
    assert out["flicker.indirect"] < out["variance.indirect"]
    # the row's image is frame 0, and the statistics are those of frames 0..K-1 (the timing
    # stopped after 4 frames, the rest rendered untimed): their mean is not frame 0
    first = (mu + sigma * (noise(0) + noise(-1)) / np.sqrt(2.0)).astype(np.float32)
    assert np.array_equal(result.indirect, first)
    assert not np.array_equal(result.frame_stats[frame_stat_image("indirect", "mean")], first)


def expected_statistics(method_cls, count=K):
    """The statistics of frames 0..count-1 of a fresh instance, rendered here frame by frame."""
    method = method_cls()
    method.prepare(None, None, None, {}, SimpleNamespace(width=W, height=H))
    stats = FrameStatistics(), FrameStatistics()
    for index in range(count):
        image = method.render(SimpleNamespace(index=index), None).indirect
        stats[0].add(image)
        stats[1].add(image)   # combined = direct (0) + indirect
    return {frame_stat_image(c, name): img for c, acc in zip(("indirect", "combined"), stats)
            for name, img in acc.images().items()}


@pytest.mark.parametrize("frames", [1, 3, K + 2])
def test_error_frames_are_the_first_k_whatever_the_timing_renders(gl_ctx, frames):
    """Frames 0..K-1 in order, with the temporal state they carry: the same statistics whether the
    timing stops before K frames (the rest rendered untimed) or goes past them."""
    result = run_method(gl_ctx, ReusedNoise, make_open_box(), "main", W, H, frames=frames, error_frames=K)
    expected = expected_statistics(ReusedNoise)
    assert set(result.frame_stats) == set(expected)
    for name, image in expected.items():
        assert np.array_equal(result.frame_stats[name], image), name
    # the warm-up and the timed frames (twice as many with a fence-serialised stage clock) come first
    timed = 1 + frames * (2 if result.stage_clock == "finish_wall" else 1)
    assert result.extra["error_frames_rendered"] == max(0, K - timed)


@pytest.mark.parametrize("method", ["ir_unshadowed", "flc", "ssdo", "dss", "pbgi"])
def test_real_methods_error_frames_do_not_depend_on_the_timing(gl_ctx, method):
    """At defaults, the statistics are bit-identical whether the timed frames cover the K error
    frames or not (the profiler, the read-backs and the untimed frames change no image)."""
    from bench.protocol.registry import load_method
    cls = load_method(method)
    few = run_method(gl_ctx, cls, make_open_box(), "main", 32, 24, frames=1, error_frames=4)
    many = run_method(gl_ctx, cls, make_open_box(), "main", 32, 24, frames=5, error_frames=4)
    assert few.extra["error_frames_rendered"] > 0 and many.extra["error_frames_rendered"] == 0
    for name, image in few.frame_stats.items():
        assert np.array_equal(image, many.frame_stats[name]), (method, name)
    assert np.array_equal(few.indirect, many.indirect)


def test_frame_statistics_are_exact_for_identical_frames():
    acc = FrameStatistics()
    frame = np.random.default_rng(0).random((4, 5, 3)).astype(np.float32) * 7.3
    for _ in range(3):
        acc.add(frame)
    images = acc.images()
    assert np.array_equal(images["mean"], frame) and not images["var"].any() and not images["flicker"].any()
    with pytest.raises(ValueError, match="at least 2 frames"):
        FrameStatistics().images()


def test_decomposition_columns_and_their_absence():
    mu, sigma, r = fields(10, 12)
    stats = {frame_stat_image(c, s): a.astype(np.float32) for c in ("indirect", "combined")
             for s, a in (("mean", mu), ("var", sigma ** 2), ("flicker", 2 * sigma ** 2))}
    out, _ = judge(stats, r, np.zeros_like(r))
    assert {f"{m}.{c}" for m in DECOMPOSITION_METRICS for c in DECOMPOSITION_COMPONENTS} <= set(out)
    assert {f"{m}_ci.{c}" for m in DECOMPOSITION_METRICS for c in DECOMPOSITION_COMPONENTS} <= set(out)
    assert not any(k.endswith(".direct") and k.split(".")[0] in DECOMPOSITION_METRICS for k in out)
    assert out["flicker.indirect"] == pytest.approx(out["variance.indirect"], rel=1e-6)
    # one error frame: no decomposition columns
    out1, _ = judge(stats, r, np.zeros_like(r), frames=1)
    assert not any(k.split(".")[0] in DECOMPOSITION_METRICS for k in out1)
    assert set(DECOMPOSITION_METRICS) <= set(error_metric_names())
    with pytest.raises(ValueError, match="at least 2 frames"):
        decomposition(mu, sigma, sigma, r, r, np.ones(r.shape[:2], bool), 1)


def test_memo_key_covers_the_frame_statistics(tmp_path):
    mu, sigma, r = fields(10, 12)
    stats = {frame_stat_image(c, s): a.astype(np.float32) for c in ("indirect", "combined")
             for s, a in (("mean", mu), ("var", sigma ** 2), ("flicker", sigma ** 2))}
    zeros = np.zeros_like(r, dtype=np.float32)
    images = {"direct": zeros, "indirect": mu.astype(np.float32), "combined": mu.astype(np.float32)}
    refs = {"direct": zeros, "indirect_unshadowed": r.astype(np.float32), "indirect_visible": r.astype(np.float32)}
    memo = tmp_path / "memo"
    first = evaluate_row(images, refs, memo, frame_stats=stats, error_frames=K)
    again = evaluate_row(images, refs, memo, frame_stats=stats, error_frames=K)
    assert first == again
    other_k = evaluate_row(images, refs, memo, frame_stats=stats, error_frames=4)
    assert other_k["bias2.indirect"] != first["bias2.indirect"]
    noisy_ref = evaluate_row(images, refs, memo, frame_stats=stats, error_frames=K,
                             ref_variances={c: np.full_like(zeros, 1e-3) for c in refs})
    assert noisy_ref["bias2.indirect"] == pytest.approx(first["bias2.indirect"] - 1e-3, rel=1e-5)
    flicker = dict(stats, **{frame_stat_image("indirect", "flicker"): 2 * stats[frame_stat_image("indirect", "flicker")]})
    assert evaluate_row(images, refs, memo, frame_stats=flicker, error_frames=K)["flicker.indirect"] \
        == pytest.approx(2 * first["flicker.indirect"], rel=1e-6)


# ---------------------------------------------------------------------------- (b) real methods, a real run
def small_run(tmp_path, out, **kw):
    base = dict(scenes=[make_open_box()], methods=["direct", "manylights"], width=32, height=24, frames=1,
                warmup=1, out=tmp_path / out, references=False, progress=False, error_frames=3)
    base.update(kw)
    return run(RunConfig(**base), log=lambda m: None)


def test_deterministic_methods_have_no_variance_nor_flicker(tmp_path):
    """`direct`, `manylights` and `pbgi` at their defaults, except pbgi's `emitter_budget`: its
    default (2048) amortises the gather over frames, 0 gathers every emitter in every frame."""
    df, runner = small_run(tmp_path, "det", methods=["direct", "manylights", "pbgi", "ir_unshadowed"],
                           params={"pbgi": [{"emitter_budget": 0}]})
    assert list(df.status) == ["ok"] * 4 and (df["extra.error_frames"] == 3).all()
    assert (df["error_frames_ms"] > 0).all()
    manifest = json.loads((runner.run_dir / "manifest.json").read_text())
    assert manifest["phases_s"]["error_frames"] > 0 and manifest["arguments"]["error_frames"] == 3
    for rec in df.to_dict("records"):
        d = runner.run_dir / rec["image_dir"]
        for comp in ("indirect", "combined"):
            mean, var, flicker = (read_exr(d / f"{comp}_frames_{s}.exr") for s in ("mean", "var", "flicker"))
            if rec["method"] == "ir_unshadowed":   # per-frame VPL sampling: a stochastic method
                assert var.max() > 0 and flicker.max() > 0
                continue
            assert not var.any() and not flicker.any(), (rec["method"], comp)
            assert np.array_equal(mean, read_exr(d / f"{comp}.exr")), (rec["method"], comp)


# ---------------------------------------------------------------------------- (c) the row cache
def fake_refs(run_dir, rec):
    """References standing in for Mitsuba's: the row's own combined image, dimmed, with a variance."""
    base = read_exr(run_dir / rec["image_dir"] / "combined.exr") * 0.9 + 0.01
    return {c: SimpleNamespace(mean=base / (1 if c == "direct" else 3), variance=np.full_like(base, 1e-5))
            for c in ("direct", "indirect_unshadowed", "indirect_visible")}


def test_row_cache_keeps_the_error_frames(tmp_path):
    from bench.run.references import judge_row
    common = dict(methods=["ir_unshadowed"], error_frames=3)
    df_a, ra = small_run(tmp_path, "a", **common)
    df_b, rb = small_run(tmp_path, "b", **common)
    assert list(df_a.status) == ["ok"] and list(df_b.status) == ["cached"]
    [a], [b] = df_a.to_dict("records"), df_b.to_dict("records")
    for name in FRAME_STAT_IMAGES:
        assert (ra.run_dir / a["image_dir"] / f"{name}.exr").read_bytes() == \
            (rb.run_dir / b["image_dir"] / f"{name}.exr").read_bytes()
    refs = fake_refs(ra.run_dir, a)
    cols_a = judge_row(ra.run_dir / a["image_dir"], refs, None, a["extra.error_frames"])
    cols_b = judge_row(rb.run_dir / b["image_dir"], refs, None, b["extra.error_frames"])
    assert cols_a == cols_b and cols_a["variance.indirect"] > 0
    # another K is another row: rendered, its statistics over 5 frames
    df_c, rc = small_run(tmp_path, "c", methods=["ir_unshadowed"], error_frames=5)
    [c] = df_c.to_dict("records")
    assert c["status"] == "ok" and c["extra.error_frames"] == 5 and c["row_key"] != a["row_key"]
    assert judge_row(rc.run_dir / c["image_dir"], refs, None, 5) != cols_a
    # one error frame: no statistics, no decomposition columns
    df_d, rd = small_run(tmp_path, "d", methods=["ir_unshadowed"], error_frames=1)
    [d] = df_d.to_dict("records")
    assert d["status"] == "ok" and d["extra.error_frames"] == 1 and d["error_frames_ms"] == 0
    assert not any((rd.run_dir / d["image_dir"] / f"{n}.exr").exists() for n in FRAME_STAT_IMAGES)
    cols_d = judge_row(rd.run_dir / d["image_dir"], refs, None, 1)
    assert "mse.indirect" in cols_d and not any(k.split(".")[0] in DECOMPOSITION_METRICS for k in cols_d)
    # an entry that lost a statistics image is a miss, evicted with a warning
    [entry] = [p for p in (tmp_path / "cache" / "rows").glob("*/*") if (p / "indirect_frames_var.exr").exists()
               and json.loads((p / "row.json").read_text())["row"]["extra.error_frames"] == 3]
    (entry / "indirect_frames_var.exr").unlink()
    logs = []
    df_e, _ = run(RunConfig(scenes=[make_open_box()], methods=["ir_unshadowed"], width=32, height=24, frames=1,
                            warmup=1, out=tmp_path / "e", references=False, progress=False, error_frames=3),
                  log=logs.append)
    assert list(df_e.status) == ["ok"]
    assert any("lacks indirect_frames_var.exr" in m and "evicted" in m for m in logs)


def test_error_frames_are_validated_and_in_the_options():
    from bench.cli import options
    from bench.run.config import ERROR_FRAMES_RANGE
    assert options.ERROR_FRAMES_RANGE == ERROR_FRAMES_RANGE == (1, 64)
    assert RunConfig(scenes=["x"], methods=["m"]).error_frames == options.ERROR_FRAMES == 8
    for bad in (0, 65):
        with pytest.raises(ValueError, match="error_frames"):
            RunConfig(scenes=["x"], methods=["m"], error_frames=bad).validate()


# ---------------------------------------------------------------------------- the columns against Mitsuba
@pytest.mark.mitsuba
def test_columns_against_a_real_reference(tmp_path):
    df, runner = run(RunConfig(scenes=["cornell_spot"], methods=["direct", "manylights", "ir_unshadowed"], width=32,
                               height=24, frames=1, warmup=1, out=tmp_path / "m", references=True,
                               reference_spp_cap=16, progress=False, error_frames=3), log=lambda m: None)
    rows = df.set_index("method")
    for comp in DECOMPOSITION_COMPONENTS:
        for metric in DECOMPOSITION_METRICS:
            assert rows[f"{metric}.{comp}"].notna().all() and rows[f"{metric}_ci.{comp}"].notna().all(), (metric, comp)
        for method in ("direct", "manylights"):   # the same image every frame
            assert rows.loc[method, f"variance.{comp}"] == 0 and rows.loc[method, f"flicker.{comp}"] == 0
            assert rows.loc[method, f"rel_variance.{comp}"] == 0 and rows.loc[method, f"rel_flicker.{comp}"] == 0
            assert rows.loc[method, f"bias2.{comp}"] == rows.loc[method, f"mse_accumulated.{comp}"]
        assert rows.loc["ir_unshadowed", f"variance.{comp}"] > 0
    assert not any(f"{m}.direct" in df.columns for m in DECOMPOSITION_METRICS)
    # deterministic: the accumulated error is the single-frame MSE net of the reference's noise
    m = rows.loc["manylights"]
    assert m["mse_accumulated.indirect"] == pytest.approx(
        m["mse.indirect"] - m["reference_noise_floor.indirect_unshadowed"], rel=0.05, abs=3 * m["mse_accumulated_ci.indirect"])
    # a re-run is cached with identical columns
    df2, _ = run(RunConfig(scenes=["cornell_spot"], methods=["direct", "manylights", "ir_unshadowed"], width=32,
                           height=24, frames=1, warmup=1, out=tmp_path / "m2", references=True,
                           reference_spp_cap=16, progress=False, error_frames=3), log=lambda m: None)
    assert set(df2.status) == {"cached"}
    cols = [c for c in df.columns if c.split(".")[0] in DECOMPOSITION_METRICS or c.split(".")[0].endswith("_ci")]
    pd.testing.assert_frame_equal(df[cols].reset_index(drop=True), df2[cols].reset_index(drop=True))


@pytest.mark.parametrize("command, extra, expected", [
    ("run", [], 8), ("run", ["--quick"], 4), ("run", ["--quick", "--error-frames", "16"], 16),
    ("run", ["--error-frames", "1"], 1), ("sweep", [], 8), ("sweep", ["--error-frames", "2"], 2),
])
def test_error_frames_option_reaches_the_run_config(monkeypatch, command, extra, expected):
    cfg = cli_run_config(monkeypatch, [command, "--scenes", "cornell_spot", "--methods", "direct", "--no-progress"] + extra)
    seen = [cfg.error_frames]
    assert seen == [expected]


@pytest.mark.parametrize("value", ["0", "65", "many"])
def test_bad_error_frames_is_one_line(capsys, value):
    from bench.cli import main
    with pytest.raises(SystemExit) as info:
        main(["run", "--scenes", "cornell_spot", "--error-frames", value])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "--error-frames" in err and "[1, 64]" in err and len(err.strip().splitlines()) == 1


# ---------------------------------------------------------------------------- (a') the identity on flc
class RecordedFrames:
    """bench.run.harness.FrameStatistics that also keeps every frame it is given (the test's view
    of the error frames one by one)."""
    kept: list = []

    def __init__(self):
        self.inner = FrameStatistics()

    def add(self, image):
        RecordedFrames.kept.append(np.asarray(image, np.float64).copy())
        self.inner.add(image)

    def images(self):
        return self.inner.images()


@pytest.mark.parametrize("scene_name", ["cornell_spot", "rooms", "lit_wall_corner"])
def test_identity_on_flc(gl_ctx, monkeypatch, scene_name):
    """E[single-frame MSE] = bias2 + variance on FLC, whose stochastic cut, interleaving tile and
    jitter are drawn anew each frame: bias2 + variance from one row's K error frames (seed 1)
    against the mean single-frame MSE of K other frames (seed 2, independent of the first), at
    frame level: FLC's draws are global per frame (one tile offset, one level hash for the whole
    image), so its pixels' errors are correlated and only frames are independent samples. The
    target is fixed (the identity holds for any fixed reference): one frame of FLC's own target
    (`manylights` with the FLC lobe over jittered VPLs), near FLC's mean, so that the variance is
    most of the MSE."""
    import bench.run.harness as harness
    from bench.model.corpus import load_scene
    from bench.protocol.registry import load_method
    scene = load_scene(scene_name)
    camera = next(iter(scene.cameras))
    w, h, k = 64, 48, 48
    target = run_method(gl_ctx, load_method("manylights"), scene, camera, w, h, frames=1, seed=99,
                        params={"emission": "flc", "jitter_frames": 8}).indirect.astype(np.float64)
    row = run_method(gl_ctx, load_method("flc"), scene, camera, w, h, frames=1, seed=1, error_frames=k)
    stats = row.frame_stats
    d = decomposition(stats[frame_stat_image("indirect", "mean")], stats[frame_stat_image("indirect", "var")],
                      stats[frame_stat_image("indirect", "flicker")], target, np.zeros_like(target),
                      np.ones((h, w), bool), k)
    predicted, variance = d["bias2"][0] + d["variance"][0], d["variance"][0]
    monkeypatch.setattr(harness, "FrameStatistics", RecordedFrames)
    RecordedFrames.kept = []
    run_method(gl_ctx, load_method("flc"), scene, camera, w, h, frames=1, seed=2, error_frames=k)
    frames = RecordedFrames.kept[0::2]   # indirect, combined, indirect, ...: the indirect ones
    assert len(frames) == k
    mse = np.array([np.mean((f - target) ** 2) for f in frames])
    # bias2 + variance is exactly the mean single-frame MSE of the row's K frames, so the two sides
    # are means of K independent frames' MSEs each
    interval = 1.96 * mse.std(ddof=1) * np.sqrt(2 / k)
    assert abs(mse.mean() - predicted) <= interval, \
        f"{scene_name}: single-frame MSE {mse.mean():.4g} vs bias2 + variance {predicted:.4g} (interval {interval:.2g})"
    assert interval < 0.5 * variance   # the interval separates the identity from "MSE = bias2"


def test_results_tables_hold_the_error_over_frames_as_numbers(tmp_path):
    """A hand-edited cell of an error-over-frames column (or of its interval) is a one-line error."""
    from bench.protocol.results import ResultsError, load_results, numeric_column
    for column in ("bias2.indirect", "rel_flicker_ci.combined", "mse_accumulated.indirect_visible", "error_frames_ms",
                   "extra.error_frames"):
        assert numeric_column(column), column
    df = pd.DataFrame([{"scene": "s", "view": "v", "method": "m", "params": "{}", "seed": 0, "status": "skipped: x",
                        "variance_ci.indirect": "wide"}])
    df.to_csv(tmp_path / "results.csv", index=False)
    with pytest.raises(ResultsError, match="variance_ci.indirect holds 'wide' in row 2"):
        load_results(tmp_path)


class FalselyIdentical(KnownNoise):
    """Declares identical frames but draws new noise every frame."""
    name = "falsely_identical"

    @classmethod
    def frames_identical(cls, params):
        return True


class TrulyIdentical(KnownNoise):
    """Declares identical frames and renders the same frame every time."""
    name = "truly_identical"
    rendered = 0

    @classmethod
    def frames_identical(cls, params):
        return True

    def frame_noise(self, index):
        TrulyIdentical.rendered += 1
        return noise(0, *self.mu.shape[:2])


def test_declared_identical_frames_render_two_and_are_checked(gl_ctx):
    """A method that declares identical frames renders 2 of the K error frames, and its statistics
    are exactly those of K identical frames; a false declaration fails with a one-line error."""
    TrulyIdentical.rendered = 0
    run_method(gl_ctx, TrulyIdentical, make_open_box(), "main", 16, 12, frames=1, warmup=1, error_frames=1)
    timed_only, TrulyIdentical.rendered = TrulyIdentical.rendered, 0
    result = run_method(gl_ctx, TrulyIdentical, make_open_box(), "main", 16, 12, frames=1, warmup=1, error_frames=K)
    assert TrulyIdentical.rendered == timed_only   # the 2 error frames of the K are the timed instance's 0 and 1
    frame = result.indirect
    assert np.array_equal(result.frame_stats[frame_stat_image("indirect", "mean")], frame)
    assert not result.frame_stats[frame_stat_image("indirect", "var")].any()
    assert not result.frame_stats[frame_stat_image("indirect", "flicker")].any()
    with pytest.raises(RuntimeError, match="falsely_identical.*declares identical frames.*frame 1 differs"):
        run_method(gl_ctx, FalselyIdentical, make_open_box(), "main", 16, 12, frames=1, error_frames=K)
    from bench.protocol.registry import load_method
    assert load_method("direct").frames_identical({}) and load_method("manylights").frames_identical(
        {"jitter_frames": 1}) and not load_method("manylights").frames_identical({"jitter_frames": 4})
    assert not load_method("flc").frames_identical({})
