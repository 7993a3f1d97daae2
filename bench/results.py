"""The results store: one row per (scene, view, method, params, seed), saved as CSV and
Parquet, written atomically after every row so an interrupted run loses nothing.

Schema versions: SCHEMA_VERSION is stored in the manifest; `migrate` upgrades older tables.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pandas as pd

SCHEMA_VERSION = 1
KEY_COLUMNS = ("scene", "view", "method", "params", "seed")
BASE_COLUMNS = ("scene", "view", "method", "params", "seed", "width", "height", "frames", "warmup",
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
    os.replace(csv_tmp, run_dir / "results.csv")
    pq_tmp = run_dir / f".results.parquet.tmp{os.getpid()}"
    df.to_parquet(pq_tmp, index=False)
    os.replace(pq_tmp, run_dir / "results.parquet")
    return df


def load_results(run_dir: Path) -> pd.DataFrame:
    run_dir = Path(run_dir)
    pq, csv = run_dir / "results.parquet", run_dir / "results.csv"
    if pq.is_file():
        df = pd.read_parquet(pq)
    elif csv.is_file():
        df = pd.read_csv(csv)
    else:
        raise FileNotFoundError(f"no results.csv or results.parquet in {run_dir}")
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
