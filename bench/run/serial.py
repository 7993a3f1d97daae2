"""The runner: scenes x views x methods x parameter sets -> result rows, images, references.

Rows run grouped by scene and view (bench.run.plan). Each scene is uploaded once (GpuScene). Each
view's shared passes (GBuffer, shadow maps, direct light, RSM) are built once with the union of
the needs of the view's rows still to render, rendered and measured once, and lent to every
method and rung of the view (bench.run.execute.SharedPassCache): a row's frames render only its
method, and its frame time adds the measured medians of the shared stages it needs (recorded in
the row's `extra.shared_*` and in the manifest's `shared_passes`). Every row is rendered by
bench.run.execute.render_outcome (prepare untimed, warm-up + K timed frames), here or in a Dask
worker (bench.run.cluster); the runner writes linear EXRs of direct, indirect and combined (and,
with `error_frames` > 1, the per-pixel mean, variance and flicker of indirect and combined over
the error frames: bench.run.harness) and appends one row to the run's results table (written
atomically after every row). The row cache (bench.run.row_cache) means a row whose scene
content, method version, parameters, resolution, frames, error frames, seed and machine are
unchanged is not re-run (`force=True` re-runs); an interrupted run
resumes from its results table (bench.run.plan.RunState). A method that fails (to load, to
prepare, to render) becomes a `failed: <reason>` row and the run goes on with the others.

Trust rules:
* A cache hit takes the measured values from the entry and every label (scene name, view, paths)
  from the current run; an entry that fails its checks is a miss, evicted with a one-line warning.
* Scene names are unique within a run (two scenes named alike are bad input, not a silent
  overwrite); a hit keyed on scene *content* therefore never mislabels a row.
* An existing `--out` is merged, not replaced (bench.run.plan.merge_existing), by one run at a
  time: the run holds the folder's lock (bench.run.plan.RunFolderLock) from before its first
  write to its end, and a second run into it is refused. A folder that vanishes mid-run ends the
  run with RunFolderLost (exit 1: incomplete, a re-run repairs it).
* Bad input is found before the run folder exists: every `--param` is checked for every method
  (a `--param` of a method that is not in the run is bad input), the scenes are loaded and the
  jobs planned (an unknown scene, a missing scene file or camera).
* Timing: each row renders under the host's timing lock (bench.run.cluster.timing_lock), as a
  Dask task does, so two gibench runs of one machine take turns in their timed frames instead of
  sharing the cores; a row records how long it waited (`timing_lock_wait_ms`), the manifest the
  run's total (`timing_lock`). Other load of the machine is not excluded.
* SIGTERM ends a run as Ctrl-C does (KeyboardInterrupt): the rows recorded so far are saved, the
  run state says unfinished, and the same command resumes.
"""
from __future__ import annotations

import os
import signal
import sys
import threading
import time
import traceback
from pathlib import Path

import numpy as np
from tqdm import tqdm

from bench import gl
from bench.analysis.summary import write_summary
from bench.gl.profiler import default_clock
from bench.model.corpus import load_scene
from bench.model.corpus.sequences import load_sequence
from bench.model.imageio import write_exr
from bench.model.scene import Scene, compute_facts
from bench.protocol import results as store
from bench.protocol.method import resolve_params
from bench.protocol.registry import load_method
from bench.protocol.versioning import method_version
from bench.protocol.vocabulary import Status, failure_reason, row_identity
from bench.run import budget, cluster, cost, plan
from bench.run.config import RunConfig, auto_shadow_resolution, effective_shadow_resolution, expand_param_sets  # noqa: F401  (the run's vocabulary)
from bench.run.execute import SharedPassCache, render_outcome
from bench.run.manifest import record_phases, write_manifest
from bench.run.references import ReferenceProvider
from bench.run.row_cache import RowCache, row_cache_key, row_image_names
from bench.run.sequence_rows import run_sequence_rows, sequence_jobs


class Runner:
    """Runs a RunConfig; `run()` returns the results DataFrame."""

    def __init__(self, cfg: RunConfig, log=print, started: float | None = None):
        t_setup = time.perf_counter()
        # the budget counts from `started` (the command's start, time.perf_counter()), else from here
        self.started = t_setup if started is None else min(float(started), t_setup)
        self._planned_done = 0.0          # the plan's prediction of the rows started so far (the run's pace)
        self._opened_views: set = set()   # views whose first row has started
        self.plan: budget.RunPlan | None = None
        cfg.validate()
        self.cfg = cfg
        self.log = log
        # bad input (a parameter, a scene, a scene file, a camera) is found before the run folder is created
        self.resolved = validate_params(cfg)
        self.scenes, self.scene_refs = load_scenes(cfg)   # scene_refs: what a worker loads each from
        self.sequences = {name: load_sequence(name, cfg.sequence_frames, cfg.sequence_rest) for name in cfg.sequences}
        self.jobs = plan.make_jobs(cfg, self.scenes)
        self.run_dir = Path(cfg.out) if cfg.out else plan.default_run_dir()
        plan.prepare_run_dir(self.run_dir)
        self.folder = plan.RunFolderLock(self.run_dir)
        self.folder.acquire()   # before reading what the folder holds: no other run writes it from here on
        try:
            self.existing = plan.existing_rows(self.run_dir)   # a corrupt table is bad input, before any write
        except Exception:
            self.folder.release()
            raise
        self.rows: list[dict] = []
        self.kept: list[dict] = []   # rows of the folder this run does not produce (merge)
        self.counts = {"ok": 0, "cached": 0, "resumed": 0, "failed": 0, "skipped": 0}
        self.cache = RowCache(log)
        self.state = plan.RunState(self.run_dir)
        self._view_lit: dict = {}   # (scene, view) -> did any rendered row have light
        self._gpu = None            # (scene name, GpuScene): uploaded once per scene, shared by its rows
        self.shared = SharedPassCache()
        self.shared_summary: dict = {}  # "scene/view" -> variant -> measurement summary (manifest)
        # wall seconds per phase of the run (the manifest records them)
        self.phases = {"setup": time.perf_counter() - t_setup, "scene_upload": 0.0, "precompute": 0.0, "timing": 0.0,
                       "error_frames": 0.0, "rows_other": 0.0, "references": 0.0, "metrics": 0.0,
                       "sequences": 0.0}

    def _job_identity(self, scene, job) -> tuple:
        """(row identity, image dir) of a job, as the row will record them."""
        params = self.resolved.get((job.method, job.index), job.params)
        row = {"scene": scene.name, "view": job.view, "method": job.method, "params": store.params_json(params),
               "seed": self.cfg.seed, "width": self.cfg.width, "height": self.cfg.height}
        folder = job.method
        if (job.method, job.index) in self.resolved:
            folder = plan.image_folder(job.method, params, load_method(job.method))
        return row_identity(row), str(Path("images") / scene.name / job.view / folder)

    def _around_sequences(self, jobs: list) -> tuple:
        """(the scenes' jobs before the sequence rows, those after). Under a budget the sequences are
        defaults too: they run after the scenes' defaults and before the ladders, so a run that
        falls behind its plan cuts ladders, not motion; otherwise every scene's job comes first."""
        if self.cfg.budget_s is None or not self.sequences or self.plan is None:
            return jobs, []
        first = {(r.job.scene, r.job.view, r.job.method, r.job.index) for r in self.plan.rows if r.priority == 0}
        before = [j for j in jobs if (j.scene, j.view, j.method, j.index) in first]
        after = [j for j in jobs if (j.scene, j.view, j.method, j.index) not in first]
        return before, after

    def _sequence_identities(self) -> list:
        """(row identity, image dir) of the sequence rows this run produces (the merge replaces them)."""
        out = []
        for name, view, method, index, pset in sequence_jobs(self.cfg, self.sequences):
            params, folder = pset, method
            try:
                cls = load_method(method)
                params = resolve_params(cls, pset)
                folder = plan.image_folder(method, params, cls)
            except Exception:   # the row fails with its reason when it runs
                pass
            row = {"scene": name, "view": view, "method": method, "params": store.params_json(params),
                   "seed": self.cfg.seed, "width": self.cfg.sequence_width, "height": self.cfg.sequence_height}
            out.append((row_identity(row), str(Path("images") / name / view / folder)))
        return out

    def save(self) -> None:
        store.save_results(self.run_dir, self.kept + self.rows)

    # ------------------------------------------------------------------ main loop
    def run(self):
        """Run every job; the folder's lock is released at the end, whatever happens."""
        sigterm = None
        if threading.current_thread() is threading.main_thread():
            sigterm = signal.signal(signal.SIGTERM, _interrupt)
        try:
            return self._run()
        except OSError as exc:
            if not isinstance(exc, plan.RunFolderLost):
                self.folder.check()   # a write failed because the folder vanished: say that
            raise
        finally:
            if sigterm is not None:
                signal.signal(signal.SIGTERM, sigterm)
            self.folder.release()

    def _run(self):
        cfg, scenes, jobs = self.cfg, self.scenes, self.jobs
        t_setup = time.perf_counter()
        ctx = gl.create_context()
        facts = {name: compute_facts(s) for name, s in scenes.items()}
        self.plan = budget.make_plan(cfg, scenes, facts, jobs, ctx, resolved=self.resolved, sequences=self.sequences)
        if cfg.budget_s is not None:
            budget.apply_budget(self.plan, cfg.budget_s, cfg.budget_margin)
            # defaults first: a short budget cuts the middles (the sequence rows run after, on their own)
            jobs = self.jobs = [j for j in self.plan.ordered_jobs() if j.scene in scenes]
        if cfg.budget_s is not None or cfg.progress:   # a quiet run (--no-progress) says only what goes wrong
            self.log(f"gibench: plan: {self.plan.summary()}")
        write_manifest(self.run_dir, ctx, cfg, scenes, facts, plan=self.plan.to_json())
        if cfg.out is None or self.run_dir.parent.name == "runs":
            plan.point_latest(self.run_dir)
        renderer = ctx.info.get("GL_RENDERER", "")
        existing = self.existing
        self.kept = plan.merge_existing(self.run_dir, existing, [self._job_identity(scenes[j.scene], j) for j in jobs]
                                        + self._sequence_identities())
        if self.kept:
            self.log(f"gibench: {self.run_dir}: keeping {len(self.kept)} row(s) of earlier runs "
                     f"(other methods, resolutions or parameters)")
        invocation = plan.invocation_hash(cfg, scenes)
        resumable = self.state.resumable(existing, invocation, cfg.force)
        self.state.start(invocation, len(jobs) + len(sequence_jobs(cfg, self.sequences)))

        progress = tqdm(total=len(jobs), unit="row", dynamic_ncols=True, file=sys.stderr) if cfg.progress else None
        references = ReferenceProvider(self.run_dir, cfg, self.log) if cfg.references else None
        self.phases["setup"] += time.perf_counter() - t_setup
        try:
            if cfg.scheduler or cfg.workers:
                cluster.run_rows(self, ctx, scenes, jobs, renderer, resumable, references, progress)
                self._release_gpu()
                run_sequence_rows(self, ctx, renderer)   # scenes in motion, judged frame by frame as they render
            else:
                before, after = self._around_sequences(jobs)
                self._run_serial(ctx, scenes, facts, before, renderer, resumable, references, progress)
                self._release_gpu()
                run_sequence_rows(self, ctx, renderer)
                self._run_serial(ctx, scenes, facts, after, renderer, resumable, references, progress)
        finally:
            if progress is not None:
                progress.close()
            self._release_gpu()
        for (scene_name, view), lit in self._view_lit.items():
            if not lit:
                self.log(f"gibench: warning: {scene_name}/{view}: every method rendered an all-black image "
                         f"(does camera '{view}' see a lit surface?)")
        if references is not None:
            references.finish()
            self.phases["references"] += references.seconds["references"]
            self.phases["metrics"] += references.seconds["metrics"]
        self.folder.check()
        df = store.save_results(self.run_dir, self.kept + self.rows)
        record_phases(self.run_dir, self.phases, self.shared_summary, self.rows, self.plan)
        self._record_history()
        self.folder.check()   # the manifest's phases went nowhere if the folder was replaced meanwhile
        self.state.finish()
        write_summary(self.run_dir)
        return df

    def _run_serial(self, ctx, scenes, facts, jobs, renderer, resumable, references, progress) -> None:
        for group in plan.view_groups(jobs):
            # plan the view's rows first: its shared passes serve the rows that still render
            plans = []
            for job in group:
                t_plan = time.perf_counter()
                planned = self.plan_row(ctx, scenes[job.scene], job, renderer, resumable)
                plans.append((planned, time.perf_counter() - t_plan))
            first = group[0]
            self.shared.expect(SharedPassCache.view_key(scenes[first.scene], self.cfg.seed, self.cfg, first.view),
                               [p["cls"] for p, _ in plans if not p["done"]])
            for job, (planned, plan_s) in zip(group, plans):
                if progress is not None:
                    progress.set_description(f"{job.scene}/{job.view}/{job.method}")
                t_row = time.perf_counter()
                spent = self.budget_spent(planned)
                if spent is not None:
                    planned = {"done": True, "row": self._skip(planned["row"], spent)}
                row = self._run_row(ctx, scenes[job.scene], facts[job.scene], job.view, planned)
                if references is not None and not Status.is_failed(row["status"]):
                    references.evaluate(row, scenes[job.scene], job.view)
                self._account_row(row, plan_s + time.perf_counter() - t_row)
                self.rows.append(row)
                # a row that cost nothing (cached, resumed, skipped) is saved with the next rendered one
                # or at the end: saving the table after each of hundreds of skipped rows took ~30 s
                self.record(row, write=not planned["done"])
                if progress is not None:
                    progress.update(1)

    def record(self, row: dict, write: bool = True) -> None:
        """A row is done: save the table, mark it in the run state (the one place either happens).
        `write=False` defers both files to the next write or the end of the run (an interrupted run
        then re-plans the deferred rows, which cost nothing to redo)."""
        if not write:
            self.state.mark_done(row, write=False)
            return
        self.folder.check()
        self.save()
        self.state.mark_done(row)

    def _run_row(self, ctx, scene, facts, view, planned) -> dict:
        if planned["done"]:
            return planned["row"]
        with cluster.timing_lock() as wait:   # one timed row per host, whichever gibench process renders it
            gpu = self._scene_gpu(ctx, scene, facts)
            shared, build = self.shared.get(ctx, gpu, self.cfg, view, planned["cls"])
            outcome = render_outcome(ctx, gpu, self.cfg, planned["cls"], scene, facts, view, planned["params"],
                                     shared=shared)
        if build is not None:
            self.account_shared(build)
        if "measured" in outcome:
            outcome["measured"]["timing_lock_wait_ms"] = wait.seconds * 1e3
        row = self.finish_row(planned, outcome)
        row["_shared_seconds"] = build.seconds if build is not None else 0.0   # the view's, not the row's own time
        row["_lock_wait_seconds"] = wait.seconds   # another process's turn, not the row's own time
        return row

    def account_shared(self, build) -> None:
        """A view's shared passes were built (here or on a worker): their time and measurement."""
        if build.failure is not None:
            self.log(f"gibench: {build.view_key}: shared passes failed ({build.failure}); each row renders its own")
            return
        self.phases["timing"] += build.frames_ms / 1e3
        self.phases["precompute"] += max(build.seconds - build.frames_ms / 1e3, 0.0)
        self.shared_summary.setdefault(build.view_key, {})[build.variant] = build.summary

    # ------------------------------------------------------------------ one row: plan, finish
    def plan_row(self, ctx, scene, job, renderer, resumable) -> dict:
        """The row's labels, key and image folder; a resumed, cached or failed-to-load row is done here
        ({"done": True, "row": row}), else {"done": False, ...} with what rendering it needs."""
        cfg = self.cfg
        view, method_name = job.view, job.method
        row = {"scene": scene.name, "scene_hash": scene.content_hash(), "view": view, "method": method_name,
               "params": store.params_json(job.params), "seed": cfg.seed, "width": cfg.width, "height": cfg.height,
               "frames": cfg.frames, "warmup": cfg.warmup,
               # the declared override this row ran (its ladder rung or --param set; "{}" for the defaults):
               # `params` is resolved below, and a history keeps a rung's series across a changed default
               "rung": store.params_json(job.params)}
        try:
            cls = load_method(method_name)
            resolved = self.resolved.get((method_name, job.index))
            params = resolved if resolved is not None else resolve_params(cls, job.params)
            version = method_version(cls)
        except Exception as exc:  # load failure or bad parameter: recorded, the run goes on
            return {"done": True, "row": self._failed(row, exc)}
        row["params"] = store.params_json(params)
        row["method_version"] = version
        key = row_cache_key(scene, view, method_name, version, params, cfg, renderer, default_clock(ctx))
        row["row_key"] = key
        image_dir = self.run_dir / "images" / scene.name / view / plan.image_folder(method_name, params, cls)
        row["image_dir"] = str(image_dir.relative_to(self.run_dir))

        if (key, row["image_dir"]) in resumable and \
                all((image_dir / f"{name}.exr").is_file() for name in row_image_names(cfg.error_frames)):
            self.counts["resumed"] += 1
            return {"done": True, "row": dict(resumable[(key, row["image_dir"])], **row)}
        cached = None if cfg.force else self.cache.restore(key, image_dir, cfg.error_frames)
        if cached is not None:
            cached.update(row)  # measured values from the cache, every label from this run
            cached["status"] = Status.CACHED
            self.counts["cached"] += 1
            return {"done": True, "row": cached}
        over = self.plan.skipped_jobs().get((job.scene, job.view, job.method, job.index)) if self.plan else None
        if over is not None:
            return {"done": True, "row": self._skip(row, over)}
        return {"done": False, "row": row, "cls": cls, "params": params, "key": key, "image_dir": image_dir,
                "scene": scene, "view": view, "job": job}

    def finish_row(self, planned: dict, outcome: dict) -> dict:
        """Write a rendered row's images and cache entry (or record its skip / failure)."""
        row, image_dir = planned["row"], planned["image_dir"]
        if outcome["status"] == Status.SKIPPED:
            row["status"] = Status.skipped(outcome["reason"])
            self.counts["skipped"] += 1
            return row
        if outcome["status"] == Status.FAILED:
            return self._failed(row, RuntimeError(outcome["reason"]))
        images = outcome["images"]
        for comp, img in images.items():
            write_exr(image_dir / f"{comp}.exr", img)
        # a view is suspicious only when no method lights it: `direct` alone is black by design
        # where every lit surface is off screen (hidden_bounce, the far room of rooms)
        view_key = (row["scene"], row["view"])
        self._view_lit[view_key] = self._view_lit.get(view_key, False) or bool(np.any(images["combined"] > 0))
        row.update(outcome["measured"])
        self.counts["ok"] += 1
        self.cache.store(planned["key"], row, image_dir)
        return row

    def _skip(self, row: dict, reason: str) -> dict:
        row["status"] = Status.skipped(reason)
        self.counts["skipped"] += 1
        return row

    def budget_spent(self, planned: dict) -> str | None:
        """Why a row that would render now is not started (the run's budget is spent), else None."""
        if self.cfg.budget_s is None or planned.get("done") or self.plan is None:
            return None
        return self._over_budget(planned["job"])

    def sequence_skip(self, name: str, view: str, method: str, index: int) -> str | None:
        """Why a sequence row is not run under the run's budget (the plan's choice, or the budget
        spent by now), else None."""
        if self.cfg.budget_s is None or self.plan is None:
            return None
        over = self.plan.skipped_jobs().get((name, view, method, index))
        return over if over is not None else self._over_budget(plan.Job(name, view, method, index, {}))

    def _over_budget(self, job) -> str | None:
        """The run's clock against its plan: a row is not started when the time spent, plus the row's
        prediction (its view's references when it opens the view), plus what the rows already run
        still need at the end (their metrics, their views' reference refinement), passes the budget.
        The predictions of what is still to come are scaled by the run's pace so far (its time spent
        over the plan's prediction of what it has done, within [0.5, 2]): a model that over- or
        under-predicts this machine today neither stops a run early nor lets it overrun."""
        planned = self.plan.planned_row(job)
        if planned is not None and planned.status == "guard":
            # its method's guard skips it: it costs nothing and opens no view (counting its view's
            # references made a default run refuse all its scenes in motion at a third of its budget)
            return None
        elapsed = time.perf_counter() - self.started
        row_s = planned.total if planned is not None else 0.0
        view = self.plan.views.get((job.scene, job.view), {})
        opening = (job.scene, job.view) not in self._opened_views
        if opening:   # the first pass now, the refinement at the end
            row_s += view.get("references", 0.0) - view.get("references_refinement", 0.0)
            if view.get("references", 0.0) > 0 and not any(self.plan.views.get(v, {}).get("references", 0.0) > 0
                                                           for v in self._opened_views):
                row_s += self.plan.reference_start_s   # Mitsuba starts with the first reference
        judged = [r for r in self.rows if Status.has_images(r.get("status"))]
        finish_s = self.plan.finish_seconds(self._opened_views | ({(job.scene, job.view)} if opening else set()),
                                            len(judged) + 1)
        pace = min(max(elapsed / max(self.plan.setup_s + self._planned_done, 1.0), 0.5), 2.0)
        if elapsed + pace * (row_s + finish_s) <= self.cfg.budget_s:
            self._planned_done += row_s
            self._opened_views.add((job.scene, job.view))
            return None
        return (f"over budget: the budget was spent ({elapsed:.0f} s of {self.cfg.budget_s:.0f} s used, "
                f"this row predicted {row_s:.0f} s)")

    def _record_history(self) -> None:
        """This run's predicted and actual phases, for the next plan's local model (bench.run.cost)."""
        judged = [r for r in self.rows if Status.has_images(r.get("status"))]
        pixels = self.cfg.width * self.cfg.height
        entry = {"setup_s": self.phases["setup"] + self.phases["scene_upload"], "rows_judged": len(judged),
                 "triangles": sum(s.triangle_count for s in self.scenes.values()),
                 "actual_s": {k: round(v, 3) for k, v in self.phases.items()},
                 "predicted_s": self.plan.to_json()["predicted_s"] if self.plan else None}
        if judged and self.phases["metrics"] > 0:
            entry["metrics_s_per_pixel"] = self.phases["metrics"] / (len(judged) * pixels)
        cost.record_history(entry)

    def _failed(self, row: dict, exc: Exception) -> dict:
        reason = failure_reason(exc)
        row["status"] = Status.failed(reason)
        self.counts["failed"] += 1
        self.log(f"gibench: {row['scene']}/{row['view']}/{row['method']} failed: {reason}")
        if os.environ.get("GIBENCH_DEBUG"):
            traceback.print_exc()
        return row

    # ------------------------------------------------------------------ shared scene upload, accounting
    def _scene_gpu(self, ctx, scene, facts):
        """The scene's GpuScene, uploaded once and shared by every row of the scene (rows run
        grouped by scene); the upload is a phase of its own, not part of any row's overhead."""
        if self._gpu is not None and self._gpu[0] == scene.name:
            return self._gpu[1]
        self._release_gpu()
        t0 = time.perf_counter()
        gpu = gl.GpuScene(ctx, scene, seed=self.cfg.seed, facts=facts)
        ctx.finish()
        self.phases["scene_upload"] += time.perf_counter() - t0
        self._gpu = (scene.name, gpu)
        return gpu

    def _release_gpu(self) -> None:
        self.shared.release()
        if self._gpu is not None:
            self._gpu[1].release()
            self._gpu = None

    def _account_row(self, row: dict, seconds: float) -> None:
        """Split a rendered row's wall time into the method's part (prepare, every frame) and the
        harness's (read-back, EXR and cache writes, bookkeeping); reference fetches and metrics
        are phases of their own. `harness_overhead` = the harness's part / the row's time."""
        reference_s = float(row.pop("_reference_seconds", 0.0))
        shared_s = float(row.pop("_shared_seconds", 0.0))   # the view's shared passes: timing + precompute
        wait_s = float(row.pop("_lock_wait_seconds", 0.0))
        if row.get("status") != Status.OK:
            return
        self.account_method(row, seconds - reference_s - shared_s - wait_s)

    def account_method(self, row: dict, row_s: float) -> None:
        """Charge a rendered row's prepare, frames and error frames to their phases, the rest of
        `row_s` to the harness."""
        error_s = float(row.get("error_frames_ms", 0.0)) / 1e3   # the error frames' read-backs, sums and untimed frames
        method_s = (float(row.get("prepare_ms", 0.0)) + float(row.get("frames_total_ms", 0.0))) / 1e3 + error_s
        self.phases["precompute"] += float(row.get("prepare_ms", 0.0)) / 1e3
        self.phases["timing"] += float(row.get("frames_total_ms", 0.0)) / 1e3
        self.phases["error_frames"] += error_s
        self.phases["rows_other"] += max(row_s - method_s, 0.0)
        row["row_wall_ms"] = row_s * 1e3
        row["harness_overhead"] = max(row_s - method_s, 0.0) / row_s if row_s > 0 else float("nan")

    def summary(self) -> str:
        c = self.counts
        total = sum(c.values())
        parts = [f"{c['ok']} rendered", f"{c['cached']} from cache", f"{c['resumed']} resumed",
                 f"{c['skipped']} skipped", f"{c['failed']} failed"]
        msg = f"{total} rows: " + ", ".join(parts)
        if total and c["ok"] == 0 and c["failed"] == 0:
            msg += " (nothing re-run: every row was unchanged)"
        return msg


def _interrupt(signum, frame):
    """SIGTERM as Ctrl-C: the run stops between rows' saves and says how to resume (bench.cli)."""
    raise KeyboardInterrupt


def validate_params(cfg: RunConfig) -> dict:
    """Every --param of every method, checked before the first row: {(method, i): resolved}."""
    stray = sorted(set(cfg.params) - set(cfg.methods))
    if stray:
        raise ValueError(f"--param given for method(s) {', '.join(stray)} not in this run "
                         f"(methods: {', '.join(cfg.methods)})")
    resolved = {}
    for method in cfg.methods:
        try:
            cls = load_method(method)
        except Exception:  # a method that fails to load becomes a failed row (recorded, the run goes on)
            continue
        for i, pset in enumerate(expand_param_sets(cfg, method)):
            resolved[(method, i)] = resolve_params(cls, pset)
    return resolved


def load_scenes(cfg: RunConfig) -> tuple[dict, dict]:
    """Corpus names, .toml scene files, or Scene objects (tests, scripts) -> ({name: Scene},
    {name: what a worker loads it from: the corpus name or path, or the Scene})."""
    scenes, given, refs = {}, {}, {}
    for item in cfg.scenes:
        scene = item if isinstance(item, Scene) else load_scene(item)
        what = str(item) if not isinstance(item, Scene) else (scene.source or "a Scene object")
        if scene.name in scenes:
            raise ValueError(f"two scenes are named '{scene.name}' ({given[scene.name]} and {what}): "
                             f"scene names must be unique within a run")
        scenes[scene.name], given[scene.name] = scene, what
        refs[scene.name] = item if isinstance(item, str) else scene
    return scenes, refs


def plan_only(cfg: RunConfig) -> budget.RunPlan:
    """The run's cost plan, made as the run would make it, without a run folder or any rendering."""
    cfg.validate()
    resolved = validate_params(cfg)
    scenes, _ = load_scenes(cfg)
    sequences = {name: load_sequence(name, cfg.sequence_frames, cfg.sequence_rest) for name in cfg.sequences}
    jobs = plan.make_jobs(cfg, scenes)
    ctx = gl.create_context()   # the process's context: its renderer and clock are part of a row's cache key
    facts = {name: compute_facts(s) for name, s in scenes.items()}
    run_plan = budget.make_plan(cfg, scenes, facts, jobs, ctx, resolved=resolved, sequences=sequences)
    if cfg.budget_s is not None:
        budget.apply_budget(run_plan, cfg.budget_s, cfg.budget_margin)
    return run_plan


def run(cfg: RunConfig, log=print, started: float | None = None):
    """Run and return (DataFrame, Runner); `started`: when the command began (its budget counts from then)."""
    runner = Runner(cfg, log=log, started=started)
    df = runner.run()
    return df, runner
