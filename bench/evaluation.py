"""Error columns of one result row: the method's images against the Mitsuba references.

Components compared (column suffix -> method image vs reference):
  direct              direct                vs direct
  indirect            indirect              vs indirect_unshadowed  (what FLC, SSDO, DSS estimate)
  indirect_visible    indirect              vs indirect_visible     (the physically correct bounce)
  combined            direct + indirect     vs direct + indirect_visible
The covered-pixel mask is where the reference's direct + indirect is non-zero or the method's
image is (background pixels are black in both).

Columns: `<metric>.<component>` for every metric of `bench.metrics.METRICS` (mse, relmse, smape,
dssim, flip_mean, flip_median, ciede2000; all lower is better). The display transforms of FLIP
and of dssim/ciede2000 depend on the reference alone (its covered pixels of positive value are
always inside the mask), so every method on a view is judged on the same scale.
"""
from __future__ import annotations

import numpy as np

COMPARISONS = {
    "direct": ("direct", ("direct",)),
    "indirect": ("indirect", ("indirect_unshadowed",)),
    "indirect_visible": ("indirect", ("indirect_visible",)),
    "combined": ("combined", ("direct", "indirect_visible")),
}


def coverage_mask(images: dict, refs: dict) -> np.ndarray:
    ref_any = [r for r in refs.values() if r is not None]
    total = sum(np.abs(r).sum(axis=2) for r in ref_any) + np.abs(images["combined"]).sum(axis=2)
    return total > 0


def evaluate_row(images: dict, refs: dict) -> dict:
    from bench.metrics import compute_all, flip_exposure_range, tonemap_scale
    missing = [name for name in ("direct", "indirect", "combined") if images.get(name) is None]
    if missing:
        raise ValueError(f"evaluate_row: method image(s) {', '.join(missing)} missing")
    mask = coverage_mask(images, refs)
    out = {}
    for column, (image_name, ref_parts) in COMPARISONS.items():
        parts = [refs.get(p) for p in ref_parts]
        if any(p is None for p in parts):
            continue
        reference = sum(parts)
        metrics = compute_all(images[image_name], reference, mask, flip_exposure=flip_exposure_range(reference, mask),
                              tonemap_scale_value=tonemap_scale(reference, mask))
        for name, value in metrics.items():
            out[f"{name}.{column}"] = float(value)
    return out
