"""Between-method comparisons on time-vs-error curves: error at equal time, time at equal error.

Each method's rows on a view (its quality-ladder rungs, or any parameter sets) are points
(frame time t, error e). Its *curve* is their lower envelope: sorted by time, the points that
improve on every faster point (the best error the method reaches within a time budget, its
own Pareto front). Between envelope points the curve is interpolated linearly in log-log
(time and error of a quality knob follow power laws); it is not extended beyond its points:

* error of A at time t: NaN when t is below A's fastest point (A cannot run that fast), A's
  best error when t is beyond its slowest point (marked `capped`: A has no slower rung);
* time of A at error e: A's fastest time when e is at or above its fastest point's error
  (marked `capped`: A may reach it sooner), NaN when e is below A's best error (A never
  reaches it on its ladder).

The comparison anchors on each method B's *default* rung (t_B, e_B):

    error ratio(A vs B) = e_A(t_B) / e_B      (< 1: A is more accurate at B's time)
    time ratio(A vs B)  = t_A(e_B) / t_B      (< 1: A is faster at B's error)

Uncertainty: every time carries its run's inter-quartile range (frame_ms_iqr) and every
error an interval: an MSE the reference's noise floor (the measured MSE is the true MSE plus
the floor, so the true one lies in [max(e - floor, 0), e]); an error over frames (bias2,
variance, flicker, mse_accumulated and their relative forms: the reference noise is already
removed from them) its 95% interval over pixels, [e - ci, e + ci] from its `<metric>_ci` column;
other metrics none. The interval [lo, hi] of each ratio is the range over the corners of those
boxes (A's curve shifted by -/+ half its IQRs and to either end of its errors' intervals, B's
anchor likewise); a ratio whose interval contains 1 does not separate the two methods.

Any error column can be compared (`comparison_table(..., errors=...)`); the curves are drawn in
log-log, so points whose error is 0 or below (a deterministic method's variance, a bias2
estimate below 0) are not on them.
"""
from __future__ import annotations

import itertools
import math

import numpy as np
import pandas as pd

from bench.protocol.vocabulary import DECOMPOSITION_METRICS, REFERENCE_PARTS, interval_column

ERROR_COLUMNS = ("mse.combined", "mse.indirect")


def envelope(times, errors) -> tuple[np.ndarray, np.ndarray]:
    """(times, errors) of the lower envelope: sorted by time, strictly decreasing error."""
    t = np.asarray(times, dtype=np.float64)
    e = np.asarray(errors, dtype=np.float64)
    ok = np.isfinite(t) & np.isfinite(e) & (t > 0) & (e > 0)
    order = np.lexsort((e[ok], t[ok]))
    out_t, out_e = [], []
    for ti, ei in zip(t[ok][order], e[ok][order]):
        if not out_e or ei < out_e[-1]:
            out_t.append(ti)
            out_e.append(ei)
    return np.asarray(out_t), np.asarray(out_e)


def error_at_time(times, errors, t: float) -> tuple[float, bool]:
    """(error of the curve at time t, capped?) - see the module docstring."""
    ct, ce = envelope(times, errors)
    if ct.size == 0 or not (math.isfinite(t) and t > 0) or t < ct[0]:
        return float("nan"), False
    if t >= ct[-1]:
        return float(ce[-1]), t > ct[-1]
    return float(math.exp(np.interp(math.log(t), np.log(ct), np.log(ce)))), False


def time_at_error(times, errors, e: float) -> tuple[float, bool]:
    """(time the curve needs to reach error e, capped?) - see the module docstring."""
    ct, ce = envelope(times, errors)
    if ct.size == 0 or not (math.isfinite(e) and e > 0) or e < ce[-1]:
        return float("nan"), False
    if e >= ce[0]:
        return float(ct[0]), e > ce[0]
    # errors decrease along the curve: interpolate on the reversed (increasing) abscissae
    return float(math.exp(np.interp(math.log(e), np.log(ce[::-1]), np.log(ct[::-1])))), False


def _floor(rows: pd.DataFrame, error: str) -> np.ndarray:
    """The noise floor of an MSE column: the sum of its reference parts' floors (an MSE each); 0 for other errors."""
    metric, _, component = error.partition(".")
    total = np.zeros(len(rows))
    for part in REFERENCE_PARTS.get(component, ()) if metric == "mse" else ():
        col = f"reference_noise_floor.{part}"
        if col not in rows.columns:
            return np.zeros(len(rows))
        total += np.nan_to_num(pd.to_numeric(rows[col], errors="coerce").to_numpy(float), nan=0.0)
    return total


def _error_bounds(rows: pd.DataFrame, error: str, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) ends of each row's error: an MSE less its noise floor, an error over frames
    -/+ its interval over pixels (see the module docstring), the value itself otherwise."""
    metric, _, component = error.partition(".")
    if metric in DECOMPOSITION_METRICS:
        col = interval_column(metric, component)
        ci = (np.nan_to_num(np.abs(pd.to_numeric(rows[col], errors="coerce").to_numpy(float)), nan=0.0)
              if col in rows.columns else np.zeros(len(rows)))
        return np.maximum(e - ci, 1e-30), e + ci
    return np.maximum(e - _floor(rows, error), 1e-30), e


def _points(rows: pd.DataFrame, error: str) -> dict:
    t = pd.to_numeric(rows["frame_ms"], errors="coerce").to_numpy(float)
    iqr = (pd.to_numeric(rows["frame_ms_iqr"], errors="coerce").to_numpy(float) if "frame_ms_iqr" in rows.columns
           else np.zeros(len(rows)))
    iqr = np.nan_to_num(iqr, nan=0.0)
    e = pd.to_numeric(rows[error], errors="coerce").to_numpy(float)
    lo, hi = _error_bounds(rows, error, e)
    return {"t": t, "iqr": iqr, "e": e, "lo": lo, "hi": hi}


def _corners(p: dict):
    """The curve's variants at the corners of its uncertainty box: (times, errors) pairs."""
    for ts, end in itertools.product((-0.5, 0.0, 0.5), ("lo", "hi")):
        t = np.maximum(p["t"] + ts * p["iqr"], 1e-9)
        yield t, p[end]


def default_row(rows: pd.DataFrame) -> int:
    """Index (label) of a method's default rung among its rows: the row whose images sit in the
    folder named after the method (the runner's folder for default parameters), else the
    median-time row."""
    if "image_dir" in rows.columns:
        for i, d in rows["image_dir"].items():
            if isinstance(d, str) and d.rstrip("/").rsplit("/", 1)[-1] == str(rows.loc[i, "method"]):
                return i
    t = pd.to_numeric(rows["frame_ms"], errors="coerce")
    return (t - t.median()).abs().idxmin()


def compare_view(rows: pd.DataFrame, error: str) -> pd.DataFrame:
    """Long table for one view: every ordered pair (A, B) of methods with both ratios and intervals."""
    cols = ["method_a", "method_b", "kind", "ratio", "lo", "hi", "capped", "anchor_ms", "anchor_error"]
    if error not in rows.columns or rows.empty:
        return pd.DataFrame(columns=cols)
    rows = rows[np.isfinite(pd.to_numeric(rows[error], errors="coerce")) &
                np.isfinite(pd.to_numeric(rows["frame_ms"], errors="coerce"))]
    by_method = {m: g for m, g in rows.groupby("method", sort=False)}
    out = []
    for b, gb in by_method.items():
        ib = default_row(gb)
        anchor = _points(gb.loc[[ib]], error)
        tb, eb = float(anchor["t"][0]), float(anchor["e"][0])
        if not (tb > 0 and eb > 0):
            continue
        tb_range = (max(tb - 0.5 * anchor["iqr"][0], 1e-9), tb, tb + 0.5 * anchor["iqr"][0])
        eb_range = (float(anchor["lo"][0]), float(anchor["hi"][0]))
        for a, ga in by_method.items():
            if a == b:
                continue
            pa = _points(ga, error)
            e_at, capped_e = error_at_time(pa["t"], pa["e"], tb)
            t_at, capped_t = time_at_error(pa["t"], pa["e"], eb)
            e_ratios, t_ratios = [], []
            for ta, ea in _corners(pa):
                for t_anchor in tb_range:
                    for e_anchor in eb_range:
                        v, _ = error_at_time(ta, ea, t_anchor)
                        e_ratios.append(v / e_anchor)
                        w, _ = time_at_error(ta, ea, e_anchor)
                        t_ratios.append(w / t_anchor)
            for kind, value, ref, capped, spread in (("error_at_equal_time", e_at, eb, capped_e, e_ratios),
                                                     ("time_at_equal_error", t_at, tb, capped_t, t_ratios)):
                spread = np.asarray(spread, dtype=float)
                finite = spread[np.isfinite(spread)]
                out.append({"method_a": a, "method_b": b, "kind": kind, "ratio": value / ref,
                            "lo": float(finite.min()) if finite.size else float("nan"),
                            "hi": float(finite.max()) if finite.size else float("nan"),
                            "capped": bool(capped), "anchor_ms": tb, "anchor_error": eb})
    return pd.DataFrame(out, columns=cols)


def comparison_table(table: pd.DataFrame, errors: tuple = ERROR_COLUMNS) -> pd.DataFrame:
    """compare_view over every scene/view and error column of a results (or sweep) table."""
    parts = []
    if table.empty:
        return pd.DataFrame()
    for (scene, view), rows in table.groupby(["scene", "view"], sort=True):
        for error in errors:
            part = compare_view(rows, error)
            if len(part):
                part.insert(0, "error", error)
                part.insert(0, "view", view)
                part.insert(0, "scene", scene)
                parts.append(part)
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()
