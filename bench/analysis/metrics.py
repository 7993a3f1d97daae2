"""Error metrics of a method's image against a reference: pure functions on linear-radiance arrays.

Every metric is "lower is better", is computed over the covered pixels only (`mask`, HxW bool:
background pixels are excluded), and takes HxWx3 linear RGB radiance (any float dtype; it is
promoted to float64, except FLIP which runs in float32). Non-finite input is rejected with a
ValueError naming the argument; a mask that covers no pixel gives NaN (nothing to judge).

Two display transforms are shared by every method judged against one reference, so methods on
a view are compared on one scale (both depend on the reference alone, never on the image):
  * `tonemap_scale(reference, mask)`: the exposure s = 1 / P99, P99 the 99th percentile of the
    per-pixel maximum RGB channel of the reference over covered pixels where it is > 0 (s = 1 if
    there is none). Tone-mapped = clip(s * x, 0, 1). Used by `dssim` and `ciede2000`.
  * `flip_exposure_range(reference, mask)`: HDR-FLIP's own automatic exposure rule,
    start = log2(x_max / Y_max), stop = log2(x_max / Y_median), computed over covered pixels
    whose reference luminance is > 0 (an indirect-only reference can have a zero median over
    all covered pixels); an all-zero reference uses Y_max = Y_median = 1.
`relmse` and `smape` are scale-invariant: their epsilon is relative to the reference's own
level over the covered pixels (mean r^2 for relmse, mean |r| for smape), so scaling image and
reference by the same brightness factor leaves them unchanged and scenes whose indirect radiance
is 0.002 or 0.08 are judged alike. (An absolute epsilon of 0.01 radiance units made relMSE
MSE / 0.01 for indirect light.) An all-zero reference falls back to the absolute epsilons.
Spatial metrics (dssim, FLIP) see every pixel outside the mask as black in both images (what
background is), so nothing outside the mask leaks into their windows.

Cost: HDR-FLIP is most of it (flip-evaluator runs max(2, ceil(stop - start)) LDR-FLIP passes,
~0.1 s each per core at 320x180). `compute_all` checks its inputs once and shares them across
the metrics, and FLIP's map is computed only on the box where it can be non-zero
(`_flip_covered`); both give exactly the values of the metric functions one by one.
"""
from __future__ import annotations

import math
import warnings

import numpy as np

EPS_RELMSE = 0.01          # relative MSE: (x - r)^2 / (r^2 + EPS_RELMSE * mean(r^2)) (Rousselle/Zwicker's 0.01, in units of the reference's level)
EPS_SMAPE = 0.01           # SMAPE: |x - r| / (|x| + |r| + EPS_SMAPE * mean|r|) (Vogels et al. 2018's 0.01, same)
TONEMAP_PERCENTILE = 99.0  # reference percentile (of max RGB channel) mapped to display white
SSIM_WINDOW = 7            # skimage's default uniform window, K1 = 0.01, K2 = 0.03
FLIP_TONEMAPPER = "aces"   # HDR-FLIP's default tone mapper
FLIP_PPD = 0.7 * (3840 / 0.7) * math.pi / 180  # FLIP's default, 67.02 pixels per degree (0.7 m from a 0.7 m wide 4K screen)
LUMA = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709 / sRGB luminance weights (as FLIP uses)

METRICS = {
    "mse": "mean over covered pixels and RGB channels of (x - r)^2, linear radiance",
    "relmse": (f"mean over covered pixels and RGB channels of (x - r)^2 / (r^2 + {EPS_RELMSE} * mean(r^2)), "
               "mean(r^2) over the reference's covered pixels and channels (scale-invariant)"),
    "smape": (f"mean over covered pixels and RGB channels of |x - r| / (|x| + |r| + {EPS_SMAPE} * mean|r|), "
              "mean|r| over the reference's covered pixels and channels, in [0, 1) (scale-invariant)"),
    "dssim": (f"1 - mean over covered pixels of the SSIM map (scikit-image, {SSIM_WINDOW}x{SSIM_WINDOW} uniform "
              "window, K1=0.01, K2=0.03, data_range=1) of the sRGB-encoded luminance of the tone-mapped images "
              f"(clip(x / P{TONEMAP_PERCENTILE:g}(reference max channel), 0, 1))"),
    "flip_mean": ("mean over covered pixels of the HDR-FLIP error map (flip-evaluator, ACES, 67 ppd), exposure "
                  "range from the reference's covered pixels of positive luminance, shared by all methods (all-zero "
                  "reference: as if of unit luminance)"),
    "flip_median": ("error-weighted median of the HDR-FLIP map over covered pixels (FLIP's 'weighted median'): "
                    "the smallest error e such that errors <= e hold more than half of the total error"),
    "ciede2000": ("mean over covered pixels of CIEDE2000 (colour-science) between the tone-mapped images "
                  f"(clip(x / P{TONEMAP_PERCENTILE:g}(reference max channel), 0, 1), linear sRGB -> XYZ -> "
                  "CIE Lab, D65)"),
}


# ---------------------------------------------------------------------------- input checks
def _as_rgb(arr, what: str) -> np.ndarray:
    a = np.asarray(arr)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"{what} must be an HxWx3 RGB array, got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.number):
        raise ValueError(f"{what} must be numeric, got dtype {a.dtype}")
    a = a.astype(np.float64, copy=False)
    bad = ~np.isfinite(a)
    if bad.any():
        raise ValueError(f"{what} has {int(bad.any(axis=2).sum())} pixel(s) with NaN or infinite values")
    return a


def _as_mask(mask, shape, what: str = "mask") -> np.ndarray:
    if mask is None:
        return np.ones(shape[:2], dtype=bool)
    m = np.asarray(mask)
    if m.shape != tuple(shape[:2]):
        raise ValueError(f"{what} has shape {m.shape}, expected {tuple(shape[:2])} (the image's HxW)")
    if m.dtype != bool:
        if not np.all(np.isfinite(m)):
            raise ValueError(f"{what} has NaN or infinite values")
        m = m != 0
    return m


def _inputs(image, reference, mask):
    ref = _as_rgb(reference, "reference")
    img = _as_rgb(image, "image")
    if img.shape != ref.shape:
        raise ValueError(f"image has shape {img.shape} but reference has shape {ref.shape}")
    return img, ref, _as_mask(mask, ref.shape)


def _black_outside(x: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Uncovered pixels as black background, for metrics whose windows straddle the mask edge."""
    return np.where(mask[..., None], x, 0.0)


# ---------------------------------------------------------------------------- per-pixel metrics
# The kernels (_mse, ...) take the covered pixels (x = image[mask], r = reference[mask], float64
# Nx3): compute_all selects them once for every per-pixel metric and CIEDE2000.
def _mse(x: np.ndarray, r: np.ndarray) -> float:
    return float(np.mean((x - r) ** 2))


def _relmse_epsilon(r: np.ndarray) -> float:
    level = float(np.mean(r ** 2)) if r.size else 0.0
    return EPS_RELMSE * level if level > 0 else EPS_RELMSE


def _smape_epsilon(r: np.ndarray) -> float:
    level = float(np.mean(np.abs(r))) if r.size else 0.0
    return EPS_SMAPE * level if level > 0 else EPS_SMAPE


def _relmse(x: np.ndarray, r: np.ndarray, e: float) -> float:
    return float(np.mean((x - r) ** 2 / (r * r + e)))


def _smape(x: np.ndarray, r: np.ndarray, e: float) -> float:
    return float(np.mean(np.abs(x - r) / (np.abs(x) + np.abs(r) + e)))


def mse(image, reference, mask=None) -> float:
    img, ref, m = _inputs(image, reference, mask)
    if not m.any():
        return math.nan
    return _mse(img[m], ref[m])


def relmse_epsilon(reference, mask=None) -> float:
    """EPS_RELMSE * mean(r^2) over the covered pixels (EPS_RELMSE itself for an all-zero reference)."""
    ref = _as_rgb(reference, "reference")
    return _relmse_epsilon(ref[_as_mask(mask, ref.shape)])


def smape_epsilon(reference, mask=None) -> float:
    """EPS_SMAPE * mean|r| over the covered pixels (EPS_SMAPE itself for an all-zero reference)."""
    ref = _as_rgb(reference, "reference")
    return _smape_epsilon(ref[_as_mask(mask, ref.shape)])


def relmse(image, reference, mask=None, eps: float | None = None) -> float:
    """Relative MSE; `eps` (absolute, radiance^2) defaults to `relmse_epsilon(reference, mask)`."""
    img, ref, m = _inputs(image, reference, mask)
    if not m.any():
        return math.nan
    x, r = img[m], ref[m]
    return _relmse(x, r, _relmse_epsilon(r) if eps is None else float(eps))


def smape(image, reference, mask=None, eps: float | None = None) -> float:
    """Symmetric MAPE; `eps` (absolute, radiance) defaults to `smape_epsilon(reference, mask)`."""
    img, ref, m = _inputs(image, reference, mask)
    if not m.any():
        return math.nan
    x, r = img[m], ref[m]
    return _smape(x, r, _smape_epsilon(r) if eps is None else float(eps))


# ---------------------------------------------------------------------------- display transforms
def tonemap_scale(reference, mask=None) -> float:
    """Exposure s mapping the reference's P99 (max RGB channel, covered pixels > 0) to 1."""
    ref = _as_rgb(reference, "reference")
    m = _as_mask(mask, ref.shape)
    peak = ref.max(axis=2)
    lit = peak[m & (peak > 0)]
    if lit.size == 0:
        return 1.0
    p = float(np.percentile(lit, TONEMAP_PERCENTILE))
    return 1.0 / p if p > 0 else 1.0


def tonemap(x: np.ndarray, scale: float) -> np.ndarray:
    """Linear radiance -> linear display RGB in [0, 1] (exposure `scale`, then clamp)."""
    return np.clip(np.asarray(x, dtype=np.float64) * scale, 0.0, 1.0)


def _check_scale(scale) -> float:
    s = float(scale)
    if not (math.isfinite(s) and s > 0):
        raise ValueError(f"tonemap scale must be a positive finite number, got {scale!r}")
    return s


def _srgb_encode(linear: np.ndarray) -> np.ndarray:
    import colour
    # the function colour.cctf_encoding(linear, function="sRGB") dispatches to, without the dispatch
    return np.asarray(colour.CCTF_ENCODINGS["sRGB"](linear), dtype=np.float64)


def _dssim(img_b: np.ndarray, ref_b: np.ndarray, m: np.ndarray, s: float) -> float:
    """dssim of images already black outside the (non-empty) mask `m`, at exposure `s`."""
    from skimage.metrics import structural_similarity
    h, w = m.shape
    if min(h, w) < SSIM_WINDOW:
        raise ValueError(f"dssim needs images of at least {SSIM_WINDOW}x{SSIM_WINDOW} pixels, got {w}x{h}")
    y_img = _srgb_encode(tonemap(img_b, s) @ LUMA)
    y_ref = _srgb_encode(tonemap(ref_b, s) @ LUMA)
    _, ssim_map = structural_similarity(y_ref, y_img, win_size=SSIM_WINDOW, data_range=1.0, full=True)
    return float(1.0 - np.mean(ssim_map[m]))


def dssim(image, reference, mask=None, scale: float | None = None) -> float:
    """1 - SSIM of sRGB-encoded luminance of the tone-mapped images, averaged over the mask."""
    img, ref, m = _inputs(image, reference, mask)
    if not m.any():
        return math.nan
    h, w = m.shape
    if min(h, w) < SSIM_WINDOW:
        raise ValueError(f"dssim needs images of at least {SSIM_WINDOW}x{SSIM_WINDOW} pixels, got {w}x{h}")
    s = tonemap_scale(ref, m) if scale is None else _check_scale(scale)
    return _dssim(_black_outside(img, m), _black_outside(ref, m), m, s)


def _lab(linear_display: np.ndarray) -> np.ndarray:
    import colour
    srgb = colour.RGB_COLOURSPACES["sRGB"]
    xyz = colour.RGB_to_XYZ(linear_display, srgb, apply_cctf_decoding=False)
    return colour.XYZ_to_Lab(xyz, srgb.whitepoint)


def _ciede2000(x: np.ndarray, r: np.ndarray, s: float) -> float:
    """Mean CIEDE2000 of the covered pixels x (image) and r (reference), Nx3, at exposure `s`."""
    from colour.difference import delta_E_CIE2000  # what colour.delta_E(method="CIE 2000") calls
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # colour's domain-range notices are not about our data
        lab_img = _lab(tonemap(x, s))
        lab_ref = _lab(tonemap(r, s))
        de = delta_E_CIE2000(lab_ref, lab_img)
    return float(np.mean(de))


def ciede2000(image, reference, mask=None, scale: float | None = None) -> float:
    """Mean CIEDE2000 over the mask between the tone-mapped images (CIE Lab, D65)."""
    img, ref, m = _inputs(image, reference, mask)
    if not m.any():
        return math.nan
    s = tonemap_scale(ref, m) if scale is None else _check_scale(scale)
    return _ciede2000(img[m], ref[m], s)


# ---------------------------------------------------------------------------- HDR-FLIP
def _flip_x_max() -> float:
    """The radiance the ACES curve (FLIP's coefficients) maps to 0.85: FLIP's automatic exposure anchor."""
    a, b, c, d, e, f = 0.6 * 0.6 * 2.51, 0.6 * 0.03, 0.0, 0.6 * 0.6 * 2.43, 0.6 * 0.59, 0.14
    t = 0.85
    qa, qb, qc = a - t * d, b - t * e, c - t * f
    return (-qb + math.sqrt(qb * qb - 4.0 * qa * qc)) / (2.0 * qa)


def _flip_reach(ppd: float) -> int:
    """How far (pixels) FLIP's filters read around a pixel: the larger of its spatial-filter radius
    ceil(3 sqrt(b / (2 pi^2)) ppd), b = 0.04 its widest Gaussian, and its feature-filter radius
    ceil(3 * 0.5 * 0.082 ppd); + 1 for FLIP computing them in float32."""
    spatial = math.ceil(3.0 * math.sqrt(0.04 / (2.0 * math.pi ** 2)) * ppd)
    feature = math.ceil(3.0 * 0.5 * 0.082 * ppd)
    return max(spatial, feature) + 1


FLIP_REACH = _flip_reach(FLIP_PPD)  # 11 pixels at 67 ppd
_MIN_EXPOSURE_SPAN = 1e-3  # FLIP aborts the process on start >= stop, so a uniform reference gets this span


def flip_exposure_range(reference, mask=None) -> tuple[float, float]:
    """(start, stop) exposures of HDR-FLIP for one reference, shared by every method judged on it.

    FLIP's rule (start = log2(x_max / Y_max), stop = log2(x_max / Y_median)) over the covered
    pixels of positive luminance; an all-zero reference behaves as a unit-luminance one.
    """
    ref = _as_rgb(reference, "reference")
    m = _as_mask(mask, ref.shape)
    lum = np.clip(ref, 0.0, None) @ LUMA
    lit = lum[m & (lum > 0)]
    y_max, y_med = (float(lit.max()), float(np.median(lit))) if lit.size else (1.0, 1.0)
    x_max = _flip_x_max()
    start, stop = math.log2(x_max / y_max), math.log2(x_max / y_med)
    return start, max(stop, start + _MIN_EXPOSURE_SPAN)


def _check_exposure(exposure) -> tuple[float, float]:
    try:
        start, stop = (float(v) for v in exposure)
    except (TypeError, ValueError):
        raise ValueError(f"flip_exposure must be a (start, stop) pair, got {exposure!r}") from None
    if not (math.isfinite(start) and math.isfinite(stop) and start < stop):
        raise ValueError(f"flip_exposure must be finite with start < stop, got ({start}, {stop})")
    return start, stop


def weighted_median(values: np.ndarray) -> float:
    """FLIP's weighted median: the smallest value v with sum(values <= v) > half the total (0 if all 0)."""
    v = np.sort(np.asarray(values, dtype=np.float64).ravel())
    total = v.sum()
    if v.size == 0 or total <= 0:
        return 0.0
    idx = int(np.searchsorted(np.cumsum(v), 0.5 * total, side="right"))
    return float(v[min(idx, v.size - 1)])


def _flip_map(ref32: np.ndarray, img32: np.ndarray, start: float, stop: float) -> np.ndarray:
    """flip-evaluator's HDR-FLIP map (float64) of two HxWx3 float32 images, exposures start..stop."""
    import flip_evaluator
    params = {"ppd": FLIP_PPD, "startExposure": start, "stopExposure": stop,
              "numExposures": max(2, math.ceil(stop - start)), "tonemapper": FLIP_TONEMAPPER}
    err, _, _ = flip_evaluator.evaluate(np.ascontiguousarray(ref32), np.ascontiguousarray(img32), "HDR",
                                        applyMagma=False, computeMeanError=False, parameters=params)
    return np.asarray(err, dtype=np.float64).reshape(ref32.shape[:2])


def _flip_inputs(img_b: np.ndarray, ref_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What FLIP is given: float32, negative radiance clamped to 0 (images black outside the mask)."""
    return (np.ascontiguousarray(np.clip(ref_b, 0.0, None), dtype=np.float32),
            np.ascontiguousarray(np.clip(img_b, 0.0, None), dtype=np.float32))


def _box(rows: np.ndarray, cols: np.ndarray):
    """[y0, y1, x0, x1) of the True entries of two 1-D any-masks, or None if there are none."""
    ys, xs = np.flatnonzero(rows), np.flatnonzero(cols)
    return None if ys.size == 0 else (int(ys[0]), int(ys[-1]) + 1, int(xs[0]), int(xs[-1]) + 1)


def _flip_covered(img_b: np.ndarray, ref_b: np.ndarray, m: np.ndarray, start: float, stop: float) -> np.ndarray:
    """HDR-FLIP's error at the covered pixels (the full map's values at `m`), computed on a crop.

    FLIP's error at a pixel depends only on the two images within FLIP_REACH pixels of it (separable
    filters clamped at the image edge, then per-pixel arithmetic and the maximum over exposures),
    and is exactly 0 where they are equal throughout that window (colour and feature differences
    are 0, and 0^p = 0). So the map is computed only on the box of covered pixels within
    FLIP_REACH of a pixel where the images differ, widened by FLIP_REACH (up to the image edge):
    every pixel of that box sees the same window, hence the same value, as in the full map, and
    the covered pixels outside it are 0, as there. An image equal to its reference costs nothing.
    """
    ref32, img32 = _flip_inputs(img_b, ref_b)
    out = np.zeros(m.shape, dtype=np.float64)
    differ = np.any(img32 != ref32, axis=2)
    d, c = _box(differ.any(axis=1), differ.any(axis=0)), _box(m.any(axis=1), m.any(axis=0))
    h, w, r = m.shape[0], m.shape[1], FLIP_REACH
    if d is not None and c is not None:
        y0, y1 = max(c[0], d[0] - r), min(c[1], d[1] + r)    # covered pixels that may be non-zero
        x0, x1 = max(c[2], d[2] - r), min(c[3], d[3] + r)
        if y0 < y1 and x0 < x1:
            y0, y1, x0, x1 = max(0, y0 - r), min(h, y1 + r), max(0, x0 - r), min(w, x1 + r)
            out[y0:y1, x0:x1] = _flip_map(ref32[y0:y1, x0:x1], img32[y0:y1, x0:x1], start, stop)
    return out[m]


def flip_error_map(image, reference, mask=None, exposure: tuple | None = None) -> np.ndarray:
    """The HxW HDR-FLIP error map (values in [0, 1]); negative radiance is clamped to 0."""
    img, ref, m = _inputs(image, reference, mask)
    start, stop = _check_exposure(flip_exposure_range(ref, m) if exposure is None else exposure)
    ref32, img32 = _flip_inputs(_black_outside(img, m), _black_outside(ref, m))
    return _flip_map(ref32, img32, start, stop)


def flip(image, reference, mask=None, exposure: tuple | None = None) -> tuple[float, float]:
    """(mean, error-weighted median) of the HDR-FLIP map over the mask."""
    img, ref, m = _inputs(image, reference, mask)
    if not m.any():
        return math.nan, math.nan
    start, stop = _check_exposure(flip_exposure_range(ref, m) if exposure is None else exposure)
    err = _flip_covered(_black_outside(img, m), _black_outside(ref, m), m, start, stop)
    return float(err.mean()), weighted_median(err)


# ---------------------------------------------------------------------------- all at once
def compute_all(image, reference, mask=None, flip_exposure: tuple | None = None,
                tonemap_scale_value: float | None = None) -> dict:
    """Every metric of METRICS, keyed by name. `flip_exposure` and `tonemap_scale_value` default
    to the reference's own (`flip_exposure_range`, `tonemap_scale`).

    The same values as the metric functions one by one, with the inputs checked once and shared:
    the covered pixels (per-pixel metrics, CIEDE2000) and the images black outside the mask
    (dssim, FLIP)."""
    img, ref, m = _inputs(image, reference, mask)
    if not m.any():
        return {name: math.nan for name in METRICS}
    s = tonemap_scale(ref, m) if tonemap_scale_value is None else _check_scale(tonemap_scale_value)
    start, stop = _check_exposure(flip_exposure_range(ref, m) if flip_exposure is None else flip_exposure)
    x, r = img[m], ref[m]
    img_b, ref_b = _black_outside(img, m), _black_outside(ref, m)
    err = _flip_covered(img_b, ref_b, m, start, stop)
    out = {"mse": _mse(x, r), "relmse": _relmse(x, r, _relmse_epsilon(r)), "smape": _smape(x, r, _smape_epsilon(r)),
           "dssim": _dssim(img_b, ref_b, m, s), "flip_mean": float(err.mean()), "flip_median": weighted_median(err),
           "ciede2000": _ciede2000(x, r, s)}
    return {name: out[name] for name in METRICS}
