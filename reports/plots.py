"""Report figures (matplotlib, SVG): time-vs-error on log-log axes with the Pareto front and
Mitsuba's convergence curve (each method's single-frame curve, solid, beside its accumulated
curve, dashed in the same colour, when the rows have the error over frames), each view's
bias/variance split, and the per-stage timing breakdown. Figures are built on
`matplotlib.figure.Figure` (no pyplot global state) and written without a date, with a fixed
SVG id salt, so the same results give the same files. The curves and bars carry SVG ids
(`single-<component>-<method>`, `accumulated-<component>-<method>`, `bias2-<method>`,
`variance-<method>`) that the browser test finds."""
from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from bench.analysis.compare import default_row
from bench.analysis.curves import curve_for, mitsuba_seconds_for_error, pareto_front

ERROR_PANELS = (("mse.indirect", "indirect (vs Mitsuba, no indirect visibility)"),
                ("mse.combined", "combined (vs Mitsuba direct + indirect)"))
ACCUMULATED = "mse_accumulated"   # the accumulated curve beside each panel's single-frame MSE
BIAS_COLOR, VARIANCE_COLOR = "#c44e52", "#4c72b0"


def save_svg(fig, path: Path) -> Path:
    """Write a figure as a reproducible SVG (no date, fixed id salt)."""
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
        acc_col = f"{ACCUMULATED}.{comp}"
        for i, m in enumerate(methods):
            pts = ok[ok["method"] == m].sort_values("frame_ms")
            if pts.empty:
                continue
            ax.plot(pts["frame_ms"], pts[col], marker=markers[i % len(markers)], ms=5, lw=1.2,
                    color=colors[m], label=m, gid=f"single-{comp}-{m}")
            acc = rows[rows["method"] == m]
            if acc_col in acc.columns:
                acc = acc[_finite(acc[acc_col]) & _finite(acc["frame_ms"])].sort_values("frame_ms")
                if len(acc):
                    ax.plot(acc["frame_ms"], acc[acc_col], marker=markers[i % len(markers)], ms=4, lw=1.0, ls="--",
                            mfc="none", color=colors[m], gid=f"accumulated-{comp}-{m}")
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
    if any(f"{ACCUMULATED}.{col.split('.', 1)[1]}" in rows.columns
           and _finite(rows[f"{ACCUMULATED}.{col.split('.', 1)[1]}"]).any() for col, _ in panels):
        handles[f"dashed: mean of {_frames_text(rows)} (accumulated)"] = Line2D([], [], color="0.3", lw=1.0, ls="--",
                                                                               marker="o", mfc="none", ms=4)
    fig.legend(handles.values(), handles.keys(), loc="outside lower center", ncols=min(4, len(handles)),
               fontsize=7, frameon=False)
    fig.suptitle(f"{scene} / {view}: time vs error", fontsize=10)
    return save_svg(fig, path)


def _frames_text(rows: pd.DataFrame) -> str:
    """"8 frames" when the rows share one error-frame count, else "the error frames"."""
    k = pd.to_numeric(rows.get("extra.error_frames", pd.Series(dtype=float)), errors="coerce").dropna().unique()
    return f"{int(k[0])} frames" if len(k) == 1 else "the error frames"


def bias_variance_plot(split: list[dict], path: Path, title: str) -> Path | None:
    """Horizontal stacked bars of one view's split (reports.tables.bias_variance: per method,
    rel_bias2 then rel_variance, each with its 95% interval over pixels), a tick at the method's
    single-frame relmse; None without a split."""
    if not split:
        return None
    labels = [e["label"] for e in split]
    fig = Figure(figsize=(6.4, 1.4 + 0.34 * len(labels)), layout="constrained")
    ax = fig.subplots()
    y = np.arange(len(labels))
    bias = np.array([max(e["rel_bias2"], 0.0) for e in split])
    var = np.array([max(e["rel_variance"], 0.0) for e in split])
    bars_b = ax.barh(y, bias, color=BIAS_COLOR, height=0.6, label="rel. bias² (accumulation cannot remove)")
    bars_v = ax.barh(y, var, left=bias, color=VARIANCE_COLOR, height=0.6,
                     label="rel. variance (a temporal filter or denoiser removes)")
    for e, bar_b, bar_v in zip(split, bars_b, bars_v):
        bar_b.set_gid(f"bias2-{e['method']}")
        bar_v.set_gid(f"variance-{e['method']}")
    ci_b = np.array([e["rel_bias2_ci"] or 0.0 for e in split])
    ci_v = np.array([e["rel_variance_ci"] or 0.0 for e in split])
    ax.errorbar(bias, y - 0.12, xerr=ci_b, fmt="none", ecolor="k", elinewidth=0.8, capsize=2)
    ax.errorbar(bias + var, y + 0.12, xerr=ci_v, fmt="none", ecolor="k", elinewidth=0.8, capsize=2,
                label="95% interval over pixels")
    relmse = np.array([np.nan if e["relmse"] is None else e["relmse"] for e in split])
    if np.isfinite(relmse).any():
        ax.scatter(relmse, y, marker="|", s=220, color="k", zorder=3, label="relmse of one frame")
    for yi, total, right, e in zip(y, bias + var, np.fmax(bias + var + ci_v, relmse), split):
        share = e["bias_share"]
        if share is not None:  # beside the bar's interval and tick, not over them
            ax.annotate(f" {total:.3g} ({100 * share:.0f}% bias)", (right, yi), va="center", fontsize=7)
    ax.set_yticks(y, labels, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlim(0, max(float(np.nanmax(np.concatenate([bias + var + ci_v, relmse]))), 1e-12) * 1.35)
    ax.set_xlabel("relative error (per pixel, as relmse), indirect component", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(True, axis="x", lw=0.3, alpha=0.5)
    fig.suptitle(title, fontsize=10)
    fig.legend(loc="outside lower center", ncols=2, fontsize=7, frameon=False)
    return save_svg(fig, path)


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
    return save_svg(fig, path)


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
    return save_svg(fig, path)
