"""Content-addressed reference cache: `<cache>/references/<key[:2]>/<key>/`.

An entry holds the accumulated per-pixel moments of one reference (mean.exr, m2.exr = sum of
squared deviations, hits.exr = primary hits per pixel) and meta.json (the key's payload, the
sample count, the convergence curve, timings). The key hashes everything the image depends on:
scene content, camera, resolution, component, integrator settings, reference code version,
Mitsuba version and variant. It excludes the sample count and the error target, so a later
request for a lower noise floor continues from the stored sums instead of starting over.
Entries are written atomically (temporary folder + rename).
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

import numpy as np

from bench.imageio import read_exr, write_exr
from reference.render import Moments

SOURCES = ("convert.py", "integrators.py", "render.py")


def cache_root() -> Path:
    return Path(os.environ.get("GIBENCH_CACHE_DIR", Path.home() / ".cache" / "gibench")) / "references"


def code_version() -> str:
    """Hash of the sources that determine a reference image (edited code never reuses a cache)."""
    h = hashlib.sha256()
    here = Path(__file__).parent
    for name in SOURCES:
        h.update(name.encode())
        h.update((here / name).read_bytes())
    return h.hexdigest()[:16]


def cache_key(payload: dict) -> str:
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()[:32]


def entry_dir(key: str, root: Path | None = None) -> Path:
    return (root or cache_root()) / key[:2] / key


def load(key: str, root: Path | None = None):
    """(Moments, meta) of a stored entry, or None."""
    d = entry_dir(key, root)
    try:
        meta = json.loads((d / "meta.json").read_text())
        mean = read_exr(d / "mean.exr").astype(np.float64)
        m2 = read_exr(d / "m2.exr").astype(np.float64)
        hits = read_exr(d / "hits.exr")[..., 0].astype(np.float64)
    except (OSError, ValueError, KeyError, json.JSONDecodeError):
        return None
    if mean.shape != m2.shape or mean.shape[:2] != hits.shape or int(meta.get("spp", 0)) < 1:
        return None
    return Moments(int(meta["spp"]), mean, m2, hits), meta


def store(key: str, moments: Moments, meta: dict, root: Path | None = None) -> Path | None:
    """Write an entry atomically; returns its folder, or None if another process won a race
    for the same key (its entry is as good: same inputs) or the disk refused."""
    d = entry_dir(key, root)
    tmp = d.with_name(f"{d.name}.tmp{os.getpid()}")
    try:
        if tmp.exists():
            shutil.rmtree(tmp)
        tmp.mkdir(parents=True)
        write_exr(tmp / "mean.exr", moments.mean)
        write_exr(tmp / "m2.exr", moments.m2)
        write_exr(tmp / "hits.exr", moments.hits[..., None])
        (tmp / "meta.json").write_text(json.dumps(meta, indent=1, default=str))
        if d.exists():
            shutil.rmtree(d, ignore_errors=True)
        os.replace(tmp, d)
        return d
    except OSError:
        shutil.rmtree(tmp, ignore_errors=True)
        return None
