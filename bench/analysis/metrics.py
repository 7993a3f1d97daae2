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

Cost: HDR-FLIP is most of it (max(2, ceil(stop - start)) LDR-FLIP passes per comparison). It runs
on FLIP.h compiled here (bench.analysis.flip_native; the flip-evaluator wheel without a compiler,
same values, ~4x slower), split in the reference's half and the image's: everything of the
reference alone (`PreparedReference`: covered pixels, epsilons, display transforms, its display
luminance's SSIM terms and its Lab, its FLIP half per exposure) is computed once and reused for
every image judged against it, and FLIP's map only on the box where it can be non-zero
(`_flip_covered`). All give exactly the values of the metric functions one by one, which call the
libraries plainly (tests/test_metrics_speed.py, tests/test_flip_native.py).
"""
from __future__ import annotations

import math
import warnings

import numpy as np

from bench.analysis import flip_native

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


def _display_luma(x_b: np.ndarray, s: float) -> np.ndarray:
    """What dssim compares: the sRGB-encoded luminance of the tone-mapped image (black outside the mask)."""
    return _srgb_encode(tonemap(x_b, s) @ LUMA)


def _check_ssim_size(m: np.ndarray) -> None:
    h, w = m.shape
    if min(h, w) < SSIM_WINDOW:
        raise ValueError(f"dssim needs images of at least {SSIM_WINDOW}x{SSIM_WINDOW} pixels, got {w}x{h}")


class _SsimReferenceSide:
    """scikit-image's structural_similarity(y_ref, y_img, win_size=SSIM_WINDOW, data_range=1, full=True)
    split at its terms of the reference alone (its im1), kept for every image judged against it; the
    image's side below repeats the library's operations in its order (the tests hold the two to the
    library call, bit for bit)."""
    COV_NORM = SSIM_WINDOW ** 2 / (SSIM_WINDOW ** 2 - 1)   # sample covariance, the library's default
    C1, C2 = (0.01 * 1.0) ** 2, (0.03 * 1.0) ** 2          # (K1 R)^2, (K2 R)^2 with R = data_range = 1

    def __init__(self, y_ref: np.ndarray):
        from scipy.ndimage import uniform_filter
        self.y = y_ref.astype(np.float64, copy=False)
        self.ux = uniform_filter(self.y, size=SSIM_WINDOW)
        self.vx = self.COV_NORM * (uniform_filter(self.y * self.y, size=SSIM_WINDOW) - self.ux * self.ux)
        self.two_ux = 2 * self.ux
        self.ux2 = self.ux ** 2

    def ssim_map(self, y_img: np.ndarray) -> np.ndarray:
        from scipy.ndimage import uniform_filter
        im2 = y_img.astype(np.float64, copy=False)
        uy = uniform_filter(im2, size=SSIM_WINDOW)
        uyy = uniform_filter(im2 * im2, size=SSIM_WINDOW)
        uxy = uniform_filter(self.y * im2, size=SSIM_WINDOW)
        vy = self.COV_NORM * (uyy - uy * uy)
        vxy = self.COV_NORM * (uxy - self.ux * uy)
        a1, a2 = self.two_ux * uy + self.C1, 2 * vxy + self.C2
        b1, b2 = self.ux2 + uy ** 2 + self.C1, self.vx + vy + self.C2
        return (a1 * a2) / (b1 * b2)


def _dssim_of_luma(y_img: np.ndarray, y_ref, m: np.ndarray) -> float:
    """1 - mean SSIM over `m`; `y_ref` the reference's display luminance or its _SsimReferenceSide."""
    side = y_ref if isinstance(y_ref, _SsimReferenceSide) else _SsimReferenceSide(y_ref)
    return float(1.0 - np.mean(side.ssim_map(y_img)[m]))


def _dssim(img_b: np.ndarray, ref_b: np.ndarray, m: np.ndarray, s: float) -> float:
    """dssim of images already black outside the (non-empty) mask `m`, at exposure `s`."""
    _check_ssim_size(m)
    return _dssim_of_luma(_display_luma(img_b, s), _display_luma(ref_b, s), m)


def dssim(image, reference, mask=None, scale: float | None = None) -> float:
    """1 - SSIM of sRGB-encoded luminance of the tone-mapped images, averaged over the mask."""
    img, ref, m = _inputs(image, reference, mask)
    if not m.any():
        return math.nan
    _check_ssim_size(m)
    s = tonemap_scale(ref, m) if scale is None else _check_scale(scale)
    return _dssim(_black_outside(img, m), _black_outside(ref, m), m, s)


def _lab(linear_display: np.ndarray) -> np.ndarray:
    import colour
    srgb = colour.RGB_COLOURSPACES["sRGB"]
    xyz = colour.RGB_to_XYZ(linear_display, srgb, apply_cctf_decoding=False)
    return colour.XYZ_to_Lab(xyz, srgb.whitepoint)


def _display_lab(x: np.ndarray, s: float) -> np.ndarray:
    """CIE Lab (D65) of the tone-mapped covered pixels x (Nx3): what CIEDE2000 compares."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # colour's domain-range notices are not about our data
        return _lab(tonemap(x, s))


def _ciede2000_of_lab(lab_img: np.ndarray, lab_ref: np.ndarray) -> float:
    from colour.difference import delta_E_CIE2000  # what colour.delta_E(method="CIE 2000") calls
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        de = delta_E_CIE2000(lab_ref, lab_img)
    return float(np.mean(de))


def _ciede2000(x: np.ndarray, r: np.ndarray, s: float) -> float:
    """Mean CIEDE2000 of the covered pixels x (image) and r (reference), Nx3, at exposure `s`."""
    return _ciede2000_of_lab(_display_lab(x, s), _display_lab(r, s))


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


def _flip_exposures(start: float, stop: float) -> int:
    return max(2, math.ceil(stop - start))   # FLIP's own count for a user-given range


def _flip_map(ref32: np.ndarray, img32: np.ndarray, start: float, stop: float) -> np.ndarray:
    """HDR-FLIP's map (float64) of two HxWx3 float32 images, exposures start..stop: FLIP.h compiled
    here (bench.analysis.flip_native) or, without a compiler, the flip-evaluator wheel (the same values)."""
    if flip_native.library() is not None:
        err = flip_native.flip_map(ref32, img32, FLIP_PPD, start, stop, _flip_exposures(start, stop))
        return err.astype(np.float64)
    import flip_evaluator
    params = {"ppd": FLIP_PPD, "startExposure": start, "stopExposure": stop,
              "numExposures": _flip_exposures(start, stop), "tonemapper": FLIP_TONEMAPPER}
    err, _, _ = flip_evaluator.evaluate(np.ascontiguousarray(ref32), np.ascontiguousarray(img32), "HDR",
                                        applyMagma=False, computeMeanError=False, parameters=params)
    return np.asarray(err, dtype=np.float64).reshape(ref32.shape[:2])


def _flip_input(x_b: np.ndarray) -> np.ndarray:
    """What FLIP is given: float32, negative radiance clamped to 0 (the image black outside the mask)."""
    return np.ascontiguousarray(np.clip(x_b, 0.0, None), dtype=np.float32)


def _flip_inputs(img_b: np.ndarray, ref_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return _flip_input(ref_b), _flip_input(img_b)


def _box(rows: np.ndarray, cols: np.ndarray):
    """[y0, y1, x0, x1) of the True entries of two 1-D any-masks, or None if there are none."""
    ys, xs = np.flatnonzero(rows), np.flatnonzero(cols)
    return None if ys.size == 0 else (int(ys[0]), int(ys[-1]) + 1, int(xs[0]), int(xs[-1]) + 1)


def _flip_boxes(img32: np.ndarray, ref32: np.ndarray, m: np.ndarray):
    """(inner, crop) boxes [y0, y1, x0, x1) of `_flip_covered`, or None when every covered pixel is 0."""
    differ = np.any(img32 != ref32, axis=2)
    d, c = _box(differ.any(axis=1), differ.any(axis=0)), _box(m.any(axis=1), m.any(axis=0))
    h, w, r = m.shape[0], m.shape[1], FLIP_REACH
    if d is None or c is None:
        return None
    y0, y1 = max(c[0], d[0] - r), min(c[1], d[1] + r)    # covered pixels that may be non-zero
    x0, x1 = max(c[2], d[2] - r), min(c[3], d[3] + r)
    if not (y0 < y1 and x0 < x1):
        return None
    return (y0, y1, x0, x1), (max(0, y0 - r), min(h, y1 + r), max(0, x0 - r), min(w, x1 + r))


def _flip_covered(img_b: np.ndarray, ref_b: np.ndarray, m: np.ndarray, start: float, stop: float,
                  reference_features=None, ref32: np.ndarray | None = None, threads: int = 0) -> np.ndarray:
    """HDR-FLIP's error at the covered pixels (the full map's values at `m`), computed on a crop.

    FLIP's error at a pixel depends only on the two images within FLIP_REACH pixels of it (separable
    filters clamped at the image edge, then per-pixel arithmetic and the maximum over exposures),
    and is exactly 0 where they are equal throughout that window (colour and feature differences
    are 0, and 0^p = 0). So the map is computed only on the box of covered pixels within
    FLIP_REACH of a pixel where the images differ (the inner box), widened by FLIP_REACH (up to the
    image edge): every pixel of the inner box sees the same window, hence the same value, as in the
    full map, the rest of the crop is 0 in both, and the covered pixels outside it are 0, as there.
    An image equal to its reference costs nothing.

    `reference_features` (a callable returning flip_native.reference_features of the whole of
    `ref_b`'s FLIP input at these exposures) lets the compiled FLIP reuse the reference's half: the
    test image's half is then computed on the crop and the inner box is kept (its filter windows lie
    in the crop, so both halves there are the whole image's). `ref32`: `ref_b`'s FLIP input, if at hand;
    `threads`: the compiled FLIP's OpenMP threads (0: its default)."""
    ref32, img32 = _flip_input(ref_b) if ref32 is None else ref32, _flip_input(img_b)
    out = np.zeros(m.shape, dtype=np.float64)
    boxes = _flip_boxes(img32, ref32, m)
    if boxes is not None:
        (iy0, iy1, ix0, ix1), (y0, y1, x0, x1) = boxes
        if reference_features is not None and flip_native.library() is not None:
            crop = flip_native.map_against_reference(reference_features(), img32[y0:y1, x0:x1], y0, x0, FLIP_PPD,
                                                     start, stop, threads)
            out[iy0:iy1, ix0:ix1] = crop[iy0 - y0:iy1 - y0, ix0 - x0:ix1 - x0]
        else:
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
class PreparedReference:
    """What the metrics derive from one reference and mask alone (checked arrays, covered pixels,
    epsilons, display transforms, the reference's display luminance and Lab, its half of HDR-FLIP),
    computed once and shared by every image judged against them (`compute_all_against`;
    bench.analysis.evaluation keeps those of a view's references across its rows)."""

    def __init__(self, reference, mask=None, flip_exposure: tuple | None = None,
                 tonemap_scale_value: float | None = None):
        ref = _as_rgb(reference, "reference")
        m = _as_mask(mask, ref.shape)
        self.ref, self.mask, self.covered = ref, m, bool(m.any())
        if not self.covered:
            return
        self.scale = tonemap_scale(ref, m) if tonemap_scale_value is None else _check_scale(tonemap_scale_value)
        self.exposure = _check_exposure(flip_exposure_range(ref, m) if flip_exposure is None else flip_exposure)
        self.r = ref[m]
        self.relmse_eps, self.smape_eps = _relmse_epsilon(self.r), _smape_epsilon(self.r)
        self.ref_b = _black_outside(ref, m)
        self.ref32 = _flip_input(self.ref_b)
        self.lab = _display_lab(self.r, self.scale)
        small = min(m.shape) < SSIM_WINDOW   # dssim raises for such images, when asked
        self.ssim = None if small else _SsimReferenceSide(_display_luma(self.ref_b, self.scale))
        self._flip_features = None

    @property
    def covered_mean(self) -> float:
        """Mean of the reference over the covered pixels and channels (0 if none is covered)."""
        return float(self.r.mean()) if self.covered else 0.0

    def flip_features(self, threads: int = 0) -> np.ndarray:
        """The reference's half of the compiled HDR-FLIP on the whole image (computed on first use)."""
        if self._flip_features is None:
            start, stop = self.exposure
            self._flip_features = flip_native.reference_features(self.ref32, FLIP_PPD, start, stop,
                                                                 _flip_exposures(start, stop), threads)
        return self._flip_features

    @property
    def nbytes(self) -> int:
        arrays = [v for v in vars(self).values() if isinstance(v, np.ndarray)]
        arrays += [v for v in vars(self.ssim).values() if isinstance(v, np.ndarray)] if self.covered and self.ssim else []
        return sum(a.nbytes for a in arrays)


def _checked_image(image, prepared: PreparedReference) -> np.ndarray:
    img = _as_rgb(image, "image")
    if img.shape != prepared.ref.shape:
        raise ValueError(f"image has shape {img.shape} but reference has shape {prepared.ref.shape}")
    return img


def flip_covered_errors(image, prepared: PreparedReference, threads: int = 0) -> np.ndarray:
    """HDR-FLIP's error at the covered pixels of `image` against `prepared` (`_flip_covered`, reusing
    the reference's half); `threads`: the compiled FLIP's OpenMP threads (0: its default)."""
    img, p = _checked_image(image, prepared), prepared
    return _flip_covered(_black_outside(img, p.mask), p.ref_b, p.mask, *p.exposure, ref32=p.ref32,
                         reference_features=lambda: p.flip_features(threads), threads=threads)


def ciede2000_against(image, prepared: PreparedReference) -> float:
    """The ciede2000 of `image` against the covered reference `prepared`."""
    img, p = _checked_image(image, prepared), prepared
    return _ciede2000_of_lab(_display_lab(img[p.mask], p.scale), p.lab)


def compute_all_against(image, prepared: PreparedReference, elsewhere: dict | None = None) -> dict:
    """`compute_all` of `image` against the reference and mask `prepared` was built from.
    `elsewhere` may hold zero-argument callables computing parts meanwhile on other threads
    (bench.analysis.evaluation): "flip" returns `flip_covered_errors(image, prepared)`, "ciede2000"
    returns `ciede2000_against(image, prepared)`."""
    img = _checked_image(image, prepared)
    if not prepared.covered:
        return {name: math.nan for name in METRICS}
    m, r, p, elsewhere = prepared.mask, prepared.r, prepared, elsewhere or {}
    x = img[m]
    img_b = _black_outside(img, m)
    flip_errors = elsewhere.get("flip") or (lambda: _flip_covered(img_b, p.ref_b, m, *p.exposure, ref32=p.ref32,
                                                                   reference_features=p.flip_features))
    ciede = elsewhere.get("ciede2000") or (lambda: _ciede2000_of_lab(_display_lab(x, p.scale), p.lab))
    if p.ssim is None:
        _check_ssim_size(m)
    out = {"mse": _mse(x, r), "relmse": _relmse(x, r, p.relmse_eps), "smape": _smape(x, r, p.smape_eps),
           "dssim": _dssim_of_luma(_display_luma(img_b, p.scale), p.ssim, m), "ciede2000": ciede()}
    err = flip_errors()
    out["flip_mean"], out["flip_median"] = float(err.mean()), weighted_median(err)
    return {name: out[name] for name in METRICS}


def compute_all(image, reference, mask=None, flip_exposure: tuple | None = None,
                tonemap_scale_value: float | None = None, prepared: PreparedReference | None = None,
                elsewhere: dict | None = None) -> dict:
    """Every metric of METRICS, keyed by name. `flip_exposure` and `tonemap_scale_value` default
    to the reference's own (`flip_exposure_range`, `tonemap_scale`). `prepared`, if given, is
    `PreparedReference(reference, mask, flip_exposure, tonemap_scale_value)` made earlier (the
    arguments are then not read again), and `elsewhere` that of `compute_all_against`.

    The same values as the metric functions one by one, with the inputs checked once and shared:
    the covered pixels (per-pixel metrics, CIEDE2000), the images black outside the mask (dssim,
    FLIP) and everything of the reference alone (`PreparedReference`)."""
    if prepared is not None:
        return compute_all_against(image, prepared, elsewhere)
    ref = _as_rgb(reference, "reference")
    img = _as_rgb(image, "image")
    if img.shape != ref.shape:
        raise ValueError(f"image has shape {img.shape} but reference has shape {ref.shape}")
    return compute_all_against(img, PreparedReference(ref, mask, flip_exposure, tonemap_scale_value))
