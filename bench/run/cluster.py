"""Running a corpus beyond one process: rows and reference renders as dask.distributed tasks.

`gibench run --workers N` starts a `LocalCluster` of N worker processes (one thread each);
`--scheduler ADDRESS` uses an existing cluster. The runner (client side) plans every row,
answers resumed and cached rows itself, and submits the others as `render_task`s; each worker
process creates its EGL context once and keeps it, with the last scene it uploaded. Workers
return the measured fields and the images; the client writes the EXRs, the row cache and the
results table, so a distributed run folder has the same files as a serial one, rows in the
same order.

* Timing: a row's frames must not share a machine's cores with another row's. Every task (and
  every row of a serial run, bench.run.serial) holds the host's timing lock (`timing_lock`: an
  exclusive `flock` on `<tmp>/gibench-timing.lock`, or on `$GIBENCH_TIMING_LOCK`) while it
  renders, so rows on one host run one at a time whatever the number of workers there, and rows
  on different hosts in parallel (a lab: one or more workers per GPU machine). The kernel
  releases the lock when its holder dies, so a killed worker does not block the host. (A Dask
  `Semaphore` did not hold: its lease is refreshed by the worker's event loop, which a GL call
  holding the GIL for longer than the lease timeout, 30 s, starves; the scheduler then expired
  the lease and let a second row of the host render beside it.)
* Failures: a task that raises is a `failed` row (the method's error, as in a serial run); a
  worker that dies loses only its task, which the scheduler retries (`retries=2`) elsewhere; a
  task the scheduler drops instead (its future cancelled, "already forgotten", seen under load
  when a worker is killed) is submitted again by the client (`RESUBMISSIONS`).
* References: after the rows, every (scene, view, component) first pass is a task of its own
  (no timing lock: references may fill every core), rendered into the content-addressed reference
  cache (written atomically), which the client then reads. On a multi-host cluster the cache
  folder (`GIBENCH_CACHE_DIR`) must be shared, or the client renders what it cannot find.
"""
from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import fcntl
import logging
import os
import socket
import tempfile
import time
from pathlib import Path

from bench import gl
from bench.model.corpus import load_scene
from bench.model.scene import compute_facts
from bench.protocol.registry import load_method
from bench.protocol.vocabulary import REFERENCE_COMPONENTS, Status, failure_reason
from bench.run.execute import SharedPassCache, render_outcome
from reference.api import COMPONENTS, _build_one, _check, get_reference, load_mitsuba

RESUBMISSIONS = 2  # a row whose task the cluster lost (not the row's own failure) is submitted again this often

def timing_lock_path() -> Path:
    """The host's timing lock file: $GIBENCH_TIMING_LOCK, else gibench-timing.lock in the temp folder."""
    return Path(os.environ.get("GIBENCH_TIMING_LOCK") or Path(tempfile.gettempdir()) / "gibench-timing.lock")


@dataclasses.dataclass
class TimingLockWait:
    """How long a holder of the timing lock waited for it: more than a few milliseconds means
    another gibench process of this host was timing (its frames were not shared with ours)."""
    seconds: float = 0.0


@contextlib.contextmanager
def timing_lock(path: Path | None = None):
    """Hold the host's timing lock (an exclusive flock) for the block: one timed row per host at a
    time, whichever gibench process (serial run or Dask worker) renders it. Yields a TimingLockWait.
    Waiting releases the GIL (the worker keeps answering its scheduler); the kernel drops the
    lock when the holding process exits or is killed, so a dead holder never blocks the host."""
    path = Path(path) if path is not None else timing_lock_path()
    try:
        # flock needs no write access; O_CREAT only when missing: in a sticky /tmp, O_CREAT on
        # another user's file is refused (fs.protected_regular) even for reading
        fd = os.open(path, os.O_RDONLY) if path.exists() else os.open(path, os.O_RDONLY | os.O_CREAT, 0o644)
    except OSError as exc:
        raise ValueError(f"timing lock {path}: cannot open it ({exc.strerror}); set GIBENCH_TIMING_LOCK") from None
    try:
        t0 = time.perf_counter()
        fcntl.flock(fd, fcntl.LOCK_EX)
        try:
            yield TimingLockWait(time.perf_counter() - t0)
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def open_client(scheduler: str | None = None, workers: int | None = None):
    """(client, cluster or None): a client of `scheduler`, or of a new LocalCluster of `workers` processes."""
    from distributed import Client, LocalCluster   # Dask starts only for a distributed run
    if scheduler:
        try:
            return Client(scheduler, timeout="20s"), None
        except OSError as exc:
            raise ValueError(f"--scheduler {scheduler}: no Dask scheduler answers ({exc})") from None
    n = int(workers or 1)
    if not 1 <= n <= 256:
        raise ValueError(f"--workers {n} outside [1, 256]")
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                           silence_logs=logging.ERROR)
    return Client(cluster), cluster


def close_client(client, cluster) -> None:
    try:
        client.close()
    finally:
        if cluster is not None:
            cluster.close()


_STATE: dict = {}   # per worker process: the GL context, loaded scenes and facts, the uploaded scene, shared passes


def _worker_context():
    if "ctx" not in _STATE:
        _STATE["ctx"] = gl.create_context()
    return _STATE["ctx"]


def _worker_scene(ref):
    """A Scene from its reference: a corpus name or .toml path (loaded once per process) or the object."""
    if not isinstance(ref, str):
        return ref
    scenes = _STATE.setdefault("scenes", {})
    if ref not in scenes:
        scenes[ref] = load_scene(ref)
    return scenes[ref]


def _worker_gpu(ctx, scene, facts, seed: int):
    key = (scene.content_hash(), int(seed))
    held = _STATE.get("gpu")
    if held is not None and held[0] == key:
        return held[1]
    _worker_shared().release()   # they belong to the held scene
    if held is not None:
        held[1].release()
    gpu = gl.GpuScene(ctx, scene, seed=seed, facts=facts)
    _STATE["gpu"] = (key, gpu)
    return gpu


def _worker_shared() -> SharedPassCache:
    """This worker's shared passes: the view's passes lent to its rows as the serial runner lends
    them (rendered and measured once), rebuilt with the union of needs when a row needs more."""
    return _STATE.setdefault("shared", SharedPassCache())


def render_task(cfg, scene_ref, view: str, method: str, params: dict) -> dict:
    """One row on a worker: render_outcome under the host's timing lock, with the view's shared
    passes measured once per worker (as a serial run does once per view), plus its wall time
    (`seconds`, without the scene upload and the shared passes' build: `upload_seconds`, and
    `shared_build`, the SharedBuild when this row built them)."""
    scene = _worker_scene(scene_ref)
    ctx = _worker_context()
    cls = load_method(method)
    facts = _STATE.setdefault("facts", {}).get(scene.content_hash())
    if facts is None:
        facts = compute_facts(scene)
        _STATE["facts"][scene.content_hash()] = facts
    with timing_lock() as wait:
        t0 = time.perf_counter()
        gpu = _worker_gpu(ctx, scene, facts, cfg.seed)
        t1 = time.perf_counter()
        shared, build = _worker_shared().get(ctx, gpu, cfg, view, cls)
        t2 = time.perf_counter()
        outcome = render_outcome(ctx, gpu, cfg, cls, scene, facts, view, params, shared=shared)
        outcome["seconds"] = time.perf_counter() - t2
        outcome["upload_seconds"] = t1 - t0
        outcome["shared_build"] = build
    if "measured" in outcome:
        outcome["measured"]["timing_lock_wait_ms"] = wait.seconds * 1e3
    outcome["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    return outcome


def reference_task(scene_ref, view: str, width: int, height: int, component: str, spp_cap: int) -> str:
    """A reference's first pass on a worker, into the shared reference cache; returns its key."""
    scene = _worker_scene(scene_ref)
    return get_reference(scene, view, width, height, component, spp_cap=spp_cap).key


def _reference_line(scene_ref, view: str, width: int, height: int, component: str, spp_cap: int, threads: int) -> str:
    return _build_one((_worker_scene(scene_ref), view, width, height, component, spp_cap, threads))


def build_references(scene_refs: list, width: int, height: int, spp_cap: int, scheduler: str | None = None,
                     workers: int | None = None, out=print) -> list[str]:
    """`gibench reference build`: every camera and component of every scene as a task (references
    may fill every core: no timing lock); one line per reference, in completion order."""
    from distributed import as_completed

    load_mitsuba()  # fail early, with the install message, before starting processes
    scenes = [(ref, ref if not isinstance(ref, str) else load_scene(ref)) for ref in scene_refs]
    client, cluster = open_client(scheduler, workers)
    try:
        n_workers = max(1, len(client.scheduler_info().get("workers", {})))
        threads = max(1, (os.cpu_count() or 1) // n_workers) if cluster is not None else 0
        futures = []
        for ref, scene in scenes:
            for view in sorted(scene.cameras):
                for component in COMPONENTS:
                    _check(scene, view, width, height, component, spp_cap, None, "center")
                    futures.append(client.submit(_reference_line, ref, view, int(width), int(height), component,
                                                 int(spp_cap), threads, retries=2, pure=False))
        lines = []
        for fut in as_completed(futures):
            lines.append(fut.result())
            out(f"reference {lines[-1]}")
        return lines
    finally:
        close_client(client, cluster)


# ---------------------------------------------------------------------------- the client side
def run_rows(runner, ctx, scenes, jobs, renderer, resumable, references, progress) -> None:
    """A run's rows as Dask tasks: `runner` (bench.run.serial.Runner) plans each row (resumed,
    cached and failed-to-load rows are answered here), the others render on workers, and the
    runner finishes, accounts and records each outcome as a serial run does; results kept in job
    order, references after."""
    from distributed import as_completed
    cfg = runner.cfg
    client, cluster = open_client(cfg.scheduler, cfg.workers)
    try:
        # what a task needs of the configuration (not the scenes, sent once each)
        worker_cfg = dataclasses.replace(cfg, scenes=[], params={}, out=None)
        scene_refs = {name: (ref if isinstance(ref, str) else client.scatter(ref, broadcast=True))
                      for name, ref in runner.scene_refs.items()}
        done: dict = {}
        futures = {}
        for i, job in enumerate(jobs):
            planned = runner.plan_row(ctx, scenes[job.scene], job, renderer, resumable)
            if planned["done"]:
                done[i] = planned["row"]
                runner.state.mark_done(planned["row"])   # counted as recorded; the table is saved with the next row
                if progress is not None:
                    progress.update(1)
                continue

            def submit(job=job, planned=planned, i=i, attempt=0):
                return client.submit(render_task, worker_cfg, scene_refs[job.scene], job.view, job.method,
                                     planned["params"], retries=2, pure=False,
                                     key=f"row-{planned['key']}-{i}" + (f"-again{attempt}" if attempt else ""))
            futures[submit()] = (i, planned, submit, 0)
        pending = as_completed(list(futures))
        for fut in pending:
            i, planned, submit, attempt = futures.pop(fut)
            try:
                outcome = fut.result()
            except Exception as exc:  # the task's worker died more often than it was retried, or was dropped
                # a killed worker's task is retried by the scheduler (retries=2), but the scheduler can
                # also drop it, cancelled "for reason: already forgotten": submit that one again
                if isinstance(exc, concurrent.futures.CancelledError) and attempt < RESUBMISSIONS:
                    again = submit(attempt=attempt + 1)
                    futures[again] = (i, planned, submit, attempt + 1)
                    pending.add(again)
                    continue
                outcome = {"status": Status.FAILED, "reason": f"worker lost: {failure_reason(exc)}"}
            row = runner.finish_row(planned, outcome)
            if outcome.get("status") == Status.OK:
                runner.phases["scene_upload"] += float(outcome.get("upload_seconds", 0.0))
                if outcome.get("shared_build") is not None:   # a worker's view passes, built once per worker
                    runner.account_shared(outcome["shared_build"])
                runner.account_method(row, float(outcome["seconds"]))
                row["worker"] = outcome.get("worker")
            done[i] = row
            runner.rows = [done[k] for k in sorted(done)]
            runner.record(row)
            if progress is not None:
                progress.set_description(f"{row['scene']}/{row['view']}/{row['method']}")
                progress.update(1)
        runner.rows = [done[k] for k in sorted(done)]
        if references is not None:
            t0 = time.perf_counter()
            views = sorted({(r["scene"], r["view"]) for r in runner.rows if Status.has_images(r.get("status"))})
            cap = min(int(cfg.reference_spp_cap), references.REFERENCE_FIRST_PASS_SPP)
            refs = [client.submit(reference_task, scene_refs[s], v, cfg.width, cfg.height, comp, max(cap, 2),
                                  retries=2, pure=False)
                    for s, v in views for comp in REFERENCE_COMPONENTS]
            for fut in as_completed(refs):
                try:
                    fut.result()
                except Exception as exc:  # the client renders (or reports) it itself below
                    runner.log(f"gibench: a reference task failed on its worker ({failure_reason(exc)})")
            runner.phases["references"] += time.perf_counter() - t0
            for row in runner.rows:
                if not Status.is_failed(row["status"]):
                    references.evaluate(row, scenes[row["scene"]], row["view"])
                    row.pop("_reference_seconds", None)
            runner.save()
    finally:
        close_client(client, cluster)
