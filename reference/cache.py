"""Content-addressed reference cache: `<cache>/references/<key[:2]>/<key>/`.

An entry holds the accumulated per-pixel moments of one reference (mean.exr, m2.exr = sum of
squared deviations, hits.exr = primary hits per pixel) and meta.json (the key's payload, the
sample count, the convergence curve, timings). The key hashes everything the image depends on:
scene content, camera, resolution, component, integrator settings, reference code version,
Mitsuba version and variant. It excludes the sample count and the error target, so a later
request for a lower noise floor continues from the stored sums instead of starting over.
Entries are written atomically (temporary folder + rename).

Integrity: meta.json records the sha256 of each image (`files`). `load` verifies them; an
entry whose meta.json is unreadable, whose images do not match their checksums or cannot be
read, is a miss: it is evicted with a one-line warning and the reference is rendered again.
An entry written before checksums existed (no `files`) is checked for readability and shape,
then gets its checksums added (from then on a changed image is detected).
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np

from bench.model.imageio import read_exr, write_exr
from reference.render import Moments

SOURCES = ("convert.py", "integrators.py", "render.py")
IMAGES = ("mean.exr", "m2.exr", "hits.exr")


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


def _sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _evict(d: Path, problem: str) -> None:
    shutil.rmtree(d, ignore_errors=True)
    print(f"gibench: warning: reference cache entry {d} {problem}: evicted, the reference is rendered again",
          file=sys.stderr)


def peek_meta(key: str, root: Path | None = None) -> dict | None:
    """An entry's meta.json as stored (unverified: for plans, never for images), None without one."""
    try:
        meta = json.loads((entry_dir(key, root) / "meta.json").read_bytes())
    except (OSError, ValueError):
        return None
    return meta if isinstance(meta, dict) else None


def load(key: str, root: Path | None = None):
    """(Moments, meta) of a stored entry whose checksums hold, or None (a bad entry is evicted)."""
    d = entry_dir(key, root)
    if not d.is_dir():
        return None
    try:
        meta = json.loads((d / "meta.json").read_bytes())
    except (OSError, ValueError):
        _evict(d, "has an unreadable meta.json")
        return None
    if not isinstance(meta, dict):
        _evict(d, "has a malformed meta.json")
        return None
    files = meta.get("files")
    try:
        if files is not None:
            for name in IMAGES:
                if not isinstance(files, dict) or files.get(name) != _sha256(d / name):
                    _evict(d, f"has a damaged {name} (checksum mismatch)")
                    return None
        mean = read_exr(d / "mean.exr").astype(np.float64)
        m2 = read_exr(d / "m2.exr").astype(np.float64)
        hits = read_exr(d / "hits.exr")[..., 0].astype(np.float64)
        spp = int(meta.get("spp", 0))
    except (OSError, ValueError, TypeError) as exc:
        _evict(d, f"is unreadable ({' '.join(str(exc).split()) or type(exc).__name__})")
        return None
    if mean.shape != m2.shape or mean.shape[:2] != hits.shape or spp < 1:
        _evict(d, "has images of mismatched shapes or no samples")
        return None
    if files is None:  # written before checksums: readable and consistent, so record them now
        meta["files"] = {name: _sha256(d / name) for name in IMAGES}
        try:
            tmp = d / f".meta.json.tmp{os.getpid()}"
            tmp.write_text(json.dumps(meta, indent=1, default=str))
            os.replace(tmp, d / "meta.json")
        except OSError:
            pass
    return Moments(spp, mean, m2, hits), meta


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
        meta = dict(meta, files={name: _sha256(tmp / name) for name in IMAGES})
        (tmp / "meta.json").write_text(json.dumps(meta, indent=1, default=str))
        if d.exists():
            shutil.rmtree(d, ignore_errors=True)
        os.replace(tmp, d)
        return d
    except OSError:
        shutil.rmtree(tmp, ignore_errors=True)
        return None
