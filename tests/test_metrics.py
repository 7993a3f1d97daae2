"""Error metrics: each against a hand-computed case, identity, mask, bad input, zero reference."""
import math

import numpy as np
import pytest

from bench.analysis import metrics as M


def srgb_encode(v):
    return 12.92 * v if v <= 0.0031308 else 1.055 * v ** (1 / 2.4) - 0.055


def lab_lightness(y):  # CIE L* of a neutral grey of luminance y (white = 1)
    return 116 * y ** (1 / 3) - 16 if y > (6 / 29) ** 3 else y * (29 / 3) ** 3


def grey(value, h=16, w=16):
    return np.full((h, w, 3), value, dtype=np.float64)


def random_pair(seed=3, h=24, w=32):
    rng = np.random.default_rng(seed)
    ref = (rng.random((h, w, 3)) ** 2 * 3).astype(np.float32)
    img = np.clip(ref * 1.3 + rng.normal(0, 0.1, ref.shape), 0, None).astype(np.float32)
    return img, ref


# ---------------------------------------------------------------------------- hand-computed cases
def test_per_pixel_metrics_hand_computed():
    ref = np.array([[[1.0, 1.0, 1.0], [2.0, 0.0, 2.0]]])
    img = np.array([[[2.0, 1.0, 1.0], [2.0, 0.5, 2.0]]])
    # errors per channel: 1, 0, 0 | 0, 0.5, 0
    assert M.mse(img, ref) == pytest.approx((1 + 0.25) / 6)
    # epsilons relative to the reference's level (issue #15): 0.01 * mean(r^2), 0.01 * mean|r|
    e_rel, e_smape = 0.01 * (1 + 1 + 1 + 4 + 0 + 4) / 6, 0.01 * (1 + 1 + 1 + 2 + 0 + 2) / 6
    assert M.relmse_epsilon(ref) == pytest.approx(e_rel) and M.smape_epsilon(ref) == pytest.approx(e_smape)
    assert M.relmse(img, ref) == pytest.approx((1 / (1 + e_rel) + 0.25 / (0 + e_rel)) / 6)
    assert M.smape(img, ref) == pytest.approx((1 / (3 + e_smape) + 0.5 / (0.5 + e_smape)) / 6)
    assert M.relmse(img, ref, eps=0.01) == pytest.approx((1 / (1 + 0.01) + 0.25 / (0 + 0.01)) / 6)
    assert "0.01 * mean(r^2)" in M.METRICS["relmse"] and "0.01 * mean|r|" in M.METRICS["smape"]


@pytest.mark.parametrize("scale", [0.002, 0.08, 37.0])
def test_relative_metrics_are_scale_invariant(scale):
    """The same relative error at the brightness of big_floor's indirect light (~0.002) or of a
    bright view gives the same relmse and smape (an absolute epsilon made relmse ~ MSE / 0.01)."""
    img, ref = (a.astype(np.float64) for a in random_pair())
    img[0, 0] = 0.0
    ref[1, 1] = 0.0  # black pixels in either image
    mask = np.ones(ref.shape[:2], bool)
    mask[:, :3] = False
    for fn in (M.relmse, M.smape):
        assert fn(img * scale, ref * scale, mask) == pytest.approx(fn(img, ref, mask), rel=1e-9), fn.__name__
    # an all-black reference falls back to the absolute epsilons: finite, not a division by zero
    zero = np.zeros_like(ref)
    assert np.isfinite(M.relmse(img, zero)) and np.isfinite(M.smape(img, zero))


def test_dssim_hand_computed_constant_images():
    # reference grey 0.5 -> P99 = 0.5 -> exposure 2 -> display 1.0; image 0.25 -> display 0.5.
    ref, img = grey(0.5), grey(0.25)
    a, b = srgb_encode(1.0), srgb_encode(0.5)
    c1 = (0.01 * 1.0) ** 2  # variances and covariance are 0: SSIM = (2ab + C1) / (a^2 + b^2 + C1)
    expected = 1 - (2 * a * b + c1) / (a * a + b * b + c1)
    assert M.tonemap_scale(ref) == pytest.approx(2.0)
    assert M.dssim(img, ref) == pytest.approx(expected, rel=1e-9)
    assert expected > 0.01  # the case is not trivial


def test_ciede2000_hand_computed_greys():
    ref = grey(0.5)
    # black against white: Delta L = 100 at mean L 50, where S_L = 1 -> DeltaE00 = 100
    assert M.ciede2000(grey(0.0), ref) == pytest.approx(100.0, abs=1e-3)
    # two neutral greys: DeltaE00 = |Delta L| / S_L, S_L = 1 + 0.015 (L-50)^2 / sqrt(20 + (L-50)^2)
    l1, l2 = lab_lightness(1.0), lab_lightness(0.5)
    lbar = (l1 + l2) / 2
    s_l = 1 + 0.015 * (lbar - 50) ** 2 / math.sqrt(20 + (lbar - 50) ** 2)
    assert M.ciede2000(grey(0.25), ref) == pytest.approx(abs(l1 - l2) / s_l, rel=1e-4)
    # clipping above display white: 2x the reference is still white after tone mapping
    assert M.ciede2000(grey(1.0), ref) == pytest.approx(0.0, abs=1e-9)


def test_flip_weighted_median_hand_computed():
    # total 1.0; cumulative 0.1, 0.3, 0.6: the first value whose running sum exceeds 0.5 is 0.3
    assert M.weighted_median(np.array([0.4, 0.1, 0.3, 0.2])) == pytest.approx(0.3)
    assert M.weighted_median(np.array([0.0, 0.0, 0.9])) == pytest.approx(0.9)
    assert M.weighted_median(np.zeros(5)) == 0.0


def test_flip_exposure_range_is_flips_own_rule():
    import flip_evaluator
    # FLIP's anchor: the ACES curve (FLIP's coefficients) maps x_max to 0.85
    x = M._flip_x_max()
    a, b, c, d, e, f = 0.6 * 0.6 * 2.51, 0.6 * 0.03, 0.0, 0.6 * 0.6 * 2.43, 0.6 * 0.59, 0.14
    assert (a * x * x + b * x + c) / (d * x * x + e * x + f) == pytest.approx(0.85, rel=1e-9)
    # a fully lit reference with an odd pixel count: our range equals FLIP's automatic one
    rng = np.random.default_rng(5)
    ref = (rng.random((9, 11, 3)) * 2 + 0.01).astype(np.float32)
    start, stop = M.flip_exposure_range(ref)
    _, _, used = flip_evaluator.evaluate(ref, ref, "HDR", applyMagma=False)
    assert start == pytest.approx(used["startExposure"], abs=1e-4)
    assert stop == pytest.approx(used["stopExposure"], abs=1e-4)
    # closed form on a reference of two luminances: Y_max = 4, median of positive pixels = 1
    two = np.zeros((3, 3, 3))
    two[0, 0] = 4.0
    two[0, 1] = two[0, 2] = 1.0
    start, stop = M.flip_exposure_range(two)
    assert start == pytest.approx(math.log2(x / 4.0)) and stop == pytest.approx(math.log2(x / 1.0))


def test_flip_matches_flip_evaluator_on_a_fully_lit_image():
    import flip_evaluator
    rng = np.random.default_rng(8)
    ref = (rng.random((25, 31, 3)) * 2 + 0.05).astype(np.float32)
    img = np.clip(ref * 1.2 + rng.normal(0, 0.1, ref.shape), 0, None).astype(np.float32)
    _, their_mean, _ = flip_evaluator.evaluate(ref, img, "HDR", applyMagma=False)
    assert M.flip(img, ref)[0] == pytest.approx(their_mean, rel=1e-4)


def test_flip_values_and_shared_exposure():
    img, ref = random_pair()
    mask = np.ones(ref.shape[:2], bool)
    exposure = M.flip_exposure_range(ref, mask)
    err = M.flip_error_map(img, ref, mask, exposure)
    assert err.shape == mask.shape and 0 <= err.min() and err.max() <= 1
    f_mean, f_median = M.flip(img, ref, mask, exposure)
    assert f_mean == pytest.approx(err.mean()) and f_median == pytest.approx(M.weighted_median(err))
    assert f_mean > 0.01
    # the exposure range matters: a narrower one (not the reference's) gives another value
    other, _ = M.flip(img, ref, mask, (exposure[0] + 2, exposure[0] + 2.5))
    assert other != pytest.approx(f_mean)


# ---------------------------------------------------------------------------- identity, mask, bad input
def test_identity_is_zero_for_every_metric():
    _, ref = random_pair()
    values = M.compute_all(ref, ref.copy(), np.ones(ref.shape[:2], bool))
    assert list(values) == list(M.METRICS)
    for name, v in values.items():
        assert v == pytest.approx(0.0, abs=1e-12), name


def test_every_metric_worsens_with_error():
    img, ref = random_pair()
    mask = np.ones(ref.shape[:2], bool)
    small = M.compute_all(0.8 * ref + 0.2 * img, ref, mask)
    large = M.compute_all(img, ref, mask)
    for name in M.METRICS:
        assert 0 < small[name] < large[name], name


def test_mask_is_respected():
    img, ref = random_pair(h=32, w=32)
    mask = np.zeros(ref.shape[:2], bool)
    mask[4:20, 6:26] = True
    base = M.compute_all(img, ref, mask)
    # anything outside the mask, in either image, changes nothing (spatial metrics included)
    img2, ref2 = img.copy(), ref.copy()
    img2[~mask] = 50.0
    ref2[~mask] = 0.0
    assert M.compute_all(img2, ref2, mask) == pytest.approx(base, rel=1e-9, abs=1e-12)
    # per-pixel metrics are the plain means over the covered pixels
    assert base["mse"] == pytest.approx(np.mean((img[mask].astype(float) - ref[mask]) ** 2))
    # a non-boolean mask works the same
    assert M.mse(img, ref, mask.astype(np.uint8)) == base["mse"]


def test_empty_mask_gives_nan():
    img, ref = random_pair()
    values = M.compute_all(img, ref, np.zeros(ref.shape[:2], bool))
    assert all(math.isnan(v) for v in values.values())


def test_all_zero_reference_is_nan_free():
    img, _ = random_pair()
    zero = np.zeros_like(img)
    mask = np.ones(img.shape[:2], bool)
    start, stop = M.flip_exposure_range(zero, mask)
    assert math.isfinite(start) and start < stop
    assert start == pytest.approx(math.log2(M._flip_x_max()))  # behaves as a unit-luminance reference
    values = M.compute_all(img, zero, mask, flip_exposure=(start, stop))
    assert all(math.isfinite(v) and v > 0 for v in values.values()), values
    assert M.compute_all(zero, zero, mask) == pytest.approx({k: 0.0 for k in M.METRICS})


@pytest.mark.parametrize("which", ["image", "reference"])
def test_nan_input_is_rejected(which):
    img, ref = random_pair()
    bad = (img if which == "image" else ref).copy()
    bad[3, 4, 1] = np.nan
    bad[5, 5, 0] = np.inf
    args = (bad, ref) if which == "image" else (img, bad)
    for fn in (M.mse, M.relmse, M.smape, M.dssim, M.ciede2000, M.flip, M.compute_all):
        with pytest.raises(ValueError, match=f"^{which} has 2 pixel"):
            fn(*args)


def test_bad_shapes_and_parameters_are_rejected():
    img, ref = random_pair()
    with pytest.raises(ValueError, match="image has shape"):
        M.mse(img[:, :-1], ref)
    with pytest.raises(ValueError, match="HxWx3"):
        M.mse(img[..., 0], ref)
    with pytest.raises(ValueError, match="mask has shape"):
        M.mse(img, ref, np.ones((3, 3), bool))
    with pytest.raises(ValueError, match="start < stop"):
        M.flip(img, ref, None, (1.0, 1.0))  # FLIP itself would abort the process here
    with pytest.raises(ValueError, match="pair"):
        M.flip(img, ref, None, 3.0)
    with pytest.raises(ValueError, match="at least 7x7"):
        M.dssim(np.ones((4, 4, 3)), np.ones((4, 4, 3)))
    with pytest.raises(ValueError, match="tonemap scale"):
        M.compute_all(img, ref, None, tonemap_scale_value=0.0)


def test_deterministic():
    img, ref = random_pair()
    assert M.compute_all(img, ref) == M.compute_all(img.copy(), ref.copy())
