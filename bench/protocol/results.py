"""The results store: one row per (scene, view, method, params, seed), saved as CSV and
Parquet, written atomically after every row so an interrupted run loses nothing.

Schema versions: SCHEMA_VERSION is stored in the manifest; `migrate` upgrades older tables.

Cells: `load_results` refuses a table (ResultsError, one line naming the file, row and column)
that lacks a row-identity column or holds a cell that is not a number in a numeric column (a
hand-edited CSV): every reader (report, gate, a resumed run) then sees numbers where numbers belong.

Whether a run finished (`run_progress`): `run_state.json`, written by the runner
(bench.run.plan.RunState), is the one record of it; report and gate both read it here.

Integrity: `results.checksums.json` holds the sha256 and row count of both files, written after
them. `load_results` uses a file only when it is consistent: with checksums, the file whose
checksum holds (parquet first; the CSV when only it holds; an error when neither does); without
them (tables written by hand or by an older gibench), a CSV that does not end with a newline is
cut mid-line (error), and a parquet and a CSV that disagree on their rows are an error.
"""
from __future__ import annotations

import fcntl
import hashlib
import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from bench.protocol.vocabulary import DECOMPOSITION_METRICS, INTERVAL_SUFFIX, METRIC_NAMES, Status

SCHEMA_VERSION = 1
KEY_COLUMNS = ("scene", "view", "method", "params", "seed")
CHECKSUMS = "results.checksums.json"
MANIFEST = "manifest.json"
RUN_STATE = "run_state.json"   # the invocation, whether it finished, the rows it planned and recorded
RUN_LOCK = ".gibench-run.lock"  # flock'ed by the run writing the folder (bench.run.plan.RunFolderLock)
IDENTITY_COLUMNS = ("scene", "view", "method", "params", "seed", "status")
IMAGE_ROW_COLUMNS = ("width", "height", "image_dir")   # what a row with images (ok, cached) needs besides
NUMERIC_COLUMNS = ("seed", "width", "height", "frames", "warmup", "frame_ms", "frame_ms_iqr", "gpu_ms", "prepare_ms",
                   "frames_total_ms", "row_wall_ms", "harness_overhead", "peak_rss_mb", "timing_lock_wait_ms",
                   "error_frames_ms", "extra.error_frames")
NUMERIC_PREFIXES = (("stage_ms.", "reference_spp.", "reference_noise_floor.") + tuple(f"{m}." for m in METRIC_NAMES)
                    + tuple(f"{m}{suffix}." for m in DECOMPOSITION_METRICS for suffix in ("", INTERVAL_SUFFIX)))
JSON_COLUMNS = {"params": dict, "samples.frame_ms": list, "samples.stage_ms": dict}   # cells of JSON text
BASE_COLUMNS = ("scene", "scene_hash", "view", "method", "params", "seed", "width", "height", "frames", "warmup",
                "frame_ms", "frame_ms_iqr", "gpu_ms", "status", "method_version", "row_key",
                "skipped_stages", "samples.frame_ms", "samples.stage_ms")


def params_json(params: dict) -> str:
    return json.dumps(params, sort_keys=True, separators=(",", ":"))


def atomic_write_text(path: Path, text: str) -> None:
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(text)
    os.replace(tmp, path)


def order_columns(df: pd.DataFrame) -> pd.DataFrame:
    first = [c for c in BASE_COLUMNS if c in df.columns]
    stages = sorted(c for c in df.columns if c.startswith("stage_ms."))
    rest = sorted(c for c in df.columns if c not in first and c not in stages)
    return df[first + stages + rest]


def save_results(run_dir: Path, rows: list[dict]) -> pd.DataFrame:
    run_dir = Path(run_dir)
    df = order_columns(pd.DataFrame(rows)) if rows else pd.DataFrame(columns=list(BASE_COLUMNS))
    csv_tmp = run_dir / f".results.csv.tmp{os.getpid()}"
    df.to_csv(csv_tmp, index=False)
    pq_tmp = run_dir / f".results.parquet.tmp{os.getpid()}"
    df.to_parquet(pq_tmp, index=False)
    sums = {"rows": int(len(df)), "results.csv": _sha256(csv_tmp), "results.parquet": _sha256(pq_tmp)}
    os.replace(csv_tmp, run_dir / "results.csv")
    os.replace(pq_tmp, run_dir / "results.parquet")
    atomic_write_text(run_dir / CHECKSUMS, json.dumps(sums, indent=1))
    return df


def _sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


class ResultsError(ValueError):
    """A results table that cannot be trusted (one line naming the file)."""


def _read_csv(csv: Path) -> pd.DataFrame:
    data = csv.read_bytes()
    if data and not data.endswith(b"\n"):
        raise ResultsError(f"{csv} is cut mid-line (no newline at its end): the table is incomplete")
    try:
        return pd.read_csv(csv)
    except (ValueError, pd.errors.ParserError) as exc:
        raise ResultsError(f"{csv} is not a readable CSV table ({' '.join(str(exc).split())})") from None


def _read_parquet(pq: Path) -> pd.DataFrame:
    try:
        return pd.read_parquet(pq)
    except Exception as exc:  # pyarrow raises several types for a damaged file
        raise ResultsError(f"{pq} is not a readable parquet table ({type(exc).__name__})") from None


def _same_rows(a: pd.DataFrame, b: pd.DataFrame) -> bool:
    if len(a) != len(b) or set(a.columns) != set(b.columns):
        return False
    for col in [c for c in ("scene", "view", "method", "status", "row_key") if c in a.columns]:
        if list(a[col].astype(str)) != list(b[col].astype(str)):
            return False
    return True


def _load_table(run_dir: Path) -> tuple[pd.DataFrame, Path]:
    pq, csv = run_dir / "results.parquet", run_dir / "results.csv"
    if not pq.is_file() and not csv.is_file():
        raise FileNotFoundError(f"no results.csv or results.parquet in {run_dir}")
    sums = None
    if (run_dir / CHECKSUMS).is_file():
        try:
            sums = json.loads((run_dir / CHECKSUMS).read_bytes())
        except (OSError, ValueError):
            sums = None
    if isinstance(sums, dict):
        good = [p for p in (pq, csv) if p.is_file() and sums.get(p.name) == _sha256(p)]
        if good:
            if len(good) == 1 and (pq.is_file() and csv.is_file()):
                print(f"gibench: warning: {run_dir}: {({pq, csv} - set(good)).pop().name} does not match its "
                      f"checksum; using {good[0].name}", file=sys.stderr)
            return (_read_parquet(good[0]) if good[0] == pq else _read_csv(good[0])), good[0]
        raise ResultsError(f"{run_dir}: neither results.parquet nor results.csv matches {CHECKSUMS} "
                           f"(edited or damaged); delete {CHECKSUMS} to accept the files as they are")
    if pq.is_file() and csv.is_file():
        a, b = _read_parquet(pq), _read_csv(csv)
        if not _same_rows(a, b):
            raise ResultsError(f"{run_dir}: results.parquet ({len(a)} rows) and results.csv ({len(b)} rows) "
                               f"disagree; delete the wrong one")
        return a, pq
    return (_read_parquet(pq), pq) if pq.is_file() else (_read_csv(csv), csv)


def numeric_column(name: str) -> bool:
    """Whether the results schema holds numbers in column `name`."""
    return name in NUMERIC_COLUMNS or name.startswith(NUMERIC_PREFIXES)


def _json_cell(text, kind: type) -> bool:
    try:
        return isinstance(json.loads(text), kind)
    except (TypeError, ValueError):
        return False


def _check_cells(df: pd.DataFrame, source: Path) -> pd.DataFrame:
    """The table with its numeric columns as numbers; a missing identity column, a cell that is not
    a number or a JSON cell that does not parse is a ResultsError naming the file, the row (as a
    spreadsheet numbers it) and the column."""
    missing = [c for c in IDENTITY_COLUMNS if c not in df.columns]
    if missing and len(df):
        raise ResultsError(f"{source} lacks column(s) {', '.join(missing)}: not a gibench results table")
    missing = [c for c in IMAGE_ROW_COLUMNS if c not in df.columns]
    if missing and "status" in df.columns and df["status"].map(Status.has_images).any():
        raise ResultsError(f"{source} lacks column(s) {', '.join(missing)}, which its rendered rows need: "
                           f"the table was edited or damaged")
    for col in [c for c in df.columns if numeric_column(str(c))]:
        if pd.api.types.is_numeric_dtype(df[col]) and not pd.api.types.is_bool_dtype(df[col]):
            continue
        values = pd.to_numeric(df[col], errors="coerce")
        bad = df[col].notna() & values.isna()
        if bad.any():
            first = int(np.flatnonzero(bad.to_numpy())[0])
            raise ResultsError(f"{source}: column {col} holds {df[col].iloc[first]!r} in row {first + 2} "
                               f"({int(bad.sum())} cell(s) in all), not a number: the table was edited or damaged")
        df[col] = values
    for col, kind in JSON_COLUMNS.items():
        if col not in df.columns:
            continue
        for i, cell in enumerate(df[col]):
            if not (cell is None or (isinstance(cell, float) and np.isnan(cell)) or _json_cell(cell, kind)):
                raise ResultsError(f"{source}: column {col} holds {cell!r} in row {i + 2}, not a JSON "
                                   f"{'object' if kind is dict else 'list'}: the table was edited or damaged")
    return df


def load_results(run_dir: Path) -> pd.DataFrame:
    run_dir = Path(run_dir)
    df, source = _load_table(run_dir)
    df = _check_cells(df, source)
    manifest = run_dir / "manifest.json"
    version = json.loads(manifest.read_text()).get("schema_version", 1) if manifest.is_file() else 1
    return migrate(df, version)


def migrate(df: pd.DataFrame, version: int) -> pd.DataFrame:
    """Upgrade a results table from `version` to SCHEMA_VERSION."""
    if version > SCHEMA_VERSION:
        raise ValueError(f"results schema {version} is newer than this gibench ({SCHEMA_VERSION})")
    return df


def summarize_samples(samples: list[float]) -> tuple[float, float]:
    if not samples:
        return float("nan"), float("nan")
    a = np.asarray(samples, dtype=np.float64)
    q1, med, q3 = np.percentile(a, [25, 50, 75])
    return float(med), float(q3 - q1)


def median_ci(samples, confidence: float = 0.95) -> tuple[float, float]:
    """Distribution-free confidence interval of the median (order statistics, normal
    approximation of the binomial): (low, high); NaNs when there are too few samples (n < 6)."""
    a = np.sort(np.asarray(samples, dtype=np.float64))
    n = a.size
    if n < 6:
        return float("nan"), float("nan")
    from scipy.stats import norm
    z = float(norm.ppf(0.5 + confidence / 2))
    j = int(np.floor(n / 2 - z * np.sqrt(n) / 2))
    k = int(np.ceil(n / 2 + 1 + z * np.sqrt(n) / 2))
    return float(a[max(j - 1, 0)]), float(a[min(k - 1, n - 1)])


def timing_settled(samples, min_frames: int, elapsed_s: float, budget_s: float, max_frames: int,
                   rel_halfwidth: float) -> bool:
    """Stop timing (the way pytest-benchmark calibrates rounds): never before `min_frames`;
    then when the time budget is spent, `max_frames` is reached, or the median's 95% interval
    is within +-rel_halfwidth of the median."""
    n = len(samples)
    if n < min_frames:
        return False
    if elapsed_s >= budget_s or n >= max_frames:
        return True
    lo, hi = median_ci(samples)
    med = float(np.median(samples))
    return bool(np.isfinite(lo) and med > 0 and (hi - lo) / (2 * med) <= rel_halfwidth)


def load_json_object(path: Path, expected: str) -> dict:
    """A run folder's JSON object file ({} when absent); a one-line error names a bad file."""
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected {expected}")
    return data


def load_manifest(run_dir: Path) -> dict:
    """The run folder's manifest.json ({} when absent)."""
    return load_json_object(Path(run_dir) / MANIFEST, "an object")


# ---------------------------------------------------------------------------- a finished run
@dataclass(frozen=True)
class RunProgress:
    """Whether a run folder's last invocation finished (`run_state.json`, the one record of it).

    `finished` is None for a folder without a run state (written by hand or by a gibench from
    before run states), which readers take as it is; `running` says a gibench run holds the
    folder now (its lock): such a folder is unfinished whatever its state says; `recorded` of
    `planned` rows were recorded when the state was read."""
    finished: bool | None
    planned: int | None = None
    recorded: int | None = None
    running: bool = False
    problem: str | None = None      # why the state could not be read

    @property
    def complete(self) -> bool:
        return self.finished is not False

    def describe(self) -> str:
        """"incomplete: 9 of 20 rows (still running)", "" for a complete run."""
        if self.complete:
            return ""
        if self.problem:
            return f"incomplete: {self.problem}"
        counts = (f"{self.recorded} of {self.planned} rows" if self.planned is not None
                  else f"{self.recorded} rows recorded")   # a state from before `planned` was recorded
        why = ("still running" if self.running
               else "interrupted or failed: re-run the same command to finish it")
        return f"incomplete: {counts} ({why})"


def run_progress(run_dir: Path) -> RunProgress:
    """The run folder's RunProgress, read from `run_state.json` (and its lock, for `running`)."""
    path = Path(run_dir) / RUN_STATE
    running = run_folder_locked(run_dir)
    if not path.is_file():
        return RunProgress(finished=False, running=True, problem="a gibench run is starting in it") if running \
            else RunProgress(finished=None)
    try:
        state = json.loads(path.read_bytes())
    except (OSError, ValueError):
        state = None
    if not isinstance(state, dict) or not isinstance(state.get("finished"), bool):
        return RunProgress(finished=False, running=running,
                           problem=f"{path} is unreadable: whether the run finished is unknown")
    if running and state["finished"]:   # the state of the previous invocation, before this one's start
        return RunProgress(finished=False, running=True, problem="a gibench run is writing it now")
    planned, recorded = state.get("planned"), state.get("recorded")
    return RunProgress(finished=state["finished"], planned=planned if isinstance(planned, int) else None,
                       recorded=recorded if isinstance(recorded, int) else len(state.get("done") or []),
                       running=running)


def run_folder_locked(run_dir: Path) -> bool:
    """Whether a gibench run holds the folder's lock now (a shared, non-blocking probe, released at
    once: the writer's exclusive lock excludes it; a writer starting meanwhile retries)."""
    try:
        fd = os.open(Path(run_dir) / RUN_LOCK, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:
        return False
    finally:
        os.close(fd)   # closing drops the probe's lock
    return False
