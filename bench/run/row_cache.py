"""The row cache: a rendered row's measurements and images, content-addressed by everything
that decides them, so an unchanged row is never rendered twice.

The key (`row_cache_key`) covers the scene's content and the camera, the method's name and
version (a hash of the code its images depend on: bench.protocol.versioning), its resolved
parameters, the resolution, frames, warm-up, error frames, seed, shadow-map size, timing
budget, the GL renderer, the stage clock and the timing harness's version. An entry
(`<cache>/rows/<ab>/<key>/`) holds `row.json` = {"format", "row", "row_sha256", "files": {name:
sha256}} and the row's EXRs (with more than one error frame, the frame statistics' EXRs too:
`row_image_names`); a hit takes the measured values from the entry and every label from the
current run. An entry that fails its checks (a checksum, a missing image, another error-frame
count than the run's) is a miss, evicted with a one-line warning.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

import numpy as np

from bench.protocol.versioning import harness_version
from bench.protocol.vocabulary import FRAME_STAT_IMAGES, IMAGE_COMPONENTS
from bench.run.config import RunConfig, cache_root, effective_shadow_resolution

ROW_CACHE_FORMAT = 2


def json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    return str(o)


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def row_image_names(error_frames) -> tuple:
    """The images (file stems) a row holds: its components, and the frame statistics when it
    rendered more than one error frame."""
    return IMAGE_COMPONENTS + (FRAME_STAT_IMAGES if _frames(error_frames) > 1 else ())


def _frames(value) -> int:
    try:
        return int(value)
    except (TypeError, ValueError):
        return 1


def row_sha256(row: dict) -> str:
    return hashlib.sha256(json.dumps(row, sort_keys=True, default=json_default).encode()).hexdigest()


def row_cache_key(scene, camera: str, method: str, version: str, params: dict, cfg: RunConfig, renderer: str,
                  stage_clock: str = "") -> str:
    payload = {"scene": scene.content_hash(), "camera": camera, "camera_def": scene.cameras[camera].to_dict(),
               "method": method, "method_version": version, "params": params, "width": cfg.width,
               "height": cfg.height, "frames": cfg.frames, "warmup": cfg.warmup, "seed": cfg.seed,
               "error_frames": int(cfg.error_frames),
               "shadow_resolution": effective_shadow_resolution(cfg), "renderer": renderer, "stage_clock": stage_clock,
               "harness": harness_version()}
    if cfg.timing_budget_s is not None:
        payload["timing_budget_s"] = cfg.timing_budget_s
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()[:24]


def entry_problem(d: Path, error_frames: int = 1, files: list | None = None) -> str | None:
    """Why a row cache entry cannot be trusted (one phrase), or None when every checksum holds and
    it holds the images of a row of `error_frames` error frames (or, given, exactly `files`: a
    sequence row's frames)."""
    try:
        entry = json.loads((d / "row.json").read_bytes())
    except FileNotFoundError:
        return "has no row.json"
    except (OSError, ValueError):
        return "has an unreadable row.json (not JSON)"
    if not isinstance(entry, dict) or entry.get("format") != ROW_CACHE_FORMAT:
        return "has no checksums (damaged, or written by an older gibench)"
    row, files = entry.get("row"), entry.get("files")
    if not isinstance(row, dict) or not isinstance(files, dict) or not isinstance(entry.get("row_sha256"), str):
        return "has a malformed row.json"
    if row_sha256(row) != entry["row_sha256"]:
        return "has a row.json whose checksum does not match"
    if not all(isinstance(row.get(k), str) for k in ("scene", "method", "status")):
        return "has a row without scene, method or status"
    if files is None:
        held = _frames(row.get("extra.error_frames", 1))
        if held != _frames(error_frames):
            return f"holds {held} error frame(s), the run asks for {error_frames}"
    for name in files if files is not None else (f"{c}.exr" for c in row_image_names(error_frames)):
        try:
            ok = files.get(name) == file_sha256(d / name)
        except OSError:
            return f"lacks {name}"
        if not ok:
            return f"has a damaged {name} (checksum mismatch)"
    return None


class RowCache:
    """Lookup and store of cache entries under `root` (default: cache_root() / "rows")."""

    def __init__(self, log=print, root: Path | None = None):
        self.log = log
        self.root = Path(root) if root is not None else cache_root() / "rows"

    def entry_dir(self, key: str) -> Path:
        return self.root / key[:2] / key

    def lookup(self, key: str, error_frames: int = 1, files: list | None = None):
        """(row, entry folder) of a verified cache entry, or None; a bad entry is evicted with a warning."""
        d = self.entry_dir(key)
        if not d.is_dir():
            return None
        problem = entry_problem(d, error_frames, files)
        if problem is None:
            entry = json.loads((d / "row.json").read_bytes())
            return dict(entry["row"]), d
        shutil.rmtree(d, ignore_errors=True)
        self.log(f"gibench: warning: row cache entry {d} {problem}: evicted, the row is rendered again")
        return None

    def restore(self, key: str, image_dir: Path, error_frames: int = 1, files: list | None = None):
        """A verified entry's row, its images (or `files`) copied into `image_dir`; None on a miss."""
        hit = self.lookup(key, error_frames, files)
        if hit is None:
            return None
        row, entry_dir = hit
        image_dir.mkdir(parents=True, exist_ok=True)
        for name in files if files is not None else [f"{c}.exr" for c in row_image_names(error_frames)]:
            shutil.copyfile(entry_dir / name, image_dir / name)
        return row

    def store(self, key: str, row: dict, image_dir: Path, files: list | None = None) -> None:
        d = self.entry_dir(key)
        tmp = d.with_name(d.name + f".tmp{os.getpid()}")
        try:
            if tmp.exists():
                shutil.rmtree(tmp)
            tmp.mkdir(parents=True)
            names = files if files is not None else \
                [f"{c}.exr" for c in row_image_names(row.get("extra.error_frames", 1))]
            files = {}
            for name in names:
                shutil.copyfile(image_dir / name, tmp / name)
                files[name] = file_sha256(tmp / name)
            clean = json.loads(json.dumps(row, default=json_default))
            entry = {"format": ROW_CACHE_FORMAT, "row": clean, "row_sha256": row_sha256(clean), "files": files}
            (tmp / "row.json").write_text(json.dumps(entry, default=json_default))
            if d.exists():
                shutil.rmtree(d)
            os.replace(tmp, d)
        except OSError as exc:
            self.log(f"gibench: could not store row cache ({exc})")
