"""Build the static HTML report of a run folder (works offline from file://).

Layout of the output folder (default `<run>/report/`):
  index.html            tables, plots, one comparison viewer per scene view
  assets/               viewer.js, report.css, colormap.js (copied from the package)
  data/view_<i>.js      linear images of one view as base64 float16 (identical images stored
                        once), loaded by <script src>
                        (browsers block fetch() of local files)
  plots/*.svg           matplotlib figures

The viewer tone-maps in JS (exposure in stops, sRGB), so the page keeps the linear data. Error
maps are |L_method - L_ref| of the luminance (or relative to L_ref + eps) on one scale per view
and component: the largest 99th percentile over the methods, so every map of that view shares
its colour bar. The report reads result files only; it never renders.
"""
from __future__ import annotations

import base64
import hashlib
import html
import json
import shutil
from importlib import resources
from pathlib import Path
from string import Template

import numpy as np
import pandas as pd

from bench.protocol import results as store
from bench.model.imageio import read_exr
from bench.analysis.curves import SPEEDUP_COMPONENTS, load_curves, pareto_table, sweep_table

from . import comparisons, plots

METRIC_NAMES = ("mse", "relmse", "smape", "dssim", "flip_mean", "flip_median", "ciede2000", "mean_ratio")
# mean_ratio (image mean / reference mean) is a bias figure: best is closest to 1, not lowest.
CLOSEST_TO_ONE = ("mean_ratio",)
EXTRA_METRIC_DOCS = {"mean_ratio": "image mean / reference mean on covered pixels: 1 is unbiased in the mean (best: closest to 1)"}
ERROR_COMPONENTS = ("indirect", "indirect_visible", "combined", "direct")
REFERENCE_COMPONENTS = ("direct", "indirect_unshadowed", "indirect_visible")
LUMINANCE = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
SHARED_STAGES = ("gbuffer_shadow", "direct_light", "rsm")
MISSING = "\u2014"


def esc(v) -> str:
    return html.escape(str(v), quote=True)


def fmt(v, digits: int = 3) -> str:
    """A number with `digits` significant digits; missing or non-finite values are an em dash."""
    if v is None:
        return MISSING
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return f"{int(v):,d}"
    try:
        f = float(v)
    except (TypeError, ValueError):
        return esc(v)
    if not np.isfinite(f):
        return MISSING
    if 10 ** digits <= abs(f) < 1e9:  # large times read better as 28,800 than 2.88e+04
        return f"{f:,.0f}"
    return f"{f:.{digits}g}"


def _cell(v, cls: str = "", digits: int = 3) -> str:
    text = fmt(v, digits)
    classes = " ".join(c for c in (cls, "missing" if text == MISSING else "") if c)
    return f"<td class='{classes}'>{text}</td>" if classes else f"<td>{text}</td>"


def _finite_min(values) -> float:
    a = np.asarray([v for v in values if v is not None], dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(a.min()) if a.size else float("nan")


# ---------------------------------------------------------------------------- image data
def _half_b64(img: np.ndarray) -> str:
    a = np.nan_to_num(np.asarray(img, dtype=np.float32)[..., :3], nan=0.0, posinf=65504.0, neginf=-65504.0)
    return base64.b64encode(np.clip(a, -65504.0, 65504.0).astype("<f2").tobytes()).decode("ascii")


def _luminance(img: np.ndarray) -> np.ndarray:
    return np.asarray(img, dtype=np.float32)[..., :3] @ LUMINANCE


def error_scales(reference: np.ndarray, images: list[np.ndarray]) -> tuple[dict, float]:
    """Shared scales ({"abs", "rel"}: the largest 99th percentile over the non-zero `images` of the
    luminance error over covered pixels) and the eps of the relative error (1% of the mean reference luminance)."""
    ref_l = _luminance(reference)
    covered_ref = np.abs(ref_l) > 0
    mean_ref = float(np.abs(ref_l[covered_ref]).mean()) if covered_ref.any() else 0.0
    eps = 0.01 * mean_ref if mean_ref > 0 else 1e-6
    abs_scale = rel_scale = 0.0
    # a method that outputs nothing for this component (e.g. `direct`'s indirect) would set the
    # scale to the reference itself and flatten every other map: it saturates instead
    nonzero = [img for img in images if np.any(np.asarray(img)[..., :3] != 0)]
    for img in nonzero or images:
        lum = _luminance(img)
        covered = covered_ref | (np.abs(lum) > 0)
        if not covered.any():
            continue
        err = np.abs(lum - ref_l)[covered]
        abs_scale = max(abs_scale, float(np.percentile(err, 99)))
        rel_scale = max(rel_scale, float(np.percentile(err / (np.abs(ref_l[covered]) + eps), 99)))
    return {"abs": abs_scale, "rel": rel_scale}, eps


def _auto_ev(img: np.ndarray) -> float:
    lum = _luminance(img)
    lum = lum[lum > 0]
    if lum.size == 0:
        return 0.0
    p = float(np.percentile(lum, 99.5))
    return float(np.clip(round(-np.log2(p) * 10) / 10, -10, 10)) if p > 0 else 0.0


def _read_image(path: Path, shape) -> np.ndarray | None:
    if not path.is_file():
        return None
    img = read_exr(path)[..., :3]
    if shape is not None and img.shape[:2] != tuple(shape):
        raise ValueError(f"{path}: image is {img.shape[1]}x{img.shape[0]}, the run's rows are {shape[1]}x{shape[0]}")
    return img


def view_data(run_dir: Path, rows: pd.DataFrame) -> dict:
    """The viewer's data of one scene view: reference and method images per component."""
    first = rows.iloc[0]
    shape = (int(first["height"]), int(first["width"]))
    ref_dir = run_dir / "references" / str(first["scene"]) / str(first["view"])
    refs = {c: _read_image(ref_dir / f"{c}.exr", shape) for c in REFERENCE_COMPONENTS}
    methods = []
    for i, rec in enumerate(rows.to_dict("records")):
        image_dir = run_dir / str(rec.get("image_dir", ""))
        imgs = {c: _read_image(image_dir / f"{c}.exr", shape) for c in ("direct", "indirect", "combined")}
        if any(v is not None for v in imgs.values()):
            methods.append((f"m{i}", rec["label"], imgs))
    ref_combined = (refs["direct"] + refs["indirect_visible"]
                    if refs["direct"] is not None and refs["indirect_visible"] is not None else None)
    component_refs = {
        "combined": [("ref", "Mitsuba reference", ref_combined)],
        "indirect": [("ref_unshadowed", "Mitsuba, no indirect visibility", refs["indirect_unshadowed"]),
                     ("ref_visible", "Mitsuba, with indirect visibility", refs["indirect_visible"])],
        "direct": [("ref", "Mitsuba reference", refs["direct"])],
    }
    labels = {"combined": "Combined", "indirect": "Indirect", "direct": "Direct"}
    blobs: dict[str, str] = {}

    def blob(img) -> str:
        """Identical images (every method's shared direct pass) are stored once."""
        data = _half_b64(img)
        key = hashlib.sha1(data.encode("ascii")).hexdigest()[:12]
        blobs.setdefault(key, data)
        return key

    components = {}
    for comp, ref_list in component_refs.items():
        sources = [{"id": rid, "label": label, "kind": "reference", "blob": blob(img)}
                   for rid, label, img in ref_list if img is not None]
        method_imgs = [(mid, label, imgs[comp]) for mid, label, imgs in methods if imgs.get(comp) is not None]
        sources += [{"id": mid, "label": label, "kind": "method", "blob": blob(img)}
                    for mid, label, img in method_imgs]
        if not sources:
            continue
        reference = next(((rid, img) for rid, _, img in ref_list if img is not None), None)
        entry = {"label": labels[comp], "sources": sources, "reference": None, "eps": 1e-6,
                 "scale": {"abs": 0.0, "rel": 0.0}}
        if reference is not None:
            scale, eps = error_scales(reference[1], [img for _, _, img in method_imgs])
            entry.update(reference=reference[0], eps=eps, scale=scale)
        components[comp] = entry
    exposure_source = ref_combined if ref_combined is not None else next(
        (imgs["combined"] for _, _, imgs in methods if imgs.get("combined") is not None), None)
    return {"scene": str(first["scene"]), "view": str(first["view"]), "width": shape[1], "height": shape[0],
            "auto_ev": _auto_ev(exposure_source) if exposure_source is not None else 0.0,
            "default_component": "combined", "components": components, "blobs": blobs}


# ---------------------------------------------------------------------------- tables
def _table(header: list[str], body_rows: list[str], left: int = 1, extra_class: str = "") -> str:
    ths = "".join(f"<th class='l'>{esc(h)}</th>" if i < left else f"<th>{esc(h)}</th>" for i, h in enumerate(header))
    return (f"<table class='data {extra_class}'><thead><tr>{ths}</tr></thead><tbody>"
            + "".join(body_rows) + "</tbody></table>")


def _metric_columns(table: pd.DataFrame) -> list[str]:
    cols = []
    for comp in ERROR_COMPONENTS:
        for metric in METRIC_NAMES:
            col = f"{metric}.{comp}"
            if col in table.columns and pd.to_numeric(table[col], errors="coerce").notna().any():
                cols.append(col)
    return cols


def overview_tables(table: pd.DataFrame, views: list[tuple[str, str]], facts: dict | None = None) -> tuple[str, list[str]]:
    """Method x scene table of time and error (one hidden table per metric, chosen by a select),
    scenes headed with their triangle count like the FLC paper's Table 2."""
    metric_cols = _metric_columns(table)
    labels = list(dict.fromkeys(table["label"]))
    lookup = {(r["label"], r["scene"], r["view"]): r for r in table.to_dict("records")}
    multi_view = len({s for s, _ in views}) < len(views)
    facts = facts or {}
    heads = []
    for s, v in views:
        tris = facts.get(s, {}).get("triangle_count")
        heads.append((f"{s}/{v}" if multi_view else s) + (f" ({fmt(tris)} tri.)" if tris is not None else ""))
    group = "<tr class='group'><th class='l'></th>" + "".join(f"<th colspan='2'>{esc(h)}</th>" for h in heads) + "</tr>"

    def one(metric: str | None) -> str:
        sub = "<tr><th class='l'>method</th>" + "".join(
            f"<th>ms</th><th>{esc(metric) if metric else 'error'}</th>" for _ in views) + "</tr>"
        best_t = {sv: _finite_min(lookup.get((l, *sv), {}).get("frame_ms") for l in labels) for sv in views}
        if metric and metric.split(".", 1)[0] in CLOSEST_TO_ONE:
            def badness(v):
                return abs(np.log(v)) if v is not None and np.isfinite(v) and v > 0 else None
        else:
            def badness(v):
                return v
        best_e = {sv: _finite_min(badness(lookup.get((l, *sv), {}).get(metric)) for l in labels) for sv in views} if metric else {}
        body = []
        for label in labels:
            cells = [f"<td class='l'>{esc(label)}</td>"]
            for sv in views:
                rec = lookup.get((label, *sv), {})
                t = rec.get("frame_ms")
                cells.append(_cell(t, "best" if t is not None and t == best_t[sv] else ""))
                e = rec.get(metric) if metric else None
                cells.append(_cell(e, "best" if metric and e is not None and badness(e) == best_e[sv] else ""))
            body.append("<tr>" + "".join(cells) + "</tr>")
        return f"<table class='data'><thead>{group}{sub}</thead><tbody>{''.join(body)}</tbody></table>"

    if not metric_cols:
        return one(None), []
    parts = [f"<div data-metric='{esc(m)}'>{one(m)}</div>" for m in metric_cols]
    return "<div id='overview-tables'>" + "".join(parts) + "</div>", metric_cols


def stage_order(rows: pd.DataFrame) -> list[str]:
    """Stages in execution order: the shared passes first, then each method's in first-seen order."""
    seen: list[str] = []
    for raw in rows.get("samples.stage_ms", pd.Series(dtype=object)):
        try:
            names = list(json.loads(raw)) if isinstance(raw, str) else []
        except json.JSONDecodeError:
            names = []
        seen += [n for n in names if n not in seen]
    seen += [c.split(".", 1)[1] for c in rows.columns if c.startswith("stage_ms.") and c.split(".", 1)[1] not in seen
             and pd.to_numeric(rows[c], errors="coerce").notna().any()]
    shared = [s for s in SHARED_STAGES if s in seen]
    return shared + [s for s in seen if s not in shared]


def stage_table(rows: pd.DataFrame, stages: list[str]) -> str:
    body = []
    for rec in rows.to_dict("records"):
        try:
            skipped = set(json.loads(rec.get("skipped_stages") or "[]"))
        except (TypeError, json.JSONDecodeError):
            skipped = set()
        cells = [f"<td class='l'>{esc(rec['label'])}</td>"]
        for s in stages:
            if s in skipped:
                cells.append("<td class='missing'>skipped</td>")
            else:
                cells.append(_cell(rec.get(f"stage_ms.{s}")))
        cells.append(_cell(rec.get("gpu_ms")))
        iqr = rec.get("frame_ms_iqr")
        cells.append(f"<td>{fmt(rec.get('frame_ms'))} <span class='note'>&plusmn;{fmt(iqr, 2)}</span></td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    return _table(["method"] + stages + ["GPU total", "frame (IQR)"], body)


def speedup_table(rows: pd.DataFrame) -> str:
    """Equal-error speed-up over the Mitsuba path tracer per component (extrapolated values marked)."""
    comps = [c for c in SPEEDUP_COMPONENTS if f"mse.{c}" in rows.columns
             and pd.to_numeric(rows[f"speedup.{c}"], errors="coerce").notna().any()]
    if not comps:
        return ""
    group = "<tr class='group'><th class='l'></th><th></th>" + "".join(
        f"<th colspan='3'>{esc(c)}</th>" for c in comps) + "</tr>"
    sub = "<tr><th class='l'>method</th><th>ms</th>" + "<th>MSE</th><th>Mitsuba ms</th><th>speed-up</th>" * len(comps) + "</tr>"
    body = []
    for rec in rows.to_dict("records"):
        cells = [f"<td class='l'>{esc(rec['label'])}</td>", _cell(rec.get("frame_ms"))]
        for c in comps:
            mark = "<sup class='x' title='extrapolated along MSE ~ 1/t'>*</sup>" if rec.get(f"speedup_extrapolated.{c}") else ""
            cells += [_cell(rec.get(f"mse.{c}")), _cell(rec.get(f"mitsuba_ms.{c}"))]
            text = fmt(rec.get(f"speedup.{c}"))
            if text != MISSING and rec.get(f"speedup_lower_bound.{c}"):
                text = f"<span title='error within twice the reference noise floor: a lower bound'>&ge;&thinsp;{text}</span>"
            cells.append(f"<td>{text}{mark if text != MISSING else ''}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    return f"<table class='data'><thead>{group}{sub}</thead><tbody>{''.join(body)}</tbody></table>"


def pareto_html(front: pd.DataFrame) -> str:
    if front.empty:
        return ""
    body = ["<tr>" + f"<td class='l'>{esc(r['label'])}</td>" + _cell(r["frame_ms"]) + _cell(r["mse.indirect"]) + "</tr>"
            for r in front.to_dict("records")]
    return "<p class='note'>Pareto front (time, MSE indirect) over all methods:</p>" + _table(["method", "ms", "MSE indirect"], body)


def scene_facts_table(manifest: dict) -> str:
    facts, purposes = manifest.get("scene_facts", {}), manifest.get("scene_purposes", {})
    if not facts:
        return "<p class='note'>No scene facts in the manifest.</p>"
    body = []
    for name, f in facts.items():
        body.append("<tr>" + f"<td class='l'>{esc(name)}</td>" + _cell(f.get("triangle_count")) + _cell(f.get("vertex_count"))
                    + _cell(f.get("total_area_m2")) + _cell(f.get("area_median_m2")) + _cell(f.get("scene_radius"))
                    + f"<td>{fmt(f.get('closed'))}</td>" + _cell(f.get("divergent_count"))
                    + f"<td class='wrap'>{esc(purposes.get(name, ''))}</td></tr>")
    return _table(["scene", "triangles", "vertices", "area m\u00b2", "median tri m\u00b2", "radius", "closed",
                   "divergent", "purpose"], body)


def noise_floor_table(table: pd.DataFrame) -> str:
    cols = [c for c in REFERENCE_COMPONENTS if f"reference_noise_floor.{c}" in table.columns]
    if not cols:
        return "<p class='note'>No Mitsuba references in this run (run without references, or Mitsuba unavailable): error columns show \u2014.</p>"
    body = []
    for (scene, view), g in table.groupby(["scene", "view"], sort=False):
        rec = g.iloc[0]
        cells = [f"<td class='l'>{esc(scene)}/{esc(view)}</td>"]
        for c in cols:
            cells += [_cell(rec.get(f"reference_noise_floor.{c}")), _cell(rec.get(f"reference_spp.{c}"), digits=6)]
        body.append("<tr>" + "".join(cells) + "</tr>")
    header = ["view"] + [h for c in cols for h in (f"noise floor MSE ({c})", "spp")]
    return (_table(header, body) + "<p class='note'>Noise floor: the MSE the reference itself carries (its variance "
            "image / spp, averaged over pixels); a method error near it is indistinguishable from the reference.</p>")


def metrics_html(metric_cols: list[str]) -> str:
    try:
        from bench.analysis.metrics import METRICS
    except ImportError:
        METRICS = {}
    used = sorted({c.split(".", 1)[0] for c in metric_cols})
    names = [m for m in METRIC_NAMES if m in METRICS or m in used]
    if not names:
        return ""
    items = "".join(f"<dt>{esc(m)}</dt><dd>{esc(METRICS.get(m, EXTRA_METRIC_DOCS.get(m, 'description unavailable')))}</dd>" for m in names)
    comps = ("Components: <b>indirect</b> = method indirect vs Mitsuba one-bounce without indirect visibility; "
             "<b>indirect_visible</b> = vs the bounce with visibility; <b>combined</b> = direct + indirect vs "
             "Mitsuba direct + indirect with visibility; <b>direct</b> = direct vs direct.")
    return f"<dl class='kv'>{items}</dl><p class='note'>{comps}</p>"


def run_info_html(manifest: dict, run_dir: Path) -> str:
    machine = manifest.get("machine", {})
    versions = manifest.get("versions", {})
    kv = lambda d: "<dl class='kv'>" + "".join(f"<dt>{esc(k)}</dt><dd>{esc(MISSING if v is None else v)}</dd>"
                                                for k, v in d.items()) + "</dl>"
    general = {"run folder": run_dir.resolve(), "created": manifest.get("created"),
               "git commit": manifest.get("git_commit"), "results schema": manifest.get("schema_version")}
    phases = manifest.get("phases_s") or {}
    timing = ""
    if phases:
        shown = {k: f"{float(v):.1f} s" for k, v in phases.items()}
        if manifest.get("harness_overhead") is not None:
            shown["harness overhead"] = f"{100 * float(manifest['harness_overhead']):.1f}% of the rendered rows' time"
        timing = "<h3>Wall time per phase</h3>" + kv(shown)
    return ("<div class='row'><div><h3>Run</h3>" + kv(general) + timing + "<h3>Machine</h3>" + kv(machine) + "</div>"
            "<div><h3>Versions</h3>" + kv(versions) + "</div></div><h3>Parameters</h3><pre class='args'>"
            + esc(json.dumps(manifest.get("arguments", {}), indent=2, default=str)) + "</pre>")


# ---------------------------------------------------------------------------- page
def _copy_assets(out_dir: Path) -> None:
    import matplotlib
    assets = out_dir / "assets"
    assets.mkdir(parents=True, exist_ok=True)
    static = resources.files(__package__) / "static"
    for name in ("viewer.js", "report.css"):
        (assets / name).write_text(static.joinpath(name).read_text(encoding="utf-8"), encoding="utf-8")
    lut = np.round(matplotlib.colormaps["inferno"](np.linspace(0, 1, 256))[:, :3] * 255).astype(int)
    (assets / "colormap.js").write_text("window.GIBENCH = window.GIBENCH || {};\nGIBENCH.colormap = "
                                        + json.dumps(lut.ravel().tolist(), separators=(",", ":")) + ";\n")


def build_report(run_dir, out_dir=None) -> Path:
    """Build the report of `run_dir` into `out_dir` (default `<run_dir>/report`); returns index.html."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError(f"run folder not found: {run_dir}")
    if (run_dir / STRESS_TABLE).is_file() and not (run_dir / "results.csv").is_file():
        return build_stress_report(run_dir, out_dir)  # a `gibench stress` folder
    df = store.load_results(run_dir)
    manifest_path = run_dir / "manifest.json"
    manifest = json.loads(manifest_path.read_text()) if manifest_path.is_file() else {}
    curves = load_curves(run_dir)
    out_dir = Path(out_dir) if out_dir is not None else run_dir / "report"
    for sub in ("data", "plots"):
        if (out_dir / sub).exists():
            shutil.rmtree(out_dir / sub)
    (out_dir / "data").mkdir(parents=True, exist_ok=True)
    _copy_assets(out_dir)

    keep = ("image_dir", "skipped_stages", "samples.stage_ms", "width", "height", "stage_ms.", "reference_")
    table = sweep_table(df, curves, keep=keep) if len(df) else pd.DataFrame(columns=["scene", "view", "label", "frame_ms"])
    views = list(dict.fromkeys(zip(table["scene"], table["view"]))) if len(table) else []
    fronts = pareto_table(table) if len(table) else pd.DataFrame()

    overview, metric_cols = overview_tables(table, views, manifest.get("scene_facts")) if views else ("<p class='note'>No rendered rows.</p>", [])
    default_metric = next((m for m in ("relmse.indirect", "mse.indirect", "mse.combined") if m in metric_cols),
                          metric_cols[0] if metric_cols else None)
    select = ""
    if metric_cols:
        opts = "".join(f"<option value='{esc(m)}'{' selected' if m == default_metric else ''}>{esc(m)}</option>"
                       for m in metric_cols)
        select = f"<p class='controls'><label>error metric <select class='metric-select' data-target='overview-tables'>{opts}</select></label></p>"
    parts = ["<h2 id='overview'>Time and error</h2>",
             "<p class='note'>Median frame time in ms (CPU wall clock around render + finish, warm-up frames "
             "discarded) and error against the Mitsuba reference; best per column highlighted; \u2014: not available.</p>",
             select, overview]
    bad = df[~df["status"].astype(str).str.startswith(("ok", "cached"))] if "status" in df.columns else df.iloc[0:0]
    if len(bad):
        rows = [f"<tr><td class='l'>{esc(r['scene'])}/{esc(r['view'])}</td><td class='l'>{esc(r['method'])}</td>"
                f"<td class='l status-bad'>{esc(r['status'])}</td></tr>" for r in bad.to_dict("records")]
        parts += ["<h3>Rows not rendered</h3>", _table(["view", "method", "status"], rows, left=3)]

    parts.append("<h2 id='scenes'>Scenes</h2>")
    scripts = []
    for i, (scene, view) in enumerate(views):
        rows = table[(table["scene"] == scene) & (table["view"] == view)]
        data = view_data(run_dir, rows)
        key = f"{scene}/{view}"
        (out_dir / "data" / f"view_{i}.js").write_text(
            "window.GIBENCH = window.GIBENCH || {}; GIBENCH.views = GIBENCH.views || {};\n"
            f"GIBENCH.views[{json.dumps(key)}] = {json.dumps(data, separators=(',', ':'))};\n")
        scripts.append(f"<script src='data/view_{i}.js'></script>")
        stages = stage_order(rows)
        block = [f"<section class='scene-block' id='view-{i}'><h3>{esc(scene)} / {esc(view)}</h3>"]
        purpose = manifest.get("scene_purposes", {}).get(scene)
        if purpose:
            block.append(f"<p class='note'>{esc(purpose)}</p>")
        block.append(f"<div class='row'><div class='viewer-col'><div class='viewer' data-view='{esc(key)}'></div>")
        block.append("<p class='note'>Wheel: zoom; drag: pan; double-click: reset. Error maps: luminance error "
                     "against the reference, one colour scale per view and component (the largest 99th percentile "
                     "over the methods).</p></div><div class='plots-col'>")
        plot = plots.time_error_plot(table, curves, scene, view, out_dir / "plots" / f"time_error_{i}.svg")
        if plot is not None:
            block.append(f"<img class='plot time-error' alt='time vs error, {esc(key)}' src='plots/{plot.name}'>")
        sp = plots.stage_plot(rows, stages, out_dir / "plots" / f"stages_{i}.svg", f"{key}: per-stage GPU time")
        if sp is not None:
            block.append(f"<img class='plot stages' alt='stage times, {esc(key)}' src='plots/{sp.name}'>")
        if len(fronts):
            block.append(pareto_html(fronts[(fronts["scene"] == scene) & (fronts["view"] == view)]))
        block.append("</div></div>")
        block.append("</section>")
        parts += block

    parts.append("<h2 id='timing'>Per-stage timing</h2><p class='note'>Median GPU time per stage (timer queries), "
                 "ms; shared passes first. GPU total is their sum; frame is the method's own CPU wall time per frame plus "
                 "the medians of the shared passes it needs, measured once per view.</p>")
    for scene, view in views:
        rows = table[(table["scene"] == scene) & (table["view"] == view)]
        parts += [f"<h3>{esc(scene)} / {esc(view)}</h3>", stage_table(rows, stage_order(rows))]

    parts.append("<h2 id='speedup'>Equal-error speed-up over Mitsuba</h2>")
    speed = [(sv, speedup_table(table[(table["scene"] == sv[0]) & (table["view"] == sv[1])])) for sv in views]
    speed = [(sv, t) for sv, t in speed if t]
    if speed:
        parts.append("<p class='note'>Time the Mitsuba path tracer needs to reach the method's MSE (log-log "
                     "interpolation of its convergence curve; <sup class='x'>*</sup> extrapolated along MSE ~ 1/t), "
                     "divided by the method's frame time; &ge;: the method's MSE is within twice the reference's noise floor, so the "
                     "speed-up is a lower bound.</p>")
        for (scene, view), t in speed:
            parts += [f"<h3>{esc(scene)} / {esc(view)}</h3>", t]
    else:
        parts.append("<p class='note'>No Mitsuba convergence curves or no error columns in this run: speed-ups unavailable.</p>")

    facts = manifest.get("scene_facts", {}) or {}
    fits = plots.scaling_fits(table, {k: v.get("triangle_count") for k, v in facts.items() if isinstance(v, dict)}) \
        if len(table) else {}
    if fits:
        sp = plots.scaling_plot(fits, out_dir / "plots" / "scaling.svg")
        body = ["<tr>" + f"<td class='l'>{esc(m)}</td>" + _cell(slope) + _cell(int(n.max())) + _cell(float(t.max()))
                + "</tr>" for m, (n, t, slope) in fits.items()]
        parts += ["<h2 id='scaling'>Cost vs triangles</h2>",
                  "<p class='note'>Frame time over the high-poly series (same room, terrain of 10k to 10M triangles), "
                  "log-log with the least-squares slope: 1 is linear in the triangle count, 0 independent of it.</p>",
                  f"<img class='plot' alt='cost vs triangles' src='plots/{sp.name}'>" if sp is not None else "",
                  _table(["method", "slope", "largest scene (tris)", "its frame ms"], body)]
    parts += ["<h2 id='between'>Between methods: equal time, equal error</h2>",
              comparisons.between_methods_html(table, run_dir, out_dir, fmt, esc, _table),
              "<h2 id='papers'>Paper reproduction</h2>",
              comparisons.reproduction_html(table, manifest, out_dir, fmt, esc, _table)]
    parts += ["<h2 id='scene-facts'>Scene facts</h2>", scene_facts_table(manifest),
              "<h2 id='references'>References</h2>", noise_floor_table(table)]
    metrics = metrics_html(metric_cols)
    if metrics:
        parts += ["<h2 id='metrics'>Metrics</h2>", metrics]
    parts += ["<h2 id='run'>Run</h2>", run_info_html(manifest, run_dir)]

    toc = "".join(f"<a href='#{a}'>{t}</a>" for a, t in (
        ("overview", "Time and error"), ("scenes", "Scenes"), ("timing", "Stages"), ("speedup", "Speed-up"),
        ("scaling", "Scaling"), ("between", "Between methods"), ("papers", "Papers"), ("scene-facts", "Scene facts"), ("references", "References"), ("metrics", "Metrics"), ("run", "Run"))
        if (metrics or a != "metrics") and (fits or a != "scaling"))
    machine = manifest.get("machine", {})
    n_ok = len(table)
    subtitle = (f"{n_ok} rendered rows, {len(views)} views, {len(set(table['method'])) if n_ok else 0} methods"
                f" &middot; {esc(machine.get('gl_renderer', '?'))} on {esc(machine.get('cpu', '?'))}"
                f" &middot; commit {esc(str(manifest.get('git_commit') or '?')[:12])}")
    template = Template((resources.files(__package__) / "templates" / "index.html").read_text(encoding="utf-8"))
    page = template.substitute(title=esc(f"gibench report: {run_dir.resolve().name}"), subtitle=subtitle, toc=toc,
                               body="\n".join(parts), data_scripts="\n".join(scripts))
    index = out_dir / "index.html"
    store.atomic_write_text(index, page)
    return index


# ---------------------------------------------------------------------------- stress page
STRESS_TABLE = "stress.csv"
_STRESS_VERDICT_TEXT = {"pass": "pass", "fail": "FAIL", "documented": "doc.", "skipped": "skip"}


def _stress_cell(rows: pd.DataFrame) -> str:
    """One matrix cell: the worst verdict of `rows` with its figures in the tooltip."""
    if rows.empty:
        return f"<td class='missing'>{MISSING}</td>"
    order = ["fail", "documented", "pass", "skipped"]
    verdicts = [v for v in order if v in set(rows["verdict"].astype(str))]
    worst = verdicts[0] if verdicts else "skipped"
    tips = []
    for r in rows.to_dict("records"):
        figures = ", ".join(f"{k} {fmt(r.get(k))}" for k in ("change", "change_indirect", "mean_change", "tolerance", "nan_pixels",
                                                              "inf_pixels", "negative_pixels", "error_change")
                            if fmt(r.get(k)) != MISSING)
        tips.append(f"{r['perturbation']}: {r['verdict']}; {figures}; {r.get('note') or ''}")
    change = rows["change"] if "change" in rows.columns else pd.Series(dtype=float)
    shown = pd.to_numeric(change, errors="coerce").max() if len(rows) == 1 else None
    text = _STRESS_VERDICT_TEXT.get(worst, worst)
    first_problem = str(rows["note"].iloc[0]).split(";")[0].strip() if len(rows) == 1 and "note" in rows else ""
    if worst in ("fail", "documented") and first_problem and " > " in first_problem:
        text += f" <span class='note'>{esc(first_problem)}</span>"  # the figure that failed, with its tolerance
    elif shown is not None and np.isfinite(shown):
        text += f" <span class='note'>{fmt(shown, 2)}</span>"
    if len(rows) > 1:
        counts = rows["verdict"].astype(str).value_counts()
        text += " <span class='note'>" + esc(", ".join(f"{n} {v}" for v, n in counts.items())) + "</span>"
    return f"<td class='v-{esc(worst)}' title='{esc(chr(10).join(tips))}'>{text}</td>"


def _stress_matrix(table: pd.DataFrame) -> str:
    parts = []
    scene_rows = table[(table["scene"] != "-") & table["target"].isin(["method", "reference"])]
    for scene, g in scene_rows.groupby("scene", sort=False):
        columns = [p for p in dict.fromkeys(g["perturbation"]) if not str(p).startswith("params:")]
        targets = list(dict.fromkeys(zip(g["target"], g["name"])))
        header = ["target"] + columns + ["parameter extremes"]
        body = []
        for target, name in targets:
            mine = g[(g["target"] == target) & (g["name"] == name)]
            label = name if target == "method" else f"reference: {name}"
            cells = [f"<td class='l'>{esc(label)}</td>"]
            cells += [_stress_cell(mine[mine["perturbation"] == p]) for p in columns]
            params = mine[mine["perturbation"].astype(str).str.startswith("params:")]
            cells.append(_stress_cell(params) if target == "method" else f"<td class='missing'>{MISSING}</td>")
            body.append("<tr>" + "".join(cells) + "</tr>")
        parts += [f"<h3>{esc(scene)} / {esc(g['view'].iloc[0])}</h3>", _table(header, body)]
    return "".join(parts) or "<p class='note'>No scene rows.</p>"


def _stress_rows(rows: pd.DataFrame, columns: list[str]) -> str:
    body = []
    for r in rows.to_dict("records"):
        cells = []
        for c in columns:
            v = r.get(c)
            if c == "verdict":
                cells.append(f"<td class='l v-{esc(v)}'>{esc(v)}</td>")
            elif c in ("scene", "perturbation", "target", "name", "status", "params"):
                cells.append(f"<td class='l'>{esc(v)}</td>")
            elif c in ("note", "criterion"):
                cells.append(f"<td class='wrap'>{esc('' if v is None or v != v else v)}</td>")
            else:
                cells.append(_cell(v))
        body.append("<tr>" + "".join(cells) + "</tr>")
    text = ("scene", "perturbation", "target", "name", "status", "params", "verdict", "note", "criterion")
    head = "".join(f"<th class='l'>{esc(c)}</th>" if c in text else f"<th>{esc(c)}</th>" for c in columns)
    return f"<table class='data'><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def build_stress_report(run_dir, out_dir=None) -> Path:
    """The page of a `gibench stress` folder (`stress.csv`, `stress.json`): `<out_dir or run_dir>/stress.html`."""
    run_dir = Path(run_dir)
    table = pd.read_csv(run_dir / STRESS_TABLE, keep_default_na=True)
    for col in ("note", "criterion", "status", "params"):
        if col in table.columns:
            table[col] = table[col].astype(object).where(table[col].notna(), "").astype(str)
    meta_path = run_dir / "stress.json"
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    out_dir = Path(out_dir) if out_dir is not None else run_dir
    assets = out_dir / "assets"
    assets.mkdir(parents=True, exist_ok=True)
    css = resources.files(__package__) / "static" / "report.css"
    (assets / "report.css").write_text(css.read_text(encoding="utf-8"), encoding="utf-8")

    counts = table["verdict"].astype(str).value_counts().to_dict() if len(table) else {}
    cfg = meta.get("config", {})
    subtitle = (", ".join(f"{counts.get(k, 0)} {k}" for k in ("pass", "fail", "documented", "skipped"))
                + f" &middot; {esc(', '.join(map(str, cfg.get('scenes', []))))} at {esc(cfg.get('width'))}x{esc(cfg.get('height'))}"
                + (" (quick)" if cfg.get("quick") else "")
                + f" &middot; references: {esc(meta.get('references', '?'))}"
                + f" &middot; commit {esc(str(meta.get('git_commit') or '?')[:12])}")
    bad = table[table["verdict"].isin(["fail", "documented"])]
    detail = ["scene", "perturbation", "target", "name", "params", "verdict", "nan_pixels", "inf_pixels",
              "negative_pixels", "change", "change_indirect", "mean_change", "tolerance", "error_base", "error",
              "error_change", "note"]
    detail = [c for c in detail if c in table.columns]
    other = table[table["scene"] == "-"]
    parts = ["<h2 id='matrix'>Verdicts per target and perturbation</h2>",
             "<p class='note'>Cell: the verdict (figure: relative L1 change of the combined image, or of the "
             "reference component, against the unperturbed case); hover for every figure. The last column sums a "
             "method's parameter extremes.</p>",
             _stress_matrix(table)]
    if len(other):
        parts += ["<h3>Scene model, scene reader</h3>", _stress_rows(other, ["perturbation", "target", "verdict",
                                                                           "criterion", "note"])]
    parts += ["<h2 id='failures'>Failures and documented limits</h2>",
              _stress_rows(bad, detail) if len(bad) else "<p class='note'>None.</p>",
              "<h2 id='table'>All rows</h2>", _stress_rows(table, detail + ["criterion"]),
              "<h2 id='criteria'>Criteria</h2>",
              "<p class='note'>Every image must be free of NaN, Inf and negative pixels. An invariance (scale with "
              "radiance-preserving intensities, translation, injected degenerate geometry, the same seed twice) "
              "must also keep the image: relative L1 change &le; the row's tolerance, "
              f"max({esc(meta.get('tolerance_floor'))}, {esc(meta.get('noise_factor'))} &times; the target's own noise) "
              "(a method's seed-to-seed change, a reference's expected difference from its variance images). Grazing "
              "views and lights and parameter extremes must run and stay finite and non-negative; their change and "
              "error figures are reported, not judged. error: relMSE of the combined image against Mitsuba "
              "(direct + indirect with visibility); error_change = error / error_base - 1. documented: the failure "
              "matches a <code>Stress limit PATTERN: reason</code> line of the target's manual.</p>",
              "<h2 id='run'>Run</h2><pre class='args'>" + esc(json.dumps(meta, indent=2, default=str)) + "</pre>"]
    template = Template((resources.files(__package__) / "templates" / "stress.html").read_text(encoding="utf-8"))
    page = template.substitute(title=esc(f"gibench stress: {run_dir.resolve().name}"), subtitle=subtitle,
                               body="\n".join(parts))
    path = out_dir / "stress.html"
    store.atomic_write_text(path, page)
    return path
