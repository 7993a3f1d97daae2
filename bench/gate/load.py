"""The gate's input: run folders read as sides (one folder, or several repetitions), their rows
indexed by `row_identity`, and the cells of a row read in one form."""
from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np

from bench.protocol.results import ResultsError, load_results
from bench.protocol.vocabulary import Status, row_identity

TIMING_COLUMN = "samples.frame_ms"


# ---------------------------------------------------------------------------- run folders and sides
def side_paths(value) -> list[Path]:
    """The run folders of one side: a path, a comma-separated string of paths, or a list."""
    if isinstance(value, (str, Path)):
        parts = [p for p in str(value).split(",") if p.strip()] if isinstance(value, str) else [value]
        return [Path(p.strip()) if isinstance(p, str) else Path(p) for p in parts]
    return [Path(v) for v in value]


def load_run(path: Path, role: str):
    """(results table, manifest dict) of one run folder; `role` ("baseline"/"candidate") names it in errors."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{role} run folder not found: {path}")
    if not path.is_dir():
        raise FileNotFoundError(f"{role} is not a run folder: {path}")
    try:
        df = load_results(path)
    except FileNotFoundError:
        raise FileNotFoundError(f"{role} run folder {path} has no results.csv or results.parquet") from None
    except ResultsError as exc:
        raise ResultsError(f"{role}: {exc}") from None
    manifest = {}
    mpath = path / "manifest.json"
    if mpath.is_file():
        try:
            manifest = json.loads(mpath.read_bytes())
        except ValueError:
            raise ValueError(f"{role} manifest {mpath} is not valid JSON") from None
        if not isinstance(manifest, dict):
            raise ValueError(f"{role} manifest {mpath} is not a JSON object")
    missing = [c for c in ("scene", "view", "method", "params", "seed", "status") if c not in df.columns]
    if missing and len(df):
        raise ValueError(f"{role} results in {path} lack column(s) {', '.join(missing)}")
    return df, manifest


def run_fingerprint(path: Path, df, manifest: dict) -> str:
    """What tells one run from another by content, not by path: the run its manifest names (its
    run id, which a copied folder keeps; for an older gibench, its creation time; for a folder
    written by hand, the folder itself, links resolved) and its rows (a copy whose rows were
    edited is another run)."""
    if isinstance(manifest.get("run_id"), str) and manifest["run_id"]:
        origin = f"run id {manifest['run_id']}"
    elif manifest.get("created"):
        origin = f"created {manifest['created']}"
    else:
        origin = f"folder {Path(path).resolve()}"
    rows = hashlib.sha256(df.to_csv(index=False).encode()).hexdigest()[:12]
    return f"{origin}, rows {rows}"


def check_distinct_runs(role: str, paths: list, runs: list) -> None:
    """Repetitions must be distinct runs: one run listed twice (the same folder, a link or a copy)
    would count as independent evidence. ValueError (one line) naming both."""
    seen: dict = {}
    for path, (df, manifest) in zip(paths, runs):
        fingerprint = run_fingerprint(path, df, manifest)
        if fingerprint in seen:
            raise ValueError(f"the {role} lists one run twice: {seen[fingerprint]} and {path} are the same run "
                             f"({fingerprint}); repetitions must be distinct runs")
        seen[fingerprint] = path


# ---------------------------------------------------------------------------- row indexes
def row_label(rec: dict) -> str:
    """scene/view/method[@params-hash] (seed N when not 0)."""
    method = str(rec["method"])
    image_dir = rec.get("image_dir")
    if isinstance(image_dir, str) and image_dir:
        method = Path(image_dir).name
    label = f"{rec['scene']}/{rec['view']}/{method}"
    seed = row_identity(rec)[4]
    return label if seed == 0 else f"{label} (seed {seed})"


def index_rows(df, role: str, notes: list) -> dict:
    """row_identity -> row of one run's table (a run folder may hold several resolutions); a
    duplicate row is noted and the first kept."""
    out: dict = {}
    for rec in df.to_dict("records"):
        key = row_identity(rec)
        if key in out:
            notes.append(f"{role} has duplicate rows for {row_label(rec)}; the first is used")
            continue
        out[key] = rec
    return out


def method_key(key: tuple, method: str) -> tuple:
    """The relative_to lookup key of `method` on a row's scene/view/seed/resolution: params None,
    so that it never collides with a row's own key."""
    return (key[0], key[1], method, None) + tuple(key[4:])


def method_index(idx: dict) -> dict:
    """(scene, view, method, None, seed, width, height) -> first row of that method rendered in this
    run (the relative_to lookup: a cached yardstick would repeat another run's timing)."""
    out = {}
    for key, rec in idx.items():
        short = method_key(key, key[2])
        if short not in out and Status.kind(rec.get("status")) in Status.MEASURED:
            out[short] = rec
    return out


def without_method_index(idx: dict) -> dict:
    """An index without the relative_to lookup entries (params None)."""
    return {k: v for k, v in idx.items() if k[3] is not None}


# ---------------------------------------------------------------------------- cells
def status_text(rec: dict) -> str:
    """The status cell as text ("" when missing)."""
    s = rec.get("status")
    return "" if s is None or (isinstance(s, float) and math.isnan(s)) else str(s)


def frame_samples(rec: dict, column: str = TIMING_COLUMN) -> list[float]:
    """The finite per-frame times of a row (a JSON list in the results table)."""
    raw = rec.get(column)
    if isinstance(raw, str):
        try:
            vals = json.loads(raw)
        except json.JSONDecodeError:
            return []
    elif isinstance(raw, (list, tuple, np.ndarray)):
        vals = list(raw)
    else:
        return []
    out = [float(v) for v in vals if v is not None]
    return [v for v in out if math.isfinite(v)]


def cell_float(rec: dict, column: str) -> float:
    """A cell as a float (NaN when empty or not a number)."""
    v = rec.get(column)
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def cell_text(rec: dict, column: str) -> str | None:
    """A cell as text; numbers in one form (64, 64.0 and "64" are "64"); None when empty."""
    v = rec.get(column)
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return None
    if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool):
        f = float(v)
        return str(int(f)) if f.is_integer() else repr(f)
    return str(v)
