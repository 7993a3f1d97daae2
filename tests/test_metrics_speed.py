"""The fast metric paths (issue #29) give exactly the values of the straightforward ones.

`reference_compute_all` below is the metric code as it was before the speed-up (each metric on
its own: inputs checked per metric, colour's dispatchers, HDR-FLIP on the whole image); the
current code must return the same floats, bit for bit (`==`, NaN equal to NaN), on rows built to
reach every shortcut: FLIP's crop (a background band, images equal to their reference in large
regions, differing pixels at the image's edges and corners), an image equal to its reference,
an all-zero reference, a mask with holes, images smaller than FLIP's filters.

No timing here (speed targets live in benchmarks). To measure the cost of one row at 320x180
(a view's first row and the next ones, and per phase):

    PYTHONPATH=. python -m tests.test_metrics_speed [repetitions]
"""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from bench.analysis import metrics as M
from bench.analysis.evaluation import COMPARISONS, coverage_mask, evaluate_row


# ---------------------------------------------------------------------------- the straightforward path
def _reference_metrics(image, reference, mask, exposure, scale) -> dict:
    import colour
    import flip_evaluator
    from skimage.metrics import structural_similarity
    img, ref, m = M._inputs(image, reference, mask)
    if not m.any():
        return {name: math.nan for name in M.METRICS}
    x, r = img[m], ref[m]
    level2, level1 = float(np.mean(r ** 2)), float(np.mean(np.abs(r)))
    e_rel = M.EPS_RELMSE * level2 if level2 > 0 else M.EPS_RELMSE
    e_smape = M.EPS_SMAPE * level1 if level1 > 0 else M.EPS_SMAPE
    out = {"mse": float(np.mean((x - r) ** 2)),
           "relmse": float(np.mean((x - r) ** 2 / (r * r + e_rel))),
           "smape": float(np.mean(np.abs(x - r) / (np.abs(x) + np.abs(r) + e_smape)))}
    img_b, ref_b = np.where(m[..., None], img, 0.0), np.where(m[..., None], ref, 0.0)

    def luma(a):
        linear = np.clip(a * scale, 0.0, 1.0) @ M.LUMA
        return np.asarray(colour.cctf_encoding(linear, function="sRGB"), dtype=np.float64)
    _, ssim_map = structural_similarity(luma(ref_b), luma(img_b), win_size=M.SSIM_WINDOW, data_range=1.0, full=True)
    out["dssim"] = float(1.0 - np.mean(ssim_map[m]))

    start, stop = exposure
    params = {"ppd": M.FLIP_PPD, "startExposure": start, "stopExposure": stop,
              "numExposures": max(2, math.ceil(stop - start)), "tonemapper": "aces"}
    err, _, _ = flip_evaluator.evaluate(np.ascontiguousarray(np.clip(ref_b, 0.0, None), dtype=np.float32),
                                        np.ascontiguousarray(np.clip(img_b, 0.0, None), dtype=np.float32),
                                        "HDR", applyMagma=False, computeMeanError=False, parameters=params)
    err = np.asarray(err, dtype=np.float64).reshape(m.shape)[m]
    out["flip_mean"], out["flip_median"] = float(err.mean()), M.weighted_median(err)

    def lab(a):
        srgb = colour.RGB_COLOURSPACES["sRGB"]
        xyz = colour.RGB_to_XYZ(np.clip(a * scale, 0.0, 1.0), srgb, apply_cctf_decoding=False)
        return colour.XYZ_to_Lab(xyz, srgb.whitepoint)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out["ciede2000"] = float(np.mean(colour.delta_E(lab(r), lab(x), method="CIE 2000")))
    return {name: out[name] for name in M.METRICS}


def reference_compute_all(image, reference, mask=None, flip_exposure=None, tonemap_scale_value=None) -> dict:
    img, ref, m = M._inputs(image, reference, mask)
    exposure = M.flip_exposure_range(ref, m) if flip_exposure is None else flip_exposure
    scale = M.tonemap_scale(ref, m) if tonemap_scale_value is None else tonemap_scale_value
    return _reference_metrics(img, ref, m, exposure, scale)


def reference_row(images: dict, refs: dict) -> dict:
    mask = coverage_mask(images, refs)
    out = {}
    for column, (image_name, parts) in COMPARISONS.items():
        if any(refs.get(p) is None for p in parts):
            continue
        reference = sum(refs[p] for p in parts)
        scores = reference_compute_all(images[image_name], reference, mask)
        out.update({f"{name}.{column}": float(v) for name, v in scores.items()})
    return out


def same(a: dict, b: dict) -> bool:
    """Equal keys and bit-equal floats (NaN equal to NaN)."""
    return a.keys() == b.keys() and all(a[k] == b[k] or (math.isnan(a[k]) and math.isnan(b[k])) for k in a)


def differences(a: dict, b: dict) -> dict:
    return {k: (a.get(k), b.get(k)) for k in a.keys() | b.keys() if not same({k: a.get(k, 0.0)}, {k: b.get(k, 0.0)})}


# ---------------------------------------------------------------------------- rows
def synthetic_row(h=180, w=320, seed=0):
    """A row's images and references: smooth gradients, noise, a few bright spots, a shadow edge in
    the visible indirect light, ~10% background (a band at the top), a method that lights a few
    background pixels."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    u, v = x / w, y / h
    base = np.stack([0.2 + 0.8 * u, 0.3 + 0.5 * v, 0.5 + 0.3 * np.sin(6 * u + 3 * v)], axis=2)
    cover = np.ones((h, w), bool)
    cover[: h // 10, :] = False
    spots = np.zeros((h, w))
    for _ in range(6):
        cy, cx = rng.integers(0, h), rng.integers(0, w)
        spots += 40.0 * np.exp(-((y - cy) ** 2 + (x - cx) ** 2) / 8.0)
    direct = base * (0.6 + 0.4 * (np.sin(20 * u) > 0))[..., None] + spots[..., None]
    unshadowed = 0.15 * base * (1 + 0.5 * np.cos(4 * v))[..., None]
    visible = unshadowed * (0.5 + 0.5 * (u > 0.4))[..., None]
    refs = {}
    for name, r in (("direct", direct), ("indirect_unshadowed", unshadowed), ("indirect_visible", visible)):
        r = np.clip(r * (1 + rng.normal(0, 0.05, r.shape)), 0, None)
        r[~cover] = 0
        refs[name] = r.astype(np.float32)
    d = np.clip(refs["direct"] * (1 + rng.normal(0, 0.1, direct.shape)), 0, None)
    i = np.clip(0.9 * unshadowed + rng.normal(0, 0.02, direct.shape), 0, None)
    d[~cover] = 0
    i[~cover] = 0
    i[0, :5] = 0.3
    images = {"direct": d.astype(np.float32), "indirect": i.astype(np.float32)}
    images["combined"] = images["direct"] + images["indirect"]
    return images, refs


def _rows():
    yield "plain", synthetic_row(36, 52, seed=1)
    images, refs = synthetic_row(36, 52, seed=2)
    yield "direct equals its reference", (dict(images, direct=refs["direct"].copy(),
                                                combined=refs["direct"] + images["indirect"]), refs)
    images, refs = synthetic_row(36, 52, seed=3)
    zero = np.zeros_like(refs["direct"])
    yield "all-zero indirect reference", (images, dict(refs, indirect_unshadowed=zero, indirect_visible=zero.copy()))
    images, refs = synthetic_row(40, 60, seed=4)
    for a in (*images.values(), *refs.values()):
        a[:, :18] = 0.0   # a wide background band on the left and at the bottom
        a[-12:, :] = 0.0
    images["combined"] = images["direct"] + images["indirect"]
    yield "background on two sides", (images, refs)
    images, refs = synthetic_row(40, 60, seed=5)
    images = {k: refs["direct"].copy() if k == "direct" else v for k, v in images.items()}
    images["direct"][0, 0] += 0.5      # the direct image differs from its reference at two corners only
    images["direct"][-1, 30] += 0.5
    images["combined"] = images["direct"] + images["indirect"]
    yield "differences at the edges", (images, refs)
    yield "smaller than FLIP's filters", synthetic_row(9, 13, seed=6)


@pytest.mark.parametrize("name,row", list(_rows()), ids=[n for n, _ in _rows()])
def test_evaluate_row_equals_the_straightforward_path(name, row):
    images, refs = row
    fast, slow = evaluate_row(images, refs), reference_row(images, refs)
    fast = {k: v for k, v in fast.items() if not k.startswith("mean_ratio.")}
    assert same(fast, slow), differences(fast, slow)


def _pairs():
    rng = np.random.default_rng(11)
    h, w = 34, 47
    ref = (rng.random((h, w, 3)) ** 2 * 3).astype(np.float32)
    img = np.clip(ref * 1.2 + rng.normal(0, 0.1, ref.shape), 0, None).astype(np.float32)
    holes = rng.random((h, w)) > 0.3                      # a mask with holes everywhere
    yield "holes", img, ref, holes
    box = np.zeros((h, w), bool)
    box[5:20, 9:30] = True                                 # covered pixels away from every edge
    yield "inner box", img, ref, box
    near = ref.copy()
    near[17, 23] += 1.0                                   # one differing pixel, in the middle
    yield "one pixel", near, ref, None
    edge = ref.copy()
    edge[h - 1, w - 1] += 1.0
    edge[0, 3] -= 0.5
    yield "corner and edge", edge, ref, box | (rng.random((h, w)) > 0.9)
    yield "identical", ref.copy(), ref, holes
    strip = np.zeros((h, w), bool)
    strip[:, 40:] = True                                   # a strip at the right edge
    yield "edge strip", img, ref, strip
    yield "negative radiance", img - 0.2, ref, None


@pytest.mark.parametrize("name,img,ref,mask", list(_pairs()), ids=[p[0] for p in _pairs()])
def test_metric_functions_equal_the_straightforward_path(name, img, ref, mask):
    slow = reference_compute_all(img, ref, mask)
    assert same(M.compute_all(img, ref, mask), slow), differences(M.compute_all(img, ref, mask), slow)
    one_by_one = {"mse": M.mse(img, ref, mask), "relmse": M.relmse(img, ref, mask), "smape": M.smape(img, ref, mask),
                  "dssim": M.dssim(img, ref, mask), "ciede2000": M.ciede2000(img, ref, mask)}
    one_by_one["flip_mean"], one_by_one["flip_median"] = M.flip(img, ref, mask)
    assert same({k: one_by_one[k] for k in M.METRICS}, slow)
    # FLIP's crop: its values at the covered pixels are those of the whole image's map, bit for bit
    m = np.ones(ref.shape[:2], bool) if mask is None else mask
    exposure = M.flip_exposure_range(ref, m)
    full = M.flip_error_map(img, ref, m, exposure)[m]
    cropped = M._flip_covered(np.where(m[..., None], img.astype(np.float64), 0.0),
                              np.where(m[..., None], ref.astype(np.float64), 0.0), m, *exposure)
    assert np.array_equal(full, cropped)
    # the reference's half on the whole image, the image's on the crop (what evaluate_row's cache reuses)
    prepared = M.PreparedReference(ref, m)
    halves = M._flip_covered(np.where(m[..., None], img.astype(np.float64), 0.0), prepared.ref_b, m, *exposure,
                             reference_features=prepared.flip_features)
    assert np.array_equal(full, halves)
    assert same(M.compute_all(img, ref, mask, prepared=prepared), slow)


def test_rows_of_a_view_reuse_its_references_and_keep_their_values():
    """evaluate_row keeps each reference's side (PreparedReference) for the next rows of the view:
    the second method's row is judged against the kept ones and still equals the straightforward path."""
    from bench.analysis import evaluation
    images, refs = synthetic_row(40, 60, seed=7)
    other = {k: (v * 1.3).astype(np.float32) for k, v in images.items()}   # another method, the same mask
    evaluation._PREPARED.clear()
    for row in (images, other, images):
        fast = {k: v for k, v in evaluate_row(row, refs).items() if not k.startswith("mean_ratio.")}
        slow = reference_row(row, refs)
        assert same(fast, slow), differences(fast, slow)
    assert len(evaluation._PREPARED) == len(COMPARISONS)      # one per reference of the view, reused
    mask = coverage_mask(images, refs)
    kept = evaluation.prepared_reference(refs["direct"], mask)
    assert evaluation.prepared_reference(refs["direct"].copy(), mask.copy()) is kept   # by content
    assert evaluation.prepared_reference(refs["direct"], ~mask) is not kept


def test_kept_references_are_bounded_in_bytes(monkeypatch):
    from bench.analysis import evaluation
    monkeypatch.setattr(evaluation, "PREPARED_CACHE_BYTES", 1)
    evaluation._PREPARED.clear()
    images, refs = synthetic_row(20, 30, seed=8)
    evaluate_row(images, refs)
    assert len(evaluation._PREPARED) == 0


def reference_decomposition(mean, var, flicker, reference, ref_variance, mask, frames) -> dict:
    """The error-frame decomposition as it was written before the speed-up: every array converted
    and selected with the mask on its own, numpy's mean over channels, relmse's epsilon recomputed."""
    from bench.analysis.evaluation import Z95
    from bench.protocol.vocabulary import DECOMPOSITION_METRICS
    m = np.asarray(mask, bool)
    Mn, V, D, R, S = (np.asarray(a, np.float64)[m] for a in (mean, var, flicker, reference, ref_variance))
    err2 = (Mn - R) ** 2
    per_channel = {"mse_accumulated": err2 - S, "variance": V, "bias2": err2 - V / frames - S, "flicker": D / 2}
    if m.any():
        weight = 1.0 / (R * R + M.relmse_epsilon(np.asarray(reference), m))
        per_channel.update({f"rel_{name}": q * weight for name, q in list(per_channel.items())})
    out = {}
    for metric in DECOMPOSITION_METRICS:
        per_pixel = per_channel[metric].mean(axis=1) if metric in per_channel else np.empty(0)
        n = per_pixel.size
        out[metric] = (float(per_pixel.mean()) if n else float("nan"),
                       float(Z95 * per_pixel.std(ddof=1) / np.sqrt(n)) if n > 1 else float("nan"))
    return out


@pytest.mark.parametrize("h,w,coverage", [(180, 320, 0.9), (33, 47, 0.5), (5, 6, 0.3), (8, 8, 0.0)])
def test_decomposition_equals_the_straightforward_path(h, w, coverage):
    """The error frames' bias/variance/flicker columns (each image's covered pixels selected once per
    row, channels summed in numpy's order) equal the plain formulas bit for bit, in evaluate_row too."""
    from bench.analysis.evaluation import decomposition
    from bench.protocol.vocabulary import FRAME_STAT_IMAGES, frame_stat_image, metric_column, interval_column
    rng = np.random.default_rng(h * w)
    arrays = [(rng.standard_normal((h, w, 3)) * rng.random()).astype(np.float32) for _ in range(5)]
    mask = rng.random((h, w)) < coverage
    fast, slow = decomposition(*arrays, mask, 8), reference_decomposition(*arrays, mask, 8)
    assert fast.keys() == slow.keys()
    for metric, (value, ci) in slow.items():
        assert same({"v": fast[metric][0], "ci": fast[metric][1]}, {"v": value, "ci": ci}), metric
    if coverage == 0.0 or min(h, w) < 7:
        return
    images, refs = synthetic_row(h, w, seed=3)
    stats = {n: (rng.random((h, w, 3)) * 0.1).astype(np.float32) for n in FRAME_STAT_IMAGES}
    variances = {c: (rng.random((h, w, 3)) * 1e-3).astype(np.float32) for c in refs}
    row = evaluate_row(images, refs, ref_variances=variances, frame_stats=stats, error_frames=6)
    row_mask = coverage_mask(images, refs)
    for column in ("indirect", "indirect_visible", "combined"):
        image_name, parts = COMPARISONS[column]
        reference = np.asarray(sum(refs[p] for p in parts), np.float32)
        variance = np.asarray(sum(variances[p] for p in parts), np.float32)
        plain = reference_decomposition(*(stats[frame_stat_image(image_name, s)] for s in ("mean", "var", "flicker")),
                                        reference, variance, row_mask, 6)
        for metric, (value, ci) in plain.items():
            got = {"v": row[metric_column(metric, column)], "ci": row[interval_column(metric, column)]}
            assert same(got, {"v": value, "ci": ci}), (column, metric)


def test_flip_reach_covers_flips_filters():
    # FLIP's spatial filter radius at 67 ppd is 10 pixels (its widest Gaussian), the feature filter's 9
    assert M.FLIP_REACH >= 10
    assert M._flip_reach(M.FLIP_PPD / 2) < M.FLIP_REACH


# ---------------------------------------------------------------------------- measurement (not a test)
def main(repetitions: int = 5) -> None:
    """Cost of one row at 320x180 (all four comparisons, no memo): CPU and wall, median of
    `repetitions`; a view's first row (its references prepared: `cold`) and the next ones (`warm`),
    then per phase on the `combined` comparison."""
    import statistics
    import time
    from bench.analysis import evaluation, flip_native
    images, refs = synthetic_row()
    evaluate_row(images, refs)   # imports, first calls, the compiled FLIP loaded (or built)

    def timed(fn, before=lambda: None):
        cpu, wall = [], []
        for _ in range(repetitions):
            before()
            c, t = time.process_time(), time.perf_counter()
            fn()
            cpu.append(time.process_time() - c)
            wall.append(time.perf_counter() - t)
        return statistics.median(cpu), statistics.median(wall)
    backend = "compiled FLIP.h" if flip_native.library() is not None else "flip-evaluator wheel"
    print(f"HDR-FLIP: {backend}")
    for name, before in (("cold", evaluation._PREPARED.clear), ("warm", lambda: None)):
        cpu, wall = timed(lambda: evaluate_row(images, refs), before)
        print(f"evaluate_row 320x180 {name}: cpu {cpu:.3f} s, wall {wall:.3f} s (median of {repetitions})")
    mask = coverage_mask(images, refs)
    img, ref = images["combined"], refs["direct"] + refs["indirect_visible"]
    prepared = M.PreparedReference(ref, mask)
    prepared.flip_features()
    img64 = img.astype(np.float64)
    x, img_b = img64[mask], np.where(mask[..., None], img64, 0.0)
    print(f"  combined ({M._flip_exposures(*prepared.exposure)} FLIP exposures), per phase:")
    for name, fn in (("reference prepared", lambda: M.PreparedReference(ref, mask).flip_features()),
                     ("image checks", lambda: M._checked_image(img, prepared)),
                     ("mse+relmse+smape", lambda: (M._mse(x, prepared.r), M._relmse(x, prepared.r, prepared.relmse_eps),
                                                   M._smape(x, prepared.r, prepared.smape_eps))),
                     ("dssim", lambda: M._dssim_of_luma(M._display_luma(img_b, prepared.scale), prepared.ssim, mask)),
                     ("ciede2000", lambda: M._ciede2000_of_lab(M._display_lab(x, prepared.scale), prepared.lab)),
                     ("flip", lambda: M.flip_covered_errors(img, prepared)),
                     ("compute_all", lambda: M.compute_all(img, ref, mask, prepared=prepared))):
        cpu, wall = timed(fn)
        print(f"    {name:20s} cpu {1000 * cpu:7.1f} ms  wall {1000 * wall:7.1f} ms")


if __name__ == "__main__":
    import sys
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 5)
