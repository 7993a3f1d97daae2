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

Error over frames (rows rendered with K = `extra.error_frames` > 1 error frames: the row's own
frames 0..K-1, bench.run.harness): for each error component e whose method image
is indirect or combined (DECOMPOSITION_COMPONENTS: indirect, indirect_visible, combined), from
the per-pixel mean M, unbiased variance V (K - 1 denominator) and flicker D (mean over
consecutive pairs of (f_{k+1} - f_k)^2) of the K frames, R the summed reference and S its
variance image (the variance of the reference's mean, summed over its parts: its own noise), the
per-pixel quantities, averaged over the covered pixels and RGB:
  mse_accumulated.e = mean((M - R)^2 - S)          what averaging the K frames reaches
  variance.e        = mean(V)                       the per-pixel variance of one frame
  bias2.e           = mean((M - R)^2 - V / K - S)   the squared bias, the variance of the mean removed
  flicker.e         = mean(D) / 2                   = the variance for independent frames
and `rel_<metric>.e`: the same per-pixel quantities weighted by 1 / (R^2 + EPS_RELMSE mean(R^2)),
relmse's normalisation (bench.analysis.metrics), so they do not change with the scene's
brightness. Each has a 95% interval over pixels, `<metric>_ci.e` = 1.96 sd(per-pixel value) /
sqrt(pixel count), a pixel's value being its RGB mean.

The identity: for frames f_k of per-pixel mean mu and variance sigma^2, independent of each
other and of the reference (mean r), E[(f - R)^2] - S = (mu - r)^2 + sigma^2 for one frame, and
E[(M - R)^2] = (mu - r)^2 + sigma^2 / K + S with E[V] = sigma^2, so bias2 and variance are
unbiased estimates of (mu - r)^2 and sigma^2 and

    E[single-frame MSE] = bias2 + variance        (rel_bias2 + rel_variance: the expected relmse)

with the single-frame MSE net of the reference's noise (mse.e minus the reference's noise
floor). Frames that reuse earlier frames (temporal accumulation) are correlated: their flicker is
below their variance, V underestimates sigma^2 (for correlation rho between neighbours only,
E[V] = sigma^2 (1 - 2 rho / K)) and V / K the variance of the mean, so bias2 then includes part of
the noise. A deterministic method (the same image every frame) has variance and flicker exactly
0, and bias2 = mse_accumulated = its single-frame MSE net of the reference's noise. The relative
columns weight each pixel by the noisy R, as relmse does, so the reference's noise is in the
weight as well as in the error: a second-order bias S does not remove, about 4 S / ((mu - r) r)
of rel_bias2 (5% on a test where the reference's noise sd is a third of the bias and 3% of r);
the absolute columns have none.

Memo: with `memo_dir`, each comparison's columns are stored under the sha256 of its inputs (the
method image, the reference, the mask) and of the metric code, and read back instead of being
recomputed: the shared direct image of a view is judged once for all its methods, and a re-run
whose images and references are unchanged computes nothing.

Cost: the reference's side of the metrics (metrics.PreparedReference, with its half of HDR-FLIP)
is kept for the next rows (`prepared_reference`: the runner judges a view's rows one after
another), and each comparison's compiled HDR-FLIP (one OpenMP thread) and CIEDE2000 run on two
threads of their own (`_worker`) while the caller's thread computes the rest: the compiled FLIP
releases the GIL throughout, numpy in its array loops, so a row keeps two cores busy. HDR-FLIP
is still the largest part: ~9-11 ms per exposure and core for the image's half at 320x180, 2 to
11 exposures a comparison on the validation views. The decomposition selects each image's covered
pixels once per row (the statistics of `indirect` serve two columns) and sums the channels in
numpy's own order (tests/test_metrics_speed.py: the plain formulas, bit for bit): 36 -> 19 ms a
column at 320x180.
"""
from __future__ import annotations

import hashlib
import json
import os
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor, wait
from pathlib import Path

import numpy as np

from bench.analysis import flip_native, metrics
from bench.protocol.versioning import hash_files
from bench.protocol.vocabulary import (COMPARISONS, DECOMPOSITION_COMPONENTS, DECOMPOSITION_METRICS, IMAGE_COMPONENTS,
                                       frame_stat_image, interval_column, metric_column)

Z95 = 1.959963984540054   # the two-sided 95% quantile of the normal distribution



def coverage_mask(images: dict, refs: dict) -> np.ndarray:
    ref_any = [r for r in refs.values() if r is not None]
    total = sum(np.abs(r).sum(axis=2) for r in ref_any) + np.abs(images["combined"]).sum(axis=2)
    return total > 0


_CODE_HASH: list = []


def _code_hash() -> str:
    """Hash of the metric code (prose excluded; the compiled FLIP's sources as text): a change to it
    invalidates every memo entry."""
    if not _CODE_HASH:
        _CODE_HASH.append(hash_files([Path(__file__), Path(metrics.__file__), Path(flip_native.__file__),
                                      *flip_native.SOURCES]))
    return _CODE_HASH[0]


def _memo_key(column: str, *arrays: np.ndarray) -> str:
    """sha256 of the metric code, the column (with any scalar input in it) and every input array
    (its shape and dtype with its bytes)."""
    h = hashlib.sha256(f"{_code_hash()}|{column}".encode())
    for arr in arrays:
        arr = np.ascontiguousarray(arr)
        h.update(f"|{arr.shape}|{arr.dtype.str}|".encode())
        h.update(memoryview(arr).cast("B"))
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


PREPARED_CACHE_BYTES = 512 * 2 ** 20   # a view's four references at 320x180 take 40-85 MB (2-12 FLIP exposures)
_PREPARED: OrderedDict = OrderedDict()   # key -> metrics.PreparedReference, least recently used first


def prepared_reference(reference: np.ndarray, mask: np.ndarray) -> metrics.PreparedReference:
    """The reference's side of the metrics (metrics.PreparedReference), kept for the next rows: the
    runner judges a view's rows one after another against the same references and mask, so all but
    the first reuse it. Keyed by the bytes of reference and mask; bounded by PREPARED_CACHE_BYTES."""
    reference, mask = np.ascontiguousarray(reference), np.ascontiguousarray(mask)
    h = hashlib.blake2b(digest_size=20)
    for arr in (reference, mask):
        h.update(f"{arr.shape}|{arr.dtype.str}|".encode())
        h.update(memoryview(arr).cast("B"))
    key = h.hexdigest()
    prepared = _PREPARED.pop(key, None)
    if prepared is None:
        prepared = metrics.PreparedReference(reference, mask)
    _PREPARED[key] = prepared
    while _PREPARED and sum(p.nbytes for p in _PREPARED.values()) > PREPARED_CACHE_BYTES:
        _PREPARED.popitem(last=False)   # the oldest first; one too big for the bound is not kept
    return prepared


_WORKERS: dict = {}   # (pid, name) -> a thread pool of one thread


def _worker(name: str) -> ThreadPoolExecutor:
    """A thread of its own for one costly part of the metrics: "flip" (the compiled HDR-FLIP, which
    releases the GIL; one OpenMP thread there) and "colour" (CIEDE2000, numpy array loops that
    release it). With the caller's thread they keep two cores busy. The colour worker is the only
    thread entering warnings.catch_warnings (not thread-safe) while they run. Per process: a
    forked child makes its own."""
    key = (os.getpid(), name)
    if key not in _WORKERS:
        _WORKERS[key] = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"gibench-{name}")
    return _WORKERS[key]


def evaluate_row(images: dict, refs: dict, memo_dir=None, ref_variances: dict | None = None,
                 frame_stats: dict | None = None, error_frames: int = 1) -> dict:
    """Error columns of a row's images (`images`: IMAGE_COMPONENTS) against the references
    (`refs`: REFERENCE_COMPONENTS, None where missing). With `frame_stats` ({frame_stat_image(c, s):
    HxWx3} of the error frames) and `error_frames` K > 1, the decomposition columns too, the
    references' noise removed with `ref_variances` (the variance of each reference's mean; a
    missing one counts as 0)."""
    missing = [name for name in IMAGE_COMPONENTS if images.get(name) is None]
    if missing:
        raise ValueError(f"evaluate_row: method image(s) {', '.join(missing)} missing")
    mask = coverage_mask(images, refs)
    jobs = []   # (column, method image, reference, memo key, memoised values or None)
    for column, (image_name, ref_parts) in COMPARISONS.items():
        parts = [refs.get(p) for p in ref_parts]
        if any(p is None for p in parts):
            continue
        reference = sum(parts)
        key = _memo_key(column, np.asarray(images[image_name], np.float32), np.asarray(reference, np.float32), mask) \
            if memo_dir is not None else ""
        jobs.append((column, images[image_name], reference, key, _memo_read(memo_dir, key)))
    prepared = {job[0]: prepared_reference(job[2], mask) for job in jobs if job[4] is None}
    elsewhere, running = {column: {} for column in prepared}, []
    if flip_native.library() is not None:   # the two costliest parts on two more threads, this one does the rest
        for column, image, _, _, _ in jobs:
            if column in prepared and prepared[column].covered:
                flip = _worker("flip").submit(metrics.flip_covered_errors, image, prepared[column], 1)
                colour = _worker("colour").submit(metrics.ciede2000_against, image, prepared[column])
                running += [flip, colour]
                elsewhere[column] = {"flip": flip.result, "ciede2000": colour.result}
    out, decomposed = {}, {}
    try:
        if frame_stats is not None and int(error_frames) > 1:   # first: this thread's share while the others run
            decomposed = _decomposition_columns(frame_stats, refs, ref_variances or {}, mask, int(error_frames),
                                                memo_dir)
        for column, image, reference, key, values in jobs:
            if values is None:
                p = prepared[column]
                scores = metrics.compute_all(image, reference, mask, prepared=p, elsewhere=elsewhere[column])
                values = {f"{name}.{column}": float(value) for name, value in scores.items()}
                ratio = mean_ratio(image, reference, mask, reference_mean=p.covered_mean)
                if np.isfinite(ratio):  # a black reference has no ratio: the column is left out
                    values[f"mean_ratio.{column}"] = ratio
                _memo_write(memo_dir, key, values)
            out.update(values)
    finally:
        wait(running)   # nothing of this row still runs when the next one starts (or an error propagates)
    out.update(decomposed)
    return out


def _decomposition_columns(frame_stats: dict, refs: dict, ref_variances: dict, mask: np.ndarray, frames: int,
                           memo_dir) -> dict:
    out = {}
    covered = _CoveredPixels(mask)   # each image's covered pixels selected once for the row's columns
    for column in DECOMPOSITION_COMPONENTS:
        image_name, ref_parts = COMPARISONS[column]
        parts = [refs.get(p) for p in ref_parts]
        if any(p is None for p in parts):
            continue
        reference = np.asarray(sum(parts), np.float32)
        variances = [ref_variances.get(p) for p in ref_parts]
        ref_variance = np.asarray(sum(v if v is not None else np.zeros_like(reference) for v in variances), np.float32)
        names = [frame_stat_image(image_name, s) for s in ("mean", "var", "flicker")]
        mean, var, flicker = (np.asarray(frame_stats[n], np.float32) for n in names)
        key = _memo_key(f"decomposition|{column}|K={frames}", mean, var, flicker, reference, ref_variance, mask) \
            if memo_dir is not None else ""
        values = _memo_read(memo_dir, key)
        if values is None:
            values = {}
            selected = [covered.get(n, a) for n, a in zip(names, (mean, var, flicker))]
            selected += [covered.get(f"reference|{column}", reference), covered.get(f"variance|{column}", ref_variance)]
            for metric, (value, ci) in _decomposition_of_covered(*selected, frames).items():
                values[metric_column(metric, column)] = value
                values[interval_column(metric, column)] = ci
            _memo_write(memo_dir, key, values)
        out.update(values)
    return out


class _CoveredPixels:
    """The covered pixels of HxWx3 images (Nx3 float64, in the order of `mask`'s flat indices, as
    `a[mask]` gives them), each selected once per name: the frame statistics of `indirect` serve
    two columns."""

    def __init__(self, mask: np.ndarray):
        self.index = np.flatnonzero(np.asarray(mask, bool).ravel())
        self._selected: dict = {}

    def get(self, name: str, image: np.ndarray) -> np.ndarray:
        if name not in self._selected:
            flat = np.asarray(image).reshape(-1, 3)
            self._selected[name] = flat.take(self.index, axis=0).astype(np.float64)   # = float64(image)[mask]
        return self._selected[name]


def decomposition(mean, var, flicker, reference, ref_variance, mask, frames: int) -> dict:
    """{metric: (value, 95% interval half-width over pixels)} for DECOMPOSITION_METRICS (the
    module's docstring): K = `frames` frames' per-pixel mean, variance and flicker against
    `reference` of variance `ref_variance`, over the covered pixels of `mask`."""
    if int(frames) < 2:
        raise ValueError(f"the decomposition needs at least 2 frames, got {frames}")
    covered = _CoveredPixels(mask)
    arrays = (mean, var, flicker, reference, ref_variance)
    return _decomposition_of_covered(*(covered.get(str(i), a) for i, a in enumerate(arrays)), frames)


def _channel_mean(q: np.ndarray) -> np.ndarray:
    """q.mean(axis=1) of an Nx3 array, bit for bit (numpy sums the three channels in order, then divides)."""
    return (q[:, 0] + q[:, 1] + q[:, 2]) / 3


def _decomposition_of_covered(M, V, D, R, S, frames: int) -> dict:
    """`decomposition` of the covered pixels (Nx3 float64 each: frames' mean, variance, flicker, the
    reference and its variance)."""
    if int(frames) < 2:
        raise ValueError(f"the decomposition needs at least 2 frames, got {frames}")
    err2 = (M - R) ** 2
    per_channel = {"mse_accumulated": err2 - S, "variance": V, "bias2": err2 - V / frames - S, "flicker": D / 2}
    if len(R):
        weight = 1.0 / (R * R + metrics._relmse_epsilon(R))   # = relmse_epsilon(reference, mask)
        per_channel.update({f"rel_{name}": q * weight for name, q in list(per_channel.items())})
    out = {}
    for metric in DECOMPOSITION_METRICS:
        per_pixel = _channel_mean(per_channel[metric]) if metric in per_channel else np.empty(0)
        n = per_pixel.size
        value = float(per_pixel.mean()) if n else float("nan")
        ci = float(Z95 * per_pixel.std(ddof=1) / np.sqrt(n)) if n > 1 else float("nan")
        out[metric] = (value, ci)
    return out


def mean_ratio(image: np.ndarray, reference: np.ndarray, mask: np.ndarray, reference_mean: float | None = None) -> float:
    """Mean of `image` over mean of `reference` on the masked pixels; NaN when the reference is black.
    `reference_mean`: that mean of the reference, when already known (metrics.PreparedReference)."""
    if reference_mean is not None:
        ref_mean = reference_mean
    else:
        ref_mean = float(np.asarray(reference, dtype=np.float64)[mask].mean()) if mask.any() else 0.0
    if not ref_mean > 0.0:
        return float("nan")
    return float(np.asarray(image, dtype=np.float64)[mask].mean()) / ref_mean
