"""Time-vs-error curves of a run's rows: Pareto fronts, and the equal-error speed-up over the
Mitsuba path tracer (the sweep that renders the rows is bench.run.sweep).

Equal-error speed-up of a result row with error e (MSE against a reference component):

    speedup = T_mitsuba(e) / t_method

T_mitsuba(e) is read off the reference's convergence curve (`reference_curves.json`: points
of spp, seconds, mse_estimate): the curve is made monotone (the running minimum of the MSE
over time: the path tracer has reached e from the first time its estimate is <= e), then
log(seconds) is interpolated linearly in log(MSE). Outside the curve the time follows the
Monte Carlo rate MSE ~ 1/t from the nearest end point, and the value is marked extrapolated.
The measured MSE against a reference of N spp is the method's true MSE plus the reference's
noise floor; when it is within twice that floor the speed-up is marked a lower bound.
The `combined` component (direct + indirect_visible) has no curve of its own unless the
reference provides one; it is then the sum of the direct and indirect_visible curves (see
`combined_curve`: times add; independent estimates, so their MSEs add).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from bench.protocol import results as store
from bench.protocol.results import load_json_object, load_manifest
from bench.protocol.vocabulary import (CURVE_COMPONENTS, DECOMPOSITION_METRICS, INTERVAL_SUFFIX, REFERENCE_PARTS, Status,
                                       error_metric_names)

SPEEDUP_COMPONENTS = ("indirect", "indirect_visible", "combined")
PARETO_ERROR = "mse.indirect"
# the metrics whose columns a sweep table keeps: every error metric, and the 95% intervals over
# pixels of the error over frames (bias2, variance, flicker, mse_accumulated and their relative forms)
TABLE_ERROR_METRICS = error_metric_names() + tuple(m + INTERVAL_SUFFIX for m in DECOMPOSITION_METRICS)


# ---------------------------------------------------------------------------- Pareto front
def pareto_front(times, errors) -> np.ndarray:
    """Boolean mask of the non-dominated points minimising both time and error.

    A point is dominated when another is no worse in both and strictly better in one; points
    with a non-finite coordinate are never on the front; identical points are all kept.
    """
    t = np.asarray(times, dtype=np.float64).ravel()
    e = np.asarray(errors, dtype=np.float64).ravel()
    if t.shape != e.shape:
        raise ValueError(f"pareto_front: {t.size} times but {e.size} errors")
    ok = np.isfinite(t) & np.isfinite(e)
    tt, ee = t[ok], e[ok]
    no_worse = (tt[None, :] <= tt[:, None]) & (ee[None, :] <= ee[:, None])
    better = (tt[None, :] < tt[:, None]) | (ee[None, :] < ee[:, None])
    dominated = (no_worse & better).any(axis=1)
    mask = np.zeros(t.shape, dtype=bool)
    mask[np.flatnonzero(ok)] = ~dominated
    return mask


# ---------------------------------------------------------------------------- convergence curves
def _curve_arrays(curve) -> tuple[np.ndarray, np.ndarray]:
    """(seconds, mse) of a convergence curve, sorted by time, monotone, strictly decreasing MSE."""
    pts = []
    for i, p in enumerate(curve or []):
        try:
            s, m = float(p["seconds"]), float(p["mse_estimate"])
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"convergence curve point {i} lacks numeric 'seconds' and 'mse_estimate': {p!r}") from None
        if math.isfinite(s) and math.isfinite(m) and s > 0 and m > 0:
            pts.append((s, m))
    if not pts:
        return np.empty(0), np.empty(0)
    pts.sort()
    secs, mses = [], []
    for s, m in pts:
        if not mses or m < mses[-1]:  # the running minimum: keep only points that improve
            secs.append(s)
            mses.append(m)
    return np.asarray(secs), np.asarray(mses)


def mitsuba_seconds_for_error(curve, error: float) -> tuple[float, bool]:
    """(seconds the path tracer needs to reach MSE `error`, extrapolated?) from its convergence curve.

    Log-log interpolation inside the curve; beyond either end MSE ~ 1/t from the end point.
    NaN (and not extrapolated) for an empty curve or a non-positive / non-finite error.
    """
    secs, mses = _curve_arrays(curve)
    error = float(error)
    if secs.size == 0 or not math.isfinite(error) or error <= 0:
        return float("nan"), False
    if error > mses[0]:
        return float(secs[0] * mses[0] / error), True
    if error < mses[-1]:
        return float(secs[-1] * mses[-1] / error), True
    # np.interp needs increasing abscissae: MSE decreases along the curve, so reverse it.
    log_t = np.interp(math.log(error), np.log(mses[::-1]), np.log(secs[::-1]))
    return float(math.exp(log_t)), False


def combined_curve(curves: dict, scene_view: str):
    """The combined (direct + indirect_visible) convergence curve of `scene/view`, or None.

    At every spp n of either curve, each component contributes its point of the largest
    spp <= n (a component that stopped early, e.g. a noiseless direct reference, stays at its
    last point): times add, and so do the MSEs of the two independent estimates.
    """
    own = curves.get(f"{scene_view}/combined")
    if own:
        return own
    direct, visible = curves.get(f"{scene_view}/direct"), curves.get(f"{scene_view}/indirect_visible")
    if not direct or not visible:
        return None

    def by_spp(curve, name):
        try:
            return sorted((int(p["spp"]), float(p["seconds"]), float(p["mse_estimate"])) for p in curve)
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"convergence curve {scene_view}/{name}: every point needs numeric "
                             "'spp', 'seconds' and 'mse_estimate'") from None

    def at(points, n):
        below = [p for p in points if p[0] <= n]
        return below[-1] if below else None

    d, v = by_spp(direct, "direct"), by_spp(visible, "indirect_visible")
    out = []
    for n in sorted({p[0] for p in d} | {p[0] for p in v}):
        a, b = at(d, n), at(v, n)
        if a is not None and b is not None:
            out.append({"spp": n, "seconds": a[1] + b[1], "mse_estimate": a[2] + b[2]})
    return out or None


def curve_for(curves: dict, scene: str, view: str, component: str):
    """Convergence curve matching an error column component (see CURVE_COMPONENTS), or None."""
    key = f"{scene}/{view}"
    if component == "combined":
        return combined_curve(curves, key)
    return curves.get(f"{key}/{CURVE_COMPONENTS[component]}") or None


def load_curves(run_dir: Path) -> dict:
    return load_json_object(Path(run_dir) / "reference_curves.json",
                            "an object of 'scene/view/component' -> curve points")


# ---------------------------------------------------------------------------- tables
def declared_defaults(manifest: dict) -> dict[str, dict]:
    """{method: {parameter: default}} as each method declared it when the run ran (the manifest's
    `methods`); {} for a run that predates that record."""
    methods = manifest.get("methods") or {}
    return {name: dict(decl.get("defaults") or {}) for name, decl in methods.items() if isinstance(decl, dict)}


def variant_labels(df: pd.DataFrame, declared: dict[str, dict]) -> pd.Series:
    """A short label per row: the method name, plus the parameters that set the row apart.

    Among a method's rows, a parameter that varies has a base value: its default in `declared`
    ({method: {parameter: default}}, see declared_defaults: a quality ladder's rungs all differ,
    and the default names the default rung), else its most frequent value when it repeats (the
    default, in a one-knob-at-a-time sweep). A label names the parameters that differ from their
    base value; a single-knob grid without a declared default names the knob on every row.
    """
    labels = pd.Series(df["method"].astype(str).values, index=df.index)
    for method, group in df.groupby("method", sort=False):
        parsed = {i: json.loads(p) if isinstance(p, str) and p else {} for i, p in group["params"].items()}
        keys = sorted({k for d in parsed.values() for k in d})
        base = {}
        defaults = declared.get(str(method), {})
        for k in keys:
            counts = pd.Series([json.dumps(d.get(k), sort_keys=True) for d in parsed.values()]).value_counts()
            if len(counts) > 1:
                if k in defaults:
                    base[k] = json.dumps(defaults[k], sort_keys=True)
                else:
                    base[k] = counts.index[0] if counts.iloc[0] > 1 else None
        for i, d in parsed.items():
            named = [k for k in base if json.dumps(d.get(k), sort_keys=True) != base[k]]
            if named:
                labels[i] = method + " " + ",".join(f"{k}={d.get(k)}" for k in named)
    return labels


def ok_rows(df: pd.DataFrame) -> pd.DataFrame:
    """The rows that have images and measurements (rendered in the run or taken from the row cache)."""
    if "status" not in df.columns:
        return df.copy()
    return df[df["status"].map(Status.has_images)].copy()


def sweep_table(df: pd.DataFrame, curves: dict, declared: dict[str, dict], keep: tuple = ()) -> pd.DataFrame:
    """Rows that rendered, labelled (see variant_labels: `declared` are the run's declared defaults),
    with their error columns (the error over frames and its intervals too, when the rows have them),
    Mitsuba's equal-error time and the speed-up (plus the columns whose names start with one of `keep`)."""
    rows = ok_rows(df)
    rows["label"] = variant_labels(rows, declared) if len(rows) else pd.Series(dtype=str)
    error_cols = sorted(c for c in rows.columns if c.split(".", 1)[0] in TABLE_ERROR_METRICS)
    base = [c for c in ("scene", "view", "method", "label", "params", "frame_ms", "frame_ms_iqr", "gpu_ms")
            if c in rows.columns]
    kept = [c for c in rows.columns if c.startswith(tuple(keep)) and c not in base and c not in error_cols]
    out = rows[base + error_cols + kept].reset_index(drop=True)
    for comp in SPEEDUP_COMPONENTS:
        col = f"mse.{comp}"
        secs, extrap = [], []
        for rec in out.to_dict("records"):
            curve = curve_for(curves, rec["scene"], rec["view"], comp) if col in out.columns else None
            s, x = mitsuba_seconds_for_error(curve, rec.get(col, float("nan"))) if curve else (float("nan"), False)
            secs.append(s)
            extrap.append(x)
        out[f"mitsuba_ms.{comp}"] = np.asarray(secs) * 1000.0
        out[f"speedup.{comp}"] = out[f"mitsuba_ms.{comp}"] / out["frame_ms"] if "frame_ms" in out else np.nan
        out[f"speedup_extrapolated.{comp}"] = extrap
        floor = _noise_floor(rows, comp)
        # error within twice the reference's own noise: the measured MSE is mostly reference noise,
        # the method may be better than measured, so the speed-up is a lower bound
        out[f"speedup_lower_bound.{comp}"] = (out[col] <= 2.0 * floor).to_numpy() if col in out.columns else False
    return out


def _noise_floor(rows: pd.DataFrame, comp: str) -> np.ndarray:
    """Noise floor MSE of the reference(s) an error column is measured against (NaN when unknown)."""
    total = np.zeros(len(rows))
    for part in REFERENCE_PARTS[comp]:
        col = f"reference_noise_floor.{part}"
        if col not in rows.columns:
            return np.full(len(rows), np.nan)
        total = total + pd.to_numeric(rows[col], errors="coerce").to_numpy(float)
    return total


def pareto_table(table: pd.DataFrame, error: str = PARETO_ERROR) -> pd.DataFrame:
    """Per scene/view, the non-dominated (frame_ms, error) rows over all methods, sorted by time."""
    cols = ["scene", "view", "method", "label", "params", "frame_ms", error]
    if error not in table.columns or table.empty:
        return pd.DataFrame(columns=cols)
    parts = []
    for _, group in table.groupby(["scene", "view"], sort=True):
        mask = pareto_front(group["frame_ms"].to_numpy(float), group[error].to_numpy(float))
        parts.append(group[mask][cols].sort_values("frame_ms"))
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=cols)


def write_sweep(run_dir: Path) -> tuple[Path, Path]:
    """Write `sweep.csv` and `pareto.csv` of a run folder (labels from its manifest); returns their paths."""
    run_dir = Path(run_dir)
    table = sweep_table(store.load_results(run_dir), load_curves(run_dir), declared_defaults(load_manifest(run_dir)))
    sweep_path, pareto_path = run_dir / "sweep.csv", run_dir / "pareto.csv"
    store.atomic_write_text(sweep_path, table.to_csv(index=False))
    store.atomic_write_text(pareto_path, pareto_table(table).to_csv(index=False))
    return sweep_path, pareto_path
