"""The figures of a stress row (bench.stress.suite): non-finite and negative pixel counts, the
relative change of an image against the unperturbed one, the expected change between two
independent reference estimates (their noise), and the error against the Mitsuba references."""
from __future__ import annotations

import numpy as np

from bench.analysis.evaluation import coverage_mask
from bench.analysis.metrics import relmse
from bench.protocol.vocabulary import REFERENCE_COMPONENTS, REFERENCE_PARTS


def pixel_counts(*images) -> dict:
    """NaN / Inf / negative pixel counts over `images` together (a pixel counts once per image)."""
    nan = inf = neg = 0
    low = np.inf
    for img in images:
        a = np.asarray(img, dtype=np.float64)[..., :3]
        nan += int(np.isnan(a).any(axis=-1).sum())
        inf += int(np.isinf(a).any(axis=-1).sum())
        neg += int((a < 0).any(axis=-1).sum())
        finite_values = a[np.isfinite(a)]
        if finite_values.size:
            low = min(low, float(finite_values.min()))
    return {"nan_pixels": nan, "inf_pixels": inf, "negative_pixels": neg, "min_value": low if np.isfinite(low) else np.nan}


def finite(img) -> np.ndarray:
    return np.nan_to_num(np.asarray(img, dtype=np.float64)[..., :3], nan=0.0, posinf=0.0, neginf=0.0)


def combined(images: dict) -> np.ndarray:
    """direct + indirect of a method's images, non-finite values as 0."""
    return finite(images["direct"]) + finite(images["indirect"])


def relative_change(image, base) -> float:
    """sum |I - I0| / sum |I0| over every pixel and channel (non-finite values count as 0)."""
    a, b = finite(image), finite(base)
    if a.shape != b.shape:
        return float("nan")
    denom = float(np.abs(b).sum())
    diff = float(np.abs(a - b).sum())
    if denom == 0.0:
        return 0.0 if diff == 0.0 else float("inf")
    return diff / denom


def mean_change(image, base) -> float:
    """mean(I) / mean(I0) - 1 (signed; non-finite values count as 0)."""
    a, b = float(finite(image).mean()), float(finite(base).mean())
    if b == 0.0:
        return 0.0 if a == 0.0 else float("inf")
    return a / b - 1.0


def image_changes(images: dict, base: dict) -> dict:
    """`change`, `change_indirect` and `mean_change` of a method's images against `base`'s."""
    return {"change": relative_change(combined(images), combined(base)),
            "change_indirect": relative_change(images["indirect"], base["indirect"]),
            "mean_change": mean_change(combined(images), combined(base))}


def reference_mean_noise(base, other) -> float:
    """Standard deviation of mean(I) / mean(I0) - 1 for two independent estimates (variance images)."""
    n = np.asarray(base.variance).size
    var = float(np.asarray(base.variance, np.float64).sum() + np.asarray(other.variance, np.float64).sum()) / n ** 2
    denom = float(finite(base.mean).mean())
    return float(np.sqrt(var)) / denom if denom > 0 else 0.0


def reference_noise_change(base, other) -> float:
    """Expected relative L1 difference of two independent estimates (means + variance images)."""
    var = np.asarray(base.variance, np.float64) + np.asarray(other.variance, np.float64)
    denom = float(np.abs(finite(base.mean)).mean())
    if denom == 0.0:
        return 0.0
    return float(np.sqrt(2.0 / np.pi * var.mean())) / denom


def error_of(images: dict, refs: dict | None) -> dict:
    """relMSE of combined and indirect against the references (NaN without references)."""
    if not refs or any(refs.get(c) is None for c in REFERENCE_COMPONENTS):
        return {"combined": float("nan"), "indirect": float("nan")}
    imgs = {k: finite(v).astype(np.float32) for k, v in images.items()}
    imgs["combined"] = imgs["direct"] + imgs["indirect"]
    ref_means = {c: finite(refs[c].mean).astype(np.float32) for c in REFERENCE_COMPONENTS}
    mask = coverage_mask(imgs, ref_means)
    if not mask.any():
        return {"combined": float("nan"), "indirect": float("nan")}
    judge = lambda component: sum(ref_means[c] for c in REFERENCE_PARTS[component])
    return {"combined": float(relmse(imgs["combined"], judge("combined"), mask)),
            "indirect": float(relmse(imgs["indirect"], judge("indirect"), mask))}
