"""A run's sequence rows (issue #25): each method at each parameter set follows each sequence of
the run (`RunConfig.sequences`) through each of its cameras, and is judged frame by frame against
a Mitsuba reference of that frame.

One row per (sequence, view, method, parameter set), after the static rows. Rendering is
bench.run.sequence.run_sequence; then, per frame t, the references of the frame's static scene
(content-addressed: a frame equal to a static scene shares its references, a re-run renders
none; capped at the run's reference spp, no refinement pass) and the row's error columns for that
frame (bench.analysis.evaluation.evaluate_row). The row holds:
  * the error columns averaged over the frames (`relmse.indirect` ...) and their worst frame
    (`worst.relmse.indirect` ...);
  * `frame_ms`: the median frame of the frames after the first (frame 0 starts cold),
    `frame_ms_worst`, `update_ms` and `update_ms_worst` (what redoing the motion's work took inside
    the frames something moved in), `upload_ms` (the engine's uploads, not the method's),
    `prepare_ms`;
  * `sequence` (its name) and `extra.sequence_frames`;
  * with frames at rest after the motion, `lag_frames`: the frames after the last motion until the
    error is back within 10% of the method's static level on the final state (a fresh instance
    at rest there, rendered before the sequence: over its first K frames, the mean error
    `static.relmse.indirect` and the worst `static_worst.relmse.indirect`, the level waited for,
    so that a noisy method is back once within its own steady spread). A row not back by
    the last frame renders settling frames at rest (the same instance, the last frame's scene,
    at most `RunConfig.sequence_settle`) until it is: a lag longer than the frames at rest is
    measured, not bounded (pbgi's amortised gather refreshes its emitters over a window of about
    20 frames). NaN if not back even then (`lag_frames_at_least`). Settling frames are in
    `frames.csv` (`settling` = 1) and in the lag, not in the row's means, worsts and frame times,
    which are over the sequence's own frames.
Per-frame values go to `frames.csv` in the row's image folder beside the images of every frame
(`frame_NNN_{direct,indirect,combined}.exr`); the last frame's images and references are also
written under the usual names, so the report shows a sequence like a view (its last frame).
A method that fails or cannot follow the motion becomes a failed or skipped row; the run goes on.
"""
from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import numpy as np
import pandas as pd

from bench.analysis.evaluation import evaluate_row
from bench.model.imageio import write_exr
from bench.model.animation import Sequence
from bench.protocol import results as store
from bench.protocol.method import SkipRow, resolve_params
from bench.protocol.registry import load_method
from bench.protocol.versioning import harness_version, hash_files, method_version
from bench.protocol.vocabulary import IMAGE_COMPONENTS, REFERENCE_COMPONENTS, Status, failure_reason
from bench.run.config import RunConfig, cache_root, effective_shadow_resolution, sequence_config, sequence_param_sets
from bench.run.plan import image_folder
from bench.run.row_cache import RowCache
from bench.run.sequence import run_sequence
from reference.api import ReferenceUnavailable, get_reference


def sequence_key(sequence, view: str, method: str, version: str, params: dict, cfg: RunConfig, renderer: str) -> str:
    """Everything a sequence row depends on: every frame's scene content, the method's version and
    parameters, the size, seed, renderer, the harness and the sequence code, and the references its
    errors are against (their spp cap: the row holds its error columns)."""
    payload = {"kind": "sequence", "frames": [sequence.frame(t).content_hash() for t in range(sequence.frames)],
               "view": view, "method": method, "version": version, "params": params, "width": cfg.width,
               "height": cfg.height, "seed": cfg.seed, "shadow_resolution": effective_shadow_resolution(cfg),
               "renderer": renderer, "harness": harness_version(), "references": bool(cfg.references),
               "reference_spp": int(cfg.reference_spp_cap), "settle": int(cfg.sequence_settle),
               # how frames follow the motion and how the row's columns (lag, static level) are made
               "sequence_code": hash_files({Path(__file__), Path(run_sequence.__code__.co_filename)})}
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()[:24]


def sequence_files(frames: int) -> list:
    """The files a sequence row keeps (and the row cache holds): every frame's images, the last
    frame's under the usual names, the per-frame table."""
    return ([f"frame_{t:03d}_{c}.exr" for t in range(frames) for c in IMAGE_COMPONENTS]
            + [f"{c}.exr" for c in IMAGE_COMPONENTS] + ["frames.csv"])


class SequenceReferences:
    """Per-frame references of a run's sequences, fetched once per (sequence, view, frame)."""

    def __init__(self, run_dir: Path, cfg: RunConfig, log):
        self.run_dir, self.cfg, self.log = run_dir, cfg, log
        self.held: dict = {}
        self.unavailable: str | None = None
        self.seconds = 0.0

    def frame(self, sequence, view: str, t: int) -> dict:
        key = (sequence.name, view, t)
        if key in self.held:
            return self.held[key]
        refs = {}
        if self.unavailable is None:
            t0 = time.perf_counter()
            scene = sequence.frame(t)
            for c in REFERENCE_COMPONENTS:
                try:
                    refs[c] = get_reference(scene, view, self.cfg.width, self.cfg.height, c,
                                            spp_cap=max(int(self.cfg.reference_spp_cap), 2))
                except ReferenceUnavailable as exc:
                    self.unavailable = str(exc)
                    self.log(f"gibench: {exc}; sequence error columns left empty")
                    refs = {}
                    break
            self.seconds += time.perf_counter() - t0
            out = self.run_dir / "references" / sequence.name / view
            for c, ref in refs.items():
                write_exr(out / f"frame_{t:03d}_{c}.exr", ref.mean)
                if t == sequence.frames - 1:   # the report shows a sequence as its last frame
                    write_exr(out / f"{c}.exr", ref.mean)
                    write_exr(out / f"{c}_variance.exr", ref.variance)
        self.held[key] = refs
        return refs


def sequence_jobs(cfg: RunConfig, sequences: dict) -> list:
    """(sequence name, view, method, parameter set index, parameter set) of every sequence row:
    each method at its defaults (or its --param grid) on every camera of every sequence."""
    jobs = []
    for name, seq in sequences.items():
        for view in cfg.views or sorted(seq.base.cameras):
            if view not in seq.base.cameras:
                continue
            for method in cfg.methods:
                for index, pset in enumerate(sequence_param_sets(cfg, method)):
                    jobs.append((name, view, method, index, pset))
    return jobs


def run_sequence_rows(runner, ctx, renderer: str) -> None:
    """Render, judge and record every sequence row of `runner`'s run (bench.run.serial.Runner)."""
    cfg = sequence_config(runner.cfg)
    if not runner.sequences:
        return
    t_start = time.perf_counter()
    references = SequenceReferences(runner.run_dir, cfg, runner.log) if cfg.references else None
    memo = cache_root() / "metrics"
    rows_cache = RowCache(runner.log)
    jobs = sequence_jobs(cfg, runner.sequences)
    if runner.plan is not None and runner.plan.view_cost:   # budgeted: the cheapest views first, as chosen
        jobs = sorted(jobs, key=lambda j: runner.plan.view_cost.get((j[0], j[1]), 0.0))
    for name, view, method, index, pset in jobs:
        seq = runner.sequences[name]
        row = {"scene": name, "sequence": name, "view": view, "method": method, "params": store.params_json(pset),
               "seed": cfg.seed, "width": cfg.width, "height": cfg.height, "frames": seq.frames, "warmup": 0,
               "rung": store.params_json(pset)}
        skipped = runner.sequence_skip(name, view, method, index)
        if skipped is not None:   # over the run's budget: planned so, or the budget is spent
            row["status"] = Status.skipped(skipped)
            runner.counts["skipped"] += 1
            runner.rows.append(row)
            runner.record(row, write=False)
            continue
        try:
            cls = load_method(method)
            params = resolve_params(cls, pset)
            row["params"] = store.params_json(params)
            row["method_version"] = version = method_version(cls)
            row["row_key"] = sequence_key(seq, view, method, version, params, cfg, renderer)
            folder = _row_dir(seq, view, method, cls, params)
            row["image_dir"] = str(folder)
            cached = None if cfg.force else rows_cache.restore(row["row_key"], runner.run_dir / folder,
                                                               files=sequence_files(seq.frames))
            if cached is not None:   # measured values from the cache, every label from this run
                for t in range(seq.frames if references is not None else 0):
                    references.frame(seq, view, t)   # the run folder's per-frame references (from their cache)
                cached.update(row)
                cached["status"] = Status.CACHED
                runner.counts["cached"] += 1
                runner.rows.append(cached)
                runner.record(cached, write=False)
                continue
            static = _static_level(ctx, cls, seq, view, params, cfg, references, memo)
            result = run_sequence(ctx, cls, seq, view, cfg.width, cfg.height, params, seed=cfg.seed,
                                  shadow_resolution=effective_shadow_resolution(cfg),
                                  unsettled=_unsettled(seq, view, static, references, memo),
                                  settle_max=int(cfg.sequence_settle))
        except SkipRow as exc:
            row["status"] = Status.skipped(str(exc))
            runner.counts["skipped"] += 1
        except Exception as exc:   # a failing method never loses the others' rows
            ctx.error
            row["status"] = Status.failed(failure_reason(exc))
            runner.counts["failed"] += 1
            runner.log(f"gibench: sequence {name}/{view}/{method} failed: {failure_reason(exc)}")
        else:
            row.update(_record(runner.run_dir / folder, seq, view, result, references, memo))
            if static is not None and "relmse.indirect" in row:
                row.update(_lag(seq, view, method, cls, params, static, references))
            row["status"] = Status.OK
            runner.counts["ok"] += 1
            rows_cache.store(row["row_key"], row, runner.run_dir / folder, files=sequence_files(seq.frames))
        runner.rows.append(row)
        runner.record(row)
    ref_s = references.seconds if references is not None else 0.0   # the references are their own phase
    runner.phases["sequences"] = runner.phases.get("sequences", 0.0) + time.perf_counter() - t_start - ref_s
    runner.phases["references"] += ref_s


LAG_TOLERANCE = 0.10   # lag_frames: back within 10% of the static level
LAG_COLUMN = "relmse.indirect"


def last_change(seq) -> int:
    """The last frame in which something moved (0: nothing after the first frame)."""
    moved = [t for t in range(1, seq.frames) if seq.changes(t)]
    return moved[-1] if moved else 0


def _static_level(ctx, cls, seq, view: str, params: dict, cfg: RunConfig, references, memo) -> dict | None:
    """The error of a fresh instance at rest on the sequence's final state: over its frames 0..K-1
    (K = the run's error frames, at least 2), the mean (`static.relmse.indirect`) and the worst
    (`static_worst.relmse.indirect`), the level `lag_frames` waits for: a method whose frames are
    noisy is back when its error is within its own steady spread, not when it beats one lucky
    frame. None without frames at rest or references."""
    if references is None or last_change(seq) >= seq.frames - 1:
        return None
    refs = references.frame(seq, view, seq.frames - 1)
    if not refs:
        return None
    at_rest = Sequence(name=f"{seq.name}@rest", base=seq.frame(seq.frames - 1), frames=max(2, int(cfg.error_frames)),
                       tracks=())
    static = run_sequence(ctx, cls, at_rest, view, cfg.width, cfg.height, params, seed=cfg.seed,
                          shadow_resolution=effective_shadow_resolution(cfg))
    means = {c: r.mean for c, r in refs.items()}
    errors = [evaluate_row({"direct": d, "indirect": i, "combined": d + i}, means, memo).get(LAG_COLUMN)
              for d, i in static.images]
    return {f"static.{LAG_COLUMN}": float(np.mean(errors)), f"static_worst.{LAG_COLUMN}": float(np.max(errors))}


def _unsettled(seq, view: str, static: dict | None, references, memo):
    """run_sequence's `unsettled`: after the last frame, True while no frame since the motion's last
    is back within LAG_TOLERANCE of the static level (each frame judged once; the metrics memo then
    serves _record). None (no settling frames) without a static level."""
    if static is None:
        return None
    end, judged, level = last_change(seq), [], static[f"static_worst.{LAG_COLUMN}"]

    def unsettled(result) -> bool:
        refs = {c: r.mean for c, r in references.frame(seq, view, seq.frames - 1).items()}
        for direct, indirect in result.images[end + len(judged):]:
            images = {"direct": direct, "indirect": indirect, "combined": direct + indirect}
            judged.append(evaluate_row(images, refs, memo).get(LAG_COLUMN))
        return lag_after(np.asarray(judged, dtype=np.float64), 0, level) is None
    return unsettled


def _lag(seq, view: str, method: str, cls, params: dict, static: dict, references) -> dict:
    """`lag_frames` from the row's per-frame errors (settling frames included) and its static level;
    NaN when it is not back by the end (`lag_frames_at_least` then says how many frames at rest it
    was not)."""
    end = last_change(seq)
    out, level = dict(static), static[f"static_worst.{LAG_COLUMN}"]
    errors = pd.read_csv(references.run_dir / _row_dir(seq, view, method, cls, params) / "frames.csv")[LAG_COLUMN]
    lag = lag_after(errors.to_numpy(dtype=np.float64), end, level)
    out["lag_frames"] = float("nan") if lag is None else float(lag)
    if lag is None:
        out["lag_frames_at_least"] = float(len(errors) - end)
    return out


def lag_after(errors: np.ndarray, end: int, level: float, tolerance: float = LAG_TOLERANCE) -> int | None:
    """Frames after frame `end` (the motion's last) until `errors` is within `tolerance` of `level`
    (0: already at `end`), None if never by the last frame."""
    for t in range(end, len(errors)):
        if errors[t] <= (1.0 + tolerance) * level + 1e-12:
            return t - end
    return None


def _row_dir(seq, view: str, method: str, cls, params: dict) -> Path:
    return Path("images") / seq.name / view / image_folder(method, params, cls)


def _record(image_dir: Path, seq, view: str, result, references, memo) -> dict:
    """Write a rendered sequence row's images and per-frame table; its columns."""
    per_frame = []
    for f, (direct, indirect) in zip(result.frames, result.images):
        images = {"direct": direct, "indirect": indirect, "combined": direct + indirect}
        for comp in IMAGE_COMPONENTS if not f.settling else ():   # settling frames: their errors only
            write_exr(image_dir / f"frame_{f.t:03d}_{comp}.exr", images[comp])
            if f.t == seq.frames - 1:
                write_exr(image_dir / f"{comp}.exr", images[comp])
        values = {"t": f.t, "changes": "+".join(f.changes), "frame_ms": f.frame_ms, "update_ms": f.update_ms,
                  "upload_ms": f.upload_ms, "settling": int(f.settling)}
        refs = references.frame(seq, view, min(f.t, seq.frames - 1)) if references is not None else {}
        if refs:
            values.update(evaluate_row(images, {c: r.mean for c, r in refs.items()}, memo))
        per_frame.append(values)
    table = pd.DataFrame(per_frame)
    table.to_csv(image_dir / "frames.csv", index=False)
    table = table[table["settling"] == 0]                       # the row's figures: the sequence's own frames
    moving = table[table["t"] > 0]                              # every frame after the cold first one
    moved = table[(table["t"] > 0) & (table["changes"].fillna("") != "")]   # the frames something moved in
    out = {"frame_ms": float(moving["frame_ms"].median()), "frame_ms_worst": float(moving["frame_ms"].max()),
           "frame_ms_first": float(table["frame_ms"].iloc[0]),
           "update_ms": float(moved["update_ms"].median()) if len(moved) else 0.0,
           "update_ms_worst": float(moved["update_ms"].max()) if len(moved) else 0.0,
           "upload_ms": float(table["upload_ms"].sum()), "prepare_ms": result.prepare_ms,
           "stage_clock": result.stage_clock, "extra.sequence_frames": seq.frames,
           "samples.frame_ms": json.dumps([round(v, 4) for v in moving["frame_ms"]])}
    for column in table.columns:
        if "." in column and np.issubdtype(table[column].dtype, np.number):   # the error columns
            out[column] = float(table[column].mean())
            out[f"worst.{column}"] = float(table[column].max())
    return out
