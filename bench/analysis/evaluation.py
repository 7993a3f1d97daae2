"""Error columns of one result row: the method's images against the Mitsuba references.

Components compared (column suffix -> method image vs reference):
  direct              direct                vs direct
  indirect            indirect              vs indirect_unshadowed  (what FLC, SSDO, DSS estimate)
  indirect_visible    indirect              vs indirect_visible     (the physically correct bounce)
  combined            direct + indirect     vs direct + indirect_visible
The covered-pixel mask is where the reference's direct + indirect is non-zero or the method's
image is (background pixels are black in both).

Components and which reference judges which image: bench.protocol.vocabulary.COMPARISONS.
Columns: `<metric>.<component>` for every metric of `bench.analysis.metrics.METRICS` (mse, relmse, smape,
dssim, flip_mean, flip_median, ciede2000; all lower is better). The display transforms of FLIP
and of dssim/ciede2000 depend on the reference alone (its covered pixels of positive value are
always inside the mask), so every method on a view is judged on the same scale.

Besides the error metrics, `mean_ratio.<component>` is the mean of the method's image over the
mean of the reference on the covered pixels (all channels): 1 is unbiased in the image mean, the
figure the method issues quote ("FLC's indirect over the reference"). It is a bias figure, not an
error (0.5 and 2 are equally wrong), so the gate does not gate on it; a black reference gives no
column.

Memo: with `memo_dir`, each comparison's columns are stored under the sha256 of its inputs (the
method image, the reference, the mask) and of the metric code, and read back instead of being
recomputed: the shared direct image of a view is judged once for all its methods, and a re-run
whose images and references are unchanged computes nothing (HDR-FLIP is most of a row's metric
cost: ~0.4 s per comparison at 320x180).
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from bench.analysis import metrics
from bench.protocol.versioning import hash_files
from bench.protocol.vocabulary import COMPARISONS, IMAGE_COMPONENTS



def coverage_mask(images: dict, refs: dict) -> np.ndarray:
    ref_any = [r for r in refs.values() if r is not None]
    total = sum(np.abs(r).sum(axis=2) for r in ref_any) + np.abs(images["combined"]).sum(axis=2)
    return total > 0


_CODE_HASH: list = []


def _code_hash() -> str:
    """Hash of the metric code (prose excluded): a change to it invalidates every memo entry."""
    if not _CODE_HASH:
        _CODE_HASH.append(hash_files([Path(__file__), Path(metrics.__file__)]))
    return _CODE_HASH[0]


def _memo_key(column: str, image: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> str:
    h = hashlib.sha256(f"{_code_hash()}|{column}|{image.shape}".encode())
    for arr in (image, reference, mask):
        h.update(memoryview(np.ascontiguousarray(arr)).cast("B"))
    return h.hexdigest()[:32]


def _memo_read(memo_dir, key: str):
    if memo_dir is None:
        return None
    try:
        data = json.loads((Path(memo_dir) / key[:2] / f"{key}.json").read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _memo_write(memo_dir, key: str, values: dict) -> None:
    if memo_dir is None:
        return
    path = Path(memo_dir) / key[:2] / f"{key}.json"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f"{path.name}.tmp{os.getpid()}")
        tmp.write_text(json.dumps(values))
        os.replace(tmp, path)
    except OSError:
        pass  # a memo that cannot be written is only a lost shortcut


def evaluate_row(images: dict, refs: dict, memo_dir=None) -> dict:
    missing = [name for name in IMAGE_COMPONENTS if images.get(name) is None]
    if missing:
        raise ValueError(f"evaluate_row: method image(s) {', '.join(missing)} missing")
    mask = coverage_mask(images, refs)
    out = {}
    for column, (image_name, ref_parts) in COMPARISONS.items():
        parts = [refs.get(p) for p in ref_parts]
        if any(p is None for p in parts):
            continue
        reference = sum(parts)
        key = _memo_key(column, np.asarray(images[image_name], np.float32), np.asarray(reference, np.float32), mask) \
            if memo_dir is not None else ""
        values = _memo_read(memo_dir, key)
        if values is None:
            scores = metrics.compute_all(images[image_name], reference, mask,
                                         flip_exposure=metrics.flip_exposure_range(reference, mask),
                                         tonemap_scale_value=metrics.tonemap_scale(reference, mask))
            values = {f"{name}.{column}": float(value) for name, value in scores.items()}
            ratio = mean_ratio(images[image_name], reference, mask)
            if np.isfinite(ratio):  # a black reference has no ratio: the column is left out
                values[f"mean_ratio.{column}"] = ratio
            _memo_write(memo_dir, key, values)
        out.update(values)
    return out


def mean_ratio(image: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> float:
    """Mean of `image` over mean of `reference` on the masked pixels; NaN when the reference is black."""
    ref_mean = float(np.asarray(reference, dtype=np.float64)[mask].mean()) if mask.any() else 0.0
    if not ref_mean > 0.0:
        return float("nan")
    return float(np.asarray(image, dtype=np.float64)[mask].mean()) / ref_mean
