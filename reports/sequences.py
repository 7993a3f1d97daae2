"""The report's sequences (issue #25): per sequence and view, the error of each method over the
frames and its frame time over the frames (SVG plots, the frames that redid work marked), and a
filmstrip: each method's combined image beside the reference's, frame by frame, one slider.

Reads each sequence row's `frames.csv` and per-frame EXRs (bench.run.sequence_rows) and the
per-frame references of the run folder. Filmstrip frames are PNGs tone-mapped with one exposure
per sequence view (1 / P99 of the reference's maximum channel over all its frames, the metrics'
rule: bench.analysis.metrics.tonemap_scale), sRGB-encoded, so frames and methods compare on one
scale.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from bench.analysis.metrics import tonemap, tonemap_scale
from bench.model.imageio import read_exr

from .plots import save_svg

ERROR_COLUMN = "relmse.indirect"


def _png(path: Path, linear: np.ndarray, scale: float) -> str:
    import colour
    import OpenImageIO as oiio
    srgb = np.asarray(colour.cctf_encoding(tonemap(linear, scale), function="sRGB"), dtype=np.float64)
    pixels = np.ascontiguousarray(np.round(np.clip(srgb, 0, 1) * 255).astype(np.uint8))
    path.parent.mkdir(parents=True, exist_ok=True)
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(pixels.shape[1], pixels.shape[0], 3, "uint8"))
    out.write_image(pixels)
    out.close()
    return path.name


def _plot(per_method: dict, column: str, ylabel: str, title: str, path: Path, log: bool) -> Path | None:
    fig = Figure(figsize=(6.4, 3.0))
    ax = fig.add_subplot(1, 1, 1)
    drawn = False
    for method, frames in per_method.items():
        if column not in frames:
            continue
        y = frames[column].to_numpy(dtype=np.float64)
        line, = ax.plot(frames["t"], y, marker="o", ms=3, label=method, gid=f"seq-{column}-{method}")
        moved = frames["update_ms"].to_numpy(dtype=np.float64) > 0
        ax.plot(frames["t"][moved], y[moved], ls="none", marker="s", mfc="none", ms=7, color=line.get_color())
        drawn = True
    if not drawn:
        return None
    if log:
        ax.set_yscale("log")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("frame (squares: frames that redid work for the motion)")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    return save_svg(fig, path)


def sequence_blocks(run_dir: Path, out_dir: Path, results: pd.DataFrame) -> list:
    """The sequences section's blocks (plots and filmstrip frames written) from the run's results
    table, [] without sequence rows. A row is labelled by its image folder (`method` at the
    defaults, `method@hash` at another parameter set)."""
    if "sequence" not in results.columns or not len(results):
        return []
    rows = results[results["sequence"].notna() & (results["status"].astype(str) == "ok")]
    blocks = []
    for i, ((name, view), group) in enumerate(rows.groupby(["sequence", "view"], sort=False)):
        per_method = {}
        for _, row in group.iterrows():
            path = run_dir / str(row["image_dir"]) / "frames.csv"
            if path.is_file():
                per_method[Path(str(row["image_dir"])).name] = (pd.read_csv(path), row)
        if not per_method:
            continue
        frames = {m: f for m, (f, _) in per_method.items()}
        key = f"{name}/{view}"
        error = _plot(frames, ERROR_COLUMN, "relMSE, indirect", f"{key}: error over frames",
                      out_dir / "plots" / f"sequence_error_{i}.svg", log=True)
        timing = _plot(frames, "frame_ms", "frame time (ms)", f"{key}: frame time over frames",
                       out_dir / "plots" / f"sequence_time_{i}.svg", log=False)
        blocks.append({"index": i, "sequence": name, "view": view, "key": key,
                       "error_plot": error.name if error else None, "time_plot": timing.name if timing else None,
                       "film": _filmstrip(run_dir, out_dir / "data" / f"sequence_{i}", name, view, per_method),
                       "rows": [{"method": m, "frame_ms": r.get("frame_ms"), "frame_ms_worst": r.get("frame_ms_worst"),
                                 "update_ms": r.get("update_ms"), "mean": r.get(ERROR_COLUMN),
                                 "worst": r.get(f"worst.{ERROR_COLUMN}")} for m, (_, r) in per_method.items()]})
    return blocks


def _filmstrip(run_dir: Path, out: Path, name: str, view: str, per_method: dict) -> dict:
    """PNGs of every frame: the reference (direct + indirect_visible) and each method's combined."""
    # the sequence's own frames (settling frames, rendered only to measure a lag, keep no images)
    frames = max(int((f["settling"] == 0).sum()) if "settling" in f else len(f) for f, _ in per_method.values())
    ref_dir = run_dir / "references" / name / view
    refs = []
    for t in range(frames):
        direct, visible = ref_dir / f"frame_{t:03d}_direct.exr", ref_dir / f"frame_{t:03d}_indirect_visible.exr"
        refs.append(read_exr(direct) + read_exr(visible) if direct.is_file() and visible.is_file() else None)
    known = [r for r in refs if r is not None]
    scale = tonemap_scale(np.concatenate(known, axis=0)) if known else None
    strip = {"frames": frames, "reference": [], "methods": {}}
    for t, ref in enumerate(refs):
        strip["reference"].append(_png(out / f"reference_{t:03d}.png", ref, scale) if ref is not None else None)
    for method, (_, row) in per_method.items():
        images = []
        for t in range(frames):
            path = run_dir / str(row["image_dir"]) / f"frame_{t:03d}_combined.exr"
            if not path.is_file():
                images.append(None)
                continue
            image = read_exr(path)
            s = scale if scale is not None else tonemap_scale(image)
            images.append(_png(out / f"{method.replace('/', '_')}_{t:03d}.png", image, s))
        strip["methods"][method] = images
    strip["folder"] = f"data/{out.name}"
    return strip
