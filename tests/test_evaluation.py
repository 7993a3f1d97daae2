"""Error columns of a row: which image is compared with which reference, over which pixels."""
import math

import numpy as np
import pytest

from bench.analysis.evaluation import COMPARISONS, coverage_mask, evaluate_row
from bench.analysis.metrics import METRICS


def scene_images(h=16, w=20):
    """A covered square (rows/cols 4..11) on black background; references with known values."""
    cover = np.zeros((h, w), bool)
    cover[4:12, 4:12] = True
    def fill(v):
        out = np.zeros((h, w, 3), np.float32)
        out[cover] = v
        return out
    refs = {"direct": fill([1.0, 0.8, 0.6]), "indirect_unshadowed": fill([0.2, 0.2, 0.2]),
            "indirect_visible": fill([0.3, 0.3, 0.3])}
    return cover, fill, refs


def test_columns_and_component_pairing():
    cover, fill, refs = scene_images()
    images = {"direct": refs["direct"].copy(), "indirect": fill([0.2, 0.2, 0.2])}
    images["combined"] = images["direct"] + images["indirect"]
    out = evaluate_row(images, refs)
    assert set(out) == {f"{m}.{c}" for m in (*METRICS, "mean_ratio") for c in COMPARISONS}
    # direct matches, indirect equals the unshadowed reference, so only the visibility difference remains
    for m in METRICS:
        assert out[f"{m}.direct"] == pytest.approx(0.0, abs=1e-12), m
        assert out[f"{m}.indirect"] == pytest.approx(0.0, abs=1e-12), m
        assert out[f"{m}.indirect_visible"] > 0, m
        assert out[f"{m}.combined"] > 0, m
    # MSE over covered pixels only: indirect 0.2 against visible 0.3 -> 0.01 (background excluded)
    assert out["mse.indirect_visible"] == pytest.approx(0.01, rel=1e-6)
    assert out["mse.combined"] == pytest.approx(0.01, rel=1e-6)
    # epsilon relative to the reference's level: 0.01 * mean(r^2) = 0.01 * 0.09 (issue #15)
    assert out["relmse.indirect_visible"] == pytest.approx(0.01 / (0.09 + 0.01 * 0.09), rel=1e-6)


def test_mask_includes_method_light_on_background():
    cover, fill, refs = scene_images()
    images = {"direct": refs["direct"].copy(), "indirect": fill([0.2, 0.2, 0.2])}
    images["indirect"][0, 0] = [2.0, 2.0, 2.0]  # the method lights a background pixel
    images["combined"] = images["direct"] + images["indirect"]
    mask = coverage_mask(images, refs)
    assert mask.sum() == cover.sum() + 1 and mask[0, 0]
    out = evaluate_row(images, refs)
    n = cover.sum() + 1
    assert out["mse.indirect"] == pytest.approx(4.0 / n, rel=1e-6)  # the stray pixel counts


def test_missing_reference_component_leaves_columns_out():
    cover, fill, refs = scene_images()
    images = {"direct": refs["direct"].copy(), "indirect": fill([0.3, 0.3, 0.3])}
    images["combined"] = images["direct"] + images["indirect"]
    out = evaluate_row(images, {"direct": refs["direct"], "indirect_unshadowed": None, "indirect_visible": None})
    assert set(out) == {f"{m}.direct" for m in (*METRICS, "mean_ratio")}
    assert all(math.isfinite(v) for v in out.values())


def test_indirect_only_zero_reference_is_finite():
    cover, fill, refs = scene_images()
    refs["indirect_unshadowed"] = np.zeros_like(refs["direct"])
    refs["indirect_visible"] = np.zeros_like(refs["direct"])
    images = {"direct": refs["direct"].copy(), "indirect": fill([0.05, 0.05, 0.05])}
    images["combined"] = images["direct"] + images["indirect"]
    out = evaluate_row(images, refs)
    assert all(math.isfinite(v) for v in out.values()), out
    assert out["flip_mean.indirect"] > 0 and out["mse.indirect"] == pytest.approx(0.0025, rel=1e-5)


def test_bad_input_names_the_culprit():
    cover, fill, refs = scene_images()
    with pytest.raises(ValueError, match="combined"):
        evaluate_row({"direct": refs["direct"], "indirect": refs["direct"]}, refs)
    images = {"direct": refs["direct"].copy(), "indirect": fill([0.4, 0.4, 0.4])}
    images["combined"] = images["direct"] + images["indirect"]
    images["direct"][5, 5, 0] = np.nan
    with pytest.raises(ValueError, match="image has 1 pixel"):
        evaluate_row(images, refs)


def test_mean_ratio_is_image_mean_over_reference_mean_on_covered_pixels():
    cover, fill, refs = scene_images()
    images = {"direct": refs["direct"].copy(), "indirect": fill([0.1, 0.1, 0.1])}
    images["combined"] = images["direct"] + images["indirect"]
    out = evaluate_row(images, refs)
    assert out["mean_ratio.direct"] == pytest.approx(1.0)
    assert out["mean_ratio.indirect"] == pytest.approx(0.5)          # 0.1 / 0.2 unshadowed
    assert out["mean_ratio.indirect_visible"] == pytest.approx(1 / 3)  # 0.1 / 0.3 visible
    # the background does not dilute it: the same figure on a larger black frame
    big = {k: np.pad(v, ((0, 10), (0, 10), (0, 0))) for k, v in images.items()}
    big_refs = {k: np.pad(v, ((0, 10), (0, 10), (0, 0))) for k, v in refs.items()}
    assert evaluate_row(big, big_refs)["mean_ratio.indirect"] == pytest.approx(0.5)
    # a black reference gives no column, not a division error
    dark = dict(refs, indirect_unshadowed=np.zeros_like(refs["indirect_unshadowed"]))
    assert "mean_ratio.indirect" not in evaluate_row(images, dark)


def test_metric_memo_returns_the_same_columns_without_recomputing(tmp_path, monkeypatch):
    import bench.analysis.metrics
    from bench.analysis.evaluation import evaluate_row
    rng = np.random.default_rng(3)
    imgs = {c: rng.random((12, 16, 3), dtype=np.float32) for c in ("direct", "indirect", "combined")}
    refs = {c: rng.random((12, 16, 3), dtype=np.float32) for c in ("direct", "indirect_unshadowed", "indirect_visible")}
    fresh = evaluate_row(imgs, refs)
    first = evaluate_row(imgs, refs, memo_dir=tmp_path)
    assert first == pytest.approx(fresh, nan_ok=True)

    def boom(*a, **k):
        raise AssertionError("recomputed despite the memo")
    monkeypatch.setattr(bench.analysis.metrics, "compute_all", boom)
    assert evaluate_row(imgs, refs, memo_dir=tmp_path) == first
    # another image is another key: computed (here: the patched function raises)
    imgs2 = dict(imgs, indirect=imgs["indirect"] * 2)
    with pytest.raises(AssertionError, match="recomputed"):
        evaluate_row(imgs2, refs, memo_dir=tmp_path)
