"""The gate's statistics: per-run times, the timing test (one-sided Welch t-test on log times)
and its multiple-testing correction, the error check and its absolute floors."""
from __future__ import annotations

import math
import re
import warnings

import numpy as np

from bench.gate.load import cell_float, cell_text, frame_samples, method_key
from bench.protocol.vocabulary import (DECOMPOSITION_COMPONENTS, DECOMPOSITION_METRICS, ERROR_COMPONENTS,
                                       REFERENCE_PARTS, Status, error_metric_names)

MIN_RUNS = 3
CORRECTIONS = ("holm", "bh")
# Absolute floors below which an error change is noise, not a regression: float32 images give
# metric noise well below these; each is far below any error a GI method actually makes. The
# error over frames has the floors of the metric it splits (radiance^2: mse's; relative: relmse's).
ERROR_ABS_FLOOR = {"mse": 1e-10, "relmse": 1e-8, "smape": 1e-6, "dssim": 1e-6, "flip_mean": 1e-6,
                   "flip_median": 1e-6, "ciede2000": 1e-4,
                   "mse_accumulated": 1e-10, "variance": 1e-10, "bias2": 1e-10, "flicker": 1e-10,
                   "rel_mse_accumulated": 1e-8, "rel_variance": 1e-8, "rel_bias2": 1e-8, "rel_flicker": 1e-8}
# The error over frames whose value does not depend on the reference (the spread of the method's
# own frames): compared even when the two sides' references differ in sample count.
REFERENCE_FREE_METRICS = ("variance", "flicker")
_ERROR_COLUMN = re.compile(r"^(%s)\.([A-Za-z0-9_]+)$" % "|".join(re.escape(m) for m in error_metric_names()))


def error_column_components(metric: str) -> tuple:
    """The components an error metric has columns for."""
    return DECOMPOSITION_COMPONENTS if metric in DECOMPOSITION_METRICS else ERROR_COMPONENTS


def check_error_column(name: str) -> str:
    """`name` if it names an error column (`<metric>.<component>`, bench.protocol.vocabulary:
    error_metric_names() and the metric's components), else ValueError (one line)."""
    metric, _, component = str(name).strip().partition(".")
    if metric not in error_metric_names():
        raise ValueError(f"unknown error column {name!r}: a column is <metric>.<component>, metric one of "
                         f"{', '.join(error_metric_names())}")
    if component not in error_column_components(metric):
        raise ValueError(f"unknown error column {name!r}: {metric} has the components "
                         f"{', '.join(error_column_components(metric))}")
    return f"{metric}.{component}"


# ---------------------------------------------------------------------------- timing
def run_median(rec: dict) -> float:
    """A run's number for a row: the median of its frame times (its frame_ms without samples)."""
    samples = frame_samples(rec)
    if samples:
        return float(np.median(samples))
    return cell_float(rec, "frame_ms")


def per_run_times(side: list, key: tuple, primary: dict, relative_to: str | None) -> list[float]:
    """One number per run of a side in which the row was rendered (not cached) and matches the
    primary run's row (method version, scene content, resolution, frames, warm-up, clock)."""
    out = []
    for idx, _ in side:
        rec = idx.get(key)
        if rec is None or Status.kind(rec.get("status")) not in Status.MEASURED:
            continue
        if any(cell_text(rec, col) != cell_text(primary, col) for col in
               ("method_version", "scene_hash", "width", "height", "frames", "warmup", "stage_clock")):
            continue
        t = run_median(rec)
        if relative_to is not None:
            ref = idx.get(method_key(key, relative_to))
            t = t / run_median(ref) if ref is not None else math.nan
        if math.isfinite(t) and t > 0:
            out.append(t)
    return out


def adjust_p_values(p_values, method: str = "holm") -> np.ndarray:
    """p-values adjusted over a family of tests: Holm's step-down (family-wise error) or
    Benjamini-Hochberg (false-discovery rate, scipy.stats.false_discovery_control)."""
    p = np.asarray(p_values, dtype=np.float64)
    if p.size == 0:
        return p
    if method == "bh":
        from scipy.stats import false_discovery_control  # scipy.stats is slow to import: only when needed
        return np.asarray(false_discovery_control(p, method="bh"), dtype=np.float64)
    if method != "holm":
        raise ValueError(f"correction must be one of {', '.join(CORRECTIONS)}, got {method!r}")
    order = np.argsort(p, kind="stable")
    m = p.size
    stepped = np.maximum.accumulate((m - np.arange(m)) * p[order])
    out = np.empty(m)
    out[order] = np.minimum(stepped, 1.0)
    return out


def timing_check(base: list[float], cand: list[float], threshold: float, alpha: float) -> dict:
    """One row's per-run times (one number per run and side): ratio of geometric means and
    one-sided Welch t-test p-values on their logarithms (unadjusted); verdict at `alpha`."""
    from scipy.stats import ttest_ind  # scipy.stats is slow to import: only when needed
    lb, lc = np.log(np.asarray(base, np.float64)), np.log(np.asarray(cand, np.float64))
    ratio = float(np.exp(lc.mean() - lb.mean()))
    if len(lb) < 2 or len(lc) < 2:
        p_slower = p_faster = 1.0
    else:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # identical runs: scipy warns about precision loss
            p_slower = float(ttest_ind(lc, lb, equal_var=False, alternative="greater").pvalue)
            p_faster = float(ttest_ind(lc, lb, equal_var=False, alternative="less").pvalue)
        if not math.isfinite(p_slower) or not math.isfinite(p_faster):  # zero spread on both sides
            same = np.isclose(lc.mean(), lb.mean(), rtol=0, atol=1e-12)
            p_slower = 1.0 if same or ratio < 1 else 0.0
            p_faster = 1.0 if same or ratio > 1 else 0.0
    verdict = None
    if ratio > 1 + threshold and p_slower < alpha:
        verdict = "regression"
    elif ratio < 1 / (1 + threshold) and p_faster < alpha:
        verdict = "improvement"
    return {"base": [float(v) for v in base], "cand": [float(v) for v in cand], "ratio": ratio,
            "p_slower": p_slower, "p_faster": p_faster, "verdict": verdict}


# ---------------------------------------------------------------------------- errors
def error_columns(columns) -> list[str]:
    """The `<metric>.<component>` error columns among `columns`, sorted."""
    return sorted(c for c in columns if _ERROR_COLUMN.match(str(c)))


def error_check(metric: str, base: float, cand: float, threshold: float, spread: float = 0.0) -> str | None:
    """The verdict on one error value: "regression", "improvement" or None (a change beyond the
    relative `threshold`, the metric's absolute floor and `spread`: for an error over frames, the
    95% interval of the difference, from the two values' intervals over pixels)."""
    floor = max(ERROR_ABS_FLOOR.get(metric, 0.0), spread if math.isfinite(spread) else 0.0)
    if cand - base > floor and (base <= 0 or (cand - base) / base > threshold):
        return "regression"
    if base - cand > floor and base > 0 and (base - cand) / base > threshold:
        return "improvement"
    return None


def noise_floor(rec: dict, component: str) -> float:
    """The summed noise floor (Var r) of the references a component was judged against (0 when unknown)."""
    total = 0.0
    for part in REFERENCE_PARTS.get(component, ()):
        v = cell_float(rec, f"reference_noise_floor.{part}")
        if not math.isfinite(v):
            return 0.0
        total += v
    return total
