"""Report figures (matplotlib, SVG): time-vs-error on log-log axes with the Pareto front and
Mitsuba's convergence curve, and the per-stage timing breakdown. Figures are built on
`matplotlib.figure.Figure` (no pyplot global state) and written without a date, with a fixed
SVG id salt, so the same results give the same files."""
from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from bench.analysis.compare import default_row
from bench.analysis.curves import curve_for, mitsuba_seconds_for_error, pareto_front

ERROR_PANELS = (("mse.indirect", "indirect (vs Mitsuba, no indirect visibility)"),
                ("mse.combined", "combined (vs Mitsuba direct + indirect)"))


def _save(fig, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    with matplotlib.rc_context({"svg.hashsalt": "gibench", "svg.fonttype": "path"}):
        fig.savefig(path, format="svg", metadata={"Date": None})
    return path


def _finite(values) -> np.ndarray:
    a = np.asarray(values, dtype=np.float64)
    return np.isfinite(a) & (a > 0)


def time_error_plot(table: pd.DataFrame, curves: dict, scene: str, view: str, path: Path) -> Path | None:
    """Log-log frame time vs MSE of every method variant of one view; None when no error exists."""
    rows = table[(table["scene"] == scene) & (table["view"] == view)]
    panels = [(col, title) for col, title in ERROR_PANELS
              if col in rows.columns and _finite(rows[col]).any() and _finite(rows["frame_ms"]).any()]
    if not panels:
        return None
    fig = Figure(figsize=(3.4 * len(panels), 3.5), layout="constrained")
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    methods = list(dict.fromkeys(rows["method"]))
    colors = {m: f"C{i % 10}" for i, m in enumerate(methods)}
    markers = "osD^v<>ph*"
    for ax, (col, title) in zip(axes, panels):
        comp = col.split(".", 1)[1]
        ok = rows[_finite(rows[col]) & _finite(rows["frame_ms"])]
        for i, m in enumerate(methods):
            pts = ok[ok["method"] == m].sort_values("frame_ms")
            if pts.empty:
                continue
            ax.plot(pts["frame_ms"], pts[col], marker=markers[i % len(markers)], ms=5, lw=1.2,
                    color=colors[m], label=m)
        front = ok[pareto_front(ok["frame_ms"], ok[col])].sort_values("frame_ms")
        if len(front):
            ax.step(front["frame_ms"], front[col], where="post", color="k", lw=1.0, ls="--", alpha=0.8,
                    label="Pareto front")
            ax.scatter(front["frame_ms"], front[col], s=70, facecolors="none", edgecolors="k", lw=1.0, zorder=3)
        curve = curve_for(curves, scene, view, comp)
        if curve:
            pts = sorted((float(p["seconds"]) * 1e3, float(p["mse_estimate"])) for p in curve
                         if float(p["seconds"]) > 0 and float(p["mse_estimate"]) > 0)
            if pts:
                t, e = zip(*pts)
                ax.plot(t, e, color="0.45", lw=1.5, marker=".", label="Mitsuba path tracer")
                # equal error: from each method point to the time Mitsuba needs for the same MSE
                for j, rec in enumerate(ok.to_dict("records")):
                    s, extrapolated = mitsuba_seconds_for_error(curve, rec[col])
                    if np.isfinite(s):
                        ax.plot([rec["frame_ms"], s * 1e3], [rec[col], rec[col]], color=colors[rec["method"]],
                                lw=0.8, ls=":" if extrapolated else "-", alpha=0.7)
                        ax.plot([s * 1e3], [rec[col]], marker="x", ms=5, color="0.35", ls="none",
                                label="Mitsuba at equal error" if j == 0 else None)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("time (ms)", fontsize=8)
        ax.set_ylabel(f"MSE, {comp}", fontsize=8)
        ax.set_title(title, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
    handles = {}
    for ax in axes:
        for h, label in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(label, h)
    fig.legend(handles.values(), handles.keys(), loc="outside lower center", ncols=min(4, len(handles)),
               fontsize=7, frameon=False)
    fig.suptitle(f"{scene} / {view}: time vs error", fontsize=10)
    return _save(fig, path)


def stage_plot(rows: pd.DataFrame, stages: list[str], path: Path, title: str) -> Path | None:
    """Horizontal stacked bars of the median GPU time of each stage, one bar per method variant."""
    if rows.empty or not stages:
        return None
    labels = list(rows["label"])
    fig = Figure(figsize=(6.4, 1.5 + 0.32 * len(labels)), layout="constrained")
    ax = fig.subplots()
    left = np.zeros(len(labels))
    y = np.arange(len(labels))
    for i, stage in enumerate(stages):
        col = f"stage_ms.{stage}"
        vals = rows[col].to_numpy(float) if col in rows.columns else np.zeros(len(labels))
        vals = np.where(np.isfinite(vals), vals, 0.0)
        if not vals.any():
            continue
        ax.barh(y, vals, left=left, color=f"C{i % 10}", label=stage, height=0.6)
        left += vals
    if "frame_ms" in rows.columns:
        ax.scatter(rows["frame_ms"].to_numpy(float), y, marker="|", s=160, color="k", label="frame (CPU wall)", zorder=3)
    ax.set_yticks(y, labels, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("median time per frame (ms)")
    fig.suptitle(title, fontsize=10)
    ax.grid(True, axis="x", lw=0.3, alpha=0.5)
    fig.legend(loc="outside lower center", ncols=4, fontsize=7, frameon=False)
    return _save(fig, path)


def scaling_fits(table: pd.DataFrame, triangles: dict, series_prefix: str = "highpoly_") -> dict:
    """method -> (triangle counts, median frame ms, fitted log-log slope or NaN) over the high-poly
    series (each method's default rung; the mean over a scene's views)."""
    rows = table[table["scene"].astype(str).str.startswith(series_prefix)]
    out = {}
    for method, g in rows.groupby("method", sort=True):
        pts = []
        for scene, gs in g.groupby("scene"):
            n = triangles.get(scene)
            t = [float(gv.loc[default_row(gv), "frame_ms"]) for _, gv in gs.groupby("view")]
            if n and np.isfinite(t).all():
                pts.append((float(n), float(np.mean(t))))
        pts.sort()
        if not pts:
            continue
        n, t = (np.asarray(v) for v in zip(*pts))
        ok = (n > 0) & (t > 0)
        slope = float(np.polyfit(np.log(n[ok]), np.log(t[ok]), 1)[0]) if ok.sum() >= 2 else float("nan")
        out[method] = (n, t, slope)
    return out


def scaling_plot(fits: dict, path: Path) -> Path | None:
    """Log-log frame time vs triangle count per method, with the fitted slope in the legend."""
    if not fits:
        return None
    fig = Figure(figsize=(5.2, 3.6), layout="constrained")
    ax = fig.subplots()
    for i, (method, (n, t, slope)) in enumerate(fits.items()):
        label = f"{method} (slope {slope:.2f})" if np.isfinite(slope) else method
        ax.plot(n, t, marker="osD^v<>ph*"[i % 10], ms=5, lw=1.2, color=f"C{i % 10}", label=label)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("triangles", fontsize=8)
    ax.set_ylabel("frame time (ms)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    ax.legend(fontsize=7, frameon=False)
    fig.suptitle("cost vs triangles (high-poly series, default parameters)", fontsize=10)
    return _save(fig, path)
