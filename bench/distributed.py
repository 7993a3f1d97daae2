"""Running a corpus beyond one process: rows and reference renders as dask.distributed tasks.

`gibench run --workers N` starts a `LocalCluster` of N worker processes (one thread each);
`--scheduler ADDRESS` uses an existing cluster. The runner (client side) plans every row,
answers resumed and cached rows itself, and submits the others as `render_task`s; each worker
process creates its EGL context once and keeps it, with the last scene it uploaded. Workers
return the measured fields and the images; the client writes the EXRs, the row cache and the
results table, so a distributed run folder has the same files as a serial one, rows in the
same order.

* Timing: a row's frames must not share a machine's cores with another row's. Every task holds
  the host's timing lock (`timing_lock`: an exclusive `flock` on `<tmp>/gibench-timing.lock`, or
  on `$GIBENCH_TIMING_LOCK`) while it renders, so rows on one host run one at a time whatever the
  number of workers there, and rows on different hosts in parallel (a lab: one or more workers
  per GPU machine). The kernel releases the lock when its holder dies, so a killed worker does
  not block the host. (A Dask `Semaphore` did not hold: its lease is refreshed by the worker's
  event loop, which a GL call holding the GIL for longer than the lease timeout, 30 s, starves;
  the scheduler then expired the lease and let a second row of the host render beside it.)
* Failures: a task that raises is a `failed` row (the method's error, as in a serial run); a
  worker that dies loses only its task, which the scheduler retries (`retries=2`) elsewhere; a
  task the scheduler drops instead (its future cancelled, "already forgotten", seen under load
  when a worker is killed) is submitted again by the runner (`runner.RESUBMISSIONS`).
* References: after the rows, every (scene, view, component) first pass is a task of its own
  (no timing lock: references may fill every core), rendered into the content-addressed reference
  cache (written atomically), which the client then reads. On a multi-host cluster the cache
  folder (`GIBENCH_CACHE_DIR`) must be shared, or the client renders what it cannot find.
"""
from __future__ import annotations

import contextlib
import logging
import os
import socket
import tempfile
import time
from pathlib import Path

_STATE: dict = {}   # per worker process: the GL context, loaded scenes, the uploaded scene


def timing_lock_path() -> Path:
    """The host's timing lock file: $GIBENCH_TIMING_LOCK, else gibench-timing.lock in the temp folder."""
    return Path(os.environ.get("GIBENCH_TIMING_LOCK") or Path(tempfile.gettempdir()) / "gibench-timing.lock")


@contextlib.contextmanager
def timing_lock(path: Path | None = None):
    """Hold the host's timing lock (an exclusive flock) for the block: one timed row per host at a
    time. Waiting releases the GIL (the worker keeps answering its scheduler); the kernel drops the
    lock when the holding process exits or is killed, so a dead holder never blocks the host."""
    import fcntl
    path = Path(path) if path is not None else timing_lock_path()
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CREAT, 0o644)   # flock needs no write access
    except OSError as exc:
        raise ValueError(f"timing lock {path}: cannot open it ({exc.strerror}); set GIBENCH_TIMING_LOCK") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def open_client(scheduler: str | None = None, workers: int | None = None):
    """(client, cluster or None): a client of `scheduler`, or of a new LocalCluster of `workers` processes."""
    from distributed import Client, LocalCluster
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


def _worker_context():
    if "ctx" not in _STATE:
        from bench.gl import create_context
        _STATE["ctx"] = create_context()
    return _STATE["ctx"]


def _worker_scene(ref):
    """A Scene from its reference: a corpus name or .toml path (loaded once per process) or the object."""
    if not isinstance(ref, str):
        return ref
    scenes = _STATE.setdefault("scenes", {})
    if ref not in scenes:
        from bench.corpus import load_scene
        scenes[ref] = load_scene(ref)
    return scenes[ref]


def _worker_gpu(ctx, scene, facts, seed: int):
    from bench.gl import GpuScene
    key = (scene.content_hash(), int(seed))
    held = _STATE.get("gpu")
    if held is not None and held[0] == key:
        return held[1]
    _release_shared()   # they belong to the held scene
    if held is not None:
        held[1].release()
    gpu = GpuScene(ctx, scene, seed=seed, facts=facts)
    _STATE["gpu"] = (key, gpu)
    return gpu


def _release_shared(keep=None) -> None:
    held = _STATE.setdefault("shared", {})
    for key in [k for k in held if keep is None or k[:-1] != keep]:
        held.pop(key).passes.release()


def _worker_shared(ctx, gpu, cfg, view: str, cls):
    """(shared passes, seconds spent building them): the view's shared passes lent to the row as
    the serial runner lends them (bench.runner.build_shared_passes: rendered and measured once),
    kept for this worker's next rows of the view; (None, 0) for a method that renders its own or
    when building them fails (the row then renders passes of its own, as in a serial run). A row
    needing a pass the held ones lack rebuilds them with the union of both rows' needs."""
    from bench.gl.passes import RSM_RESOLUTION, expand_needs, shared_variant
    from bench.runner import build_shared_passes, effective_shadow_resolution
    if not getattr(cls, "reuses_shared_passes", True):
        return None, 0.0
    try:
        needs = expand_needs(cls.needs)
        variant = shared_variant(needs)
    except ValueError:   # the row fails with this message in run_method
        return None, 0.0
    view_key = (gpu.scene.content_hash(), gpu.seed, view, cfg.width, cfg.height, effective_shadow_resolution(cfg),
                RSM_RESOLUTION)   # every input of the shared passes (none is per frame)
    _release_shared(keep=view_key)
    held = _STATE["shared"]
    current = held.get(view_key + (variant,))
    if current is not None and current.passes.serves(needs) is None:
        return current, 0.0
    if current is not None:
        needs = needs | (current.passes.needs - {"precompute"})
        held.pop(view_key + (variant,)).passes.release()
    t0 = time.perf_counter()
    try:
        shared = build_shared_passes(ctx, gpu, cfg, view, needs)
    except Exception:
        ctx.error   # clear a pending GL error: the row renders passes of its own
        return None, time.perf_counter() - t0
    held[view_key + (variant,)] = shared
    return shared, time.perf_counter() - t0


def render_task(cfg, scene_ref, view: str, method: str, params: dict) -> dict:
    """One row on a worker: render_outcome under the host's timing lock, with the view's shared
    passes measured once per worker (as a serial run does once per view), plus its wall time
    (`seconds`, without the scene upload and the shared passes' build: `upload_seconds`,
    `shared_seconds`) and, when this row built them, `shared_summary` {"scene/view": {variant:
    the measurement}} for the manifest."""
    from bench.registry import load_method
    from bench.runner import render_outcome
    from bench.scene import compute_facts
    scene = _worker_scene(scene_ref)
    ctx = _worker_context()
    cls = load_method(method)
    facts = _STATE.setdefault("facts", {}).get(scene.content_hash())
    if facts is None:
        facts = compute_facts(scene)
        _STATE["facts"][scene.content_hash()] = facts
    with timing_lock():
        t0 = time.perf_counter()
        gpu = _worker_gpu(ctx, scene, facts, cfg.seed)
        t1 = time.perf_counter()
        shared, shared_s = _worker_shared(ctx, gpu, cfg, view, cls)
        t2 = time.perf_counter()
        outcome = render_outcome(ctx, gpu, cfg, cls, scene, facts, view, params, shared=shared)
        outcome["seconds"] = time.perf_counter() - t2
        outcome["upload_seconds"] = t1 - t0
        outcome["shared_seconds"] = shared_s
        if shared is not None and shared_s > 0:
            from bench.gl.passes import shared_variant
            outcome["shared_summary"] = {f"{scene.name}/{view}": {shared_variant(cls.needs): shared.summary()}}
    outcome["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    return outcome


def reference_task(scene_ref, view: str, width: int, height: int, component: str, spp_cap: int) -> str:
    """A reference's first pass on a worker, into the shared reference cache; returns its key."""
    from reference.api import get_reference
    scene = _worker_scene(scene_ref)
    return get_reference(scene, view, width, height, component, spp_cap=spp_cap).key


def _reference_line(scene_ref, view: str, width: int, height: int, component: str, spp_cap: int, threads: int) -> str:
    from reference.api import _build_one
    return _build_one((_worker_scene(scene_ref), view, width, height, component, spp_cap, threads))


def build_references(scene_refs: list, width: int, height: int, spp_cap: int, scheduler: str | None = None,
                     workers: int | None = None, out=print) -> list[str]:
    """`gibench reference build`: every camera and component of every scene as a task (references
    may fill every core: no timing lock); one line per reference, in completion order."""
    from distributed import as_completed

    from bench.corpus import load_scene
    from reference.api import COMPONENTS, _check, load_mitsuba
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
