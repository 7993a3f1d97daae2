"""Mitsuba references of a run's views and the error columns of its rows (the ReferenceProvider).

Runs in the runner's process after the rows (a Dask run renders the first passes on its workers
into the shared reference cache first). References come from `reference.api.get_reference`
(content-addressed cache); metrics from bench.analysis.evaluation (memoised by content).
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from bench.analysis.evaluation import evaluate_row
from bench.model.imageio import read_exr, write_exr
from bench.protocol import results as store
from bench.protocol.vocabulary import (FRAME_STAT_IMAGES, IMAGE_COMPONENTS, JUDGES, REFERENCE_COMPONENTS, Status,
                                       failure_reason)
from bench.run.config import RunConfig, cache_root
from bench.run.row_cache import json_default
from reference.api import ReferenceUnavailable, get_reference
from tqdm import tqdm


class ReferenceProvider:
    """Fetches (or builds) the Mitsuba references of each view and adds error columns.

    Two passes. `evaluate()` (per row) fetches a first-pass reference of at most
    REFERENCE_FIRST_PASS_SPP samples per pixel (or the cap, if lower). `finish()` then refines,
    for each view, every component whose noise floor is above 1/10 of the best method's MSE
    against it (bounded by `reference_spp_cap`; the cache continues from the first pass) and
    only then computes every row's error columns, once, against the final references (metrics
    memoised by content in the cache: bench.analysis.evaluation). Each row records the key, spp and noise
    floor of the references it was judged against. Without Mitsuba the run goes on: error
    columns stay empty (NaN), never zero, and the reason is logged once.
    """

    COMPONENTS = REFERENCE_COMPONENTS
    JUDGES = JUDGES   # which method image each reference component judges
    REFERENCE_FIRST_PASS_SPP = 64
    TARGET_FRACTION = 0.1

    def __init__(self, run_dir: Path, cfg: RunConfig, log):
        self.run_dir, self.cfg, self.log = run_dir, cfg, log
        self._refs: dict = {}
        self._unavailable: str | None = None
        self._curves: dict = {}
        self._rows: dict = {}     # (scene name, view) -> [(row, scene)]
        self.seconds = {"references": 0.0, "metrics": 0.0}   # wall time fetching/rendering references, judging rows

    def _reference(self, scene, view: str, component: str, target_mse: float | None = None):
        t0 = time.perf_counter()
        try:
            return self._reference_uncounted(scene, view, component, target_mse)
        finally:
            self.seconds["references"] += time.perf_counter() - t0

    def _reference_uncounted(self, scene, view: str, component: str, target_mse: float | None = None):
        key = (scene.name, view, component)
        if key in self._refs and target_mse is None:
            return self._refs[key]
        ref = None
        if self._unavailable is None:
            cap = int(self.cfg.reference_spp_cap)
            if target_mse is None:
                cap = min(cap, self.REFERENCE_FIRST_PASS_SPP)
            try:
                ref = get_reference(scene, view, self.cfg.width, self.cfg.height, component,
                                    spp_cap=max(cap, 2), target_mse=target_mse)
            except ReferenceUnavailable as exc:
                self._unavailable = str(exc)
                self.log(f"gibench: {exc}; error columns left empty")
            except Exception as exc:  # a reference that fails leaves this view's columns empty
                self.log(f"gibench: reference {scene.name}/{view}/{component} failed: {failure_reason(exc)}")
            if ref is not None:
                out = self.run_dir / "references" / scene.name / view
                write_exr(out / f"{component}.exr", ref.mean)
                write_exr(out / f"{component}_variance.exr", ref.variance)
                self._curves[f"{scene.name}/{view}/{component}"] = ref.curve
        if ref is not None or key not in self._refs:  # a failed refinement keeps the first pass
            self._refs[key] = ref
        return ref

    def evaluate(self, row: dict, scene, view: str) -> None:
        """Fetch the view's first-pass references and record the row; its error columns come in finish()."""
        if not Status.has_images(row.get("status")):
            return  # skipped rows have no images to judge
        t0 = time.perf_counter()
        for c in self.COMPONENTS:
            self._reference(scene, view, c)
        self._rows.setdefault((scene.name, view), []).append((row, scene))
        row["_reference_seconds"] = time.perf_counter() - t0   # not the row's own time (see Runner._account_row)

    def judge_all(self) -> None:
        """Every recorded row's error columns against the final references of its view. (In one
        process: a pool of one worker per core measured slower, 340 s against 240 s for the 336
        rows of the default run, HDR-FLIP already keeping the cores busy.)"""
        t0 = time.perf_counter()
        jobs = []   # (row, refs of its view)
        for (scene_name, view), entries in self._rows.items():
            refs = {c: self._refs.get((scene_name, view, c)) for c in self.COMPONENTS}
            for row, _ in entries:
                for comp, ref in refs.items():
                    if ref is not None:
                        row[f"reference_key.{comp}"] = ref.key
                        row[f"reference_noise_floor.{comp}"] = ref.noise_floor_mse
                        row[f"reference_spp.{comp}"] = ref.spp
                if any(r is not None for r in refs.values()):
                    jobs.append((row, refs))
        progress = None
        if self.cfg.progress and jobs:
            progress = tqdm(total=len(jobs), unit="row", dynamic_ncols=True, file=sys.stderr, desc="error metrics")
        memo = cache_root() / "metrics"
        try:
            for row, refs in jobs:
                row.update(judge_row(self.run_dir / row["image_dir"], refs, memo, row.get("extra.error_frames")))
                if progress is not None:
                    progress.update(1)
        finally:
            if progress is not None:
                progress.close()
            self.seconds["metrics"] += time.perf_counter() - t0

    @staticmethod
    def _mse(image: np.ndarray, ref) -> float:
        mask = ref.coverage
        if not mask.any():
            return float("nan")
        return float(((image.astype(np.float64) - ref.mean) ** 2)[mask].mean())

    def refine(self) -> None:
        """Second pass: bring each view's references below 1/10 of the best method's MSE.

        A method's MSE against a noisy reference overestimates its true MSE by the reference's
        noise floor (E[(x - r)^2] = (x - mu)^2 + Var r), so the floor is subtracted before the
        target is set, and the target is re-estimated after each refinement (at most 4 times).
        """
        if self._unavailable is not None:
            return
        progress = None
        if self.cfg.progress and self._rows:
            progress = tqdm(total=len(self._rows), unit="view", dynamic_ncols=True, file=sys.stderr,
                            desc="refining references")
        try:
            for (scene_name, view), rows in self._rows.items():
                self._refine_view(scene_name, view, rows)
                if progress is not None:
                    progress.update(1)
        finally:
            if progress is not None:
                progress.close()

    def _refine_view(self, scene_name: str, view: str, rows: list) -> None:
        scene = rows[0][1]
        refs = {c: self._refs.get((scene_name, view, c)) for c in self.COMPONENTS}
        images: dict = {}
        for row, _ in rows:
            for name in set(self.JUDGES.values()):
                path = self.run_dir / row["image_dir"] / f"{name}.exr"
                if path.is_file():
                    images.setdefault(name, []).append(read_exr(path))
        for comp in self.COMPONENTS:
            for _ in range(4):
                ref = refs[comp]
                if ref is None or ref.noise_floor_mse == 0.0 or ref.spp >= self.cfg.reference_spp_cap:
                    break
                errors = [self._mse(img, ref) - ref.noise_floor_mse for img in images.get(self.JUDGES[comp], [])]
                errors = [e for e in errors if np.isfinite(e)]
                if not errors:
                    break
                target = self.TARGET_FRACTION * max(min(errors), 0.0)
                if ref.noise_floor_mse <= target:
                    break
                refined = self._reference(scene, view, comp, target_mse=target)
                if refined is None or refined.spp == ref.spp:
                    break
                refs[comp] = refined

    def finish(self) -> None:
        self.refine()
        self.judge_all()
        if self._curves:
            store.atomic_write_text(self.run_dir / "reference_curves.json", json.dumps(self._curves, default=json_default))


def judge_row(image_dir: Path, refs: dict, memo_dir, error_frames=None) -> dict:
    """Error columns of one row (its image folder) against its view's references: with more than
    one error frame, the decomposition columns too, from the frame statistics' images and the
    references' variance images (a row whose statistics are missing gets none)."""
    images = {c: read_exr(Path(image_dir) / f"{c}.exr") for c in IMAGE_COMPONENTS}
    try:
        frames = int(error_frames)
    except (TypeError, ValueError):   # a row of an older run (NaN, missing): no error frames
        frames = 1
    stats = None
    if frames > 1 and all((Path(image_dir) / f"{n}.exr").is_file() for n in FRAME_STAT_IMAGES):
        stats = {n: read_exr(Path(image_dir) / f"{n}.exr") for n in FRAME_STAT_IMAGES}
    return evaluate_row(images, {c: (r.mean if r is not None else None) for c, r in refs.items()}, memo_dir=memo_dir,
                        ref_variances={c: (r.variance if r is not None else None) for c, r in refs.items()},
                        frame_stats=stats, error_frames=frames)

