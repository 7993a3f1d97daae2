"""Running a corpus beyond one process: rows and reference renders as dask.distributed tasks.

`gibench run --workers N` starts a `LocalCluster` of N worker processes (one thread each);
`--scheduler ADDRESS` uses an existing cluster. The runner (client side) plans every row,
answers resumed and cached rows itself, and submits the others as `render_task`s; each worker
process creates its EGL context once and keeps it, with the last scene it uploaded. Workers
return the measured fields and the images; the client writes the EXRs, the row cache and the
results table, so a distributed run folder has the same files as a serial one, rows in the
same order.

* Timing: a row's frames must not share a machine's cores with another row's. Every task holds
  the host's timing semaphore (`Semaphore(max_leases=1, name="gibench-timing-<host>")`) while it
  renders, so rows on one host run one at a time whatever the number of workers there, and rows
  on different hosts in parallel (a lab: one or more workers per GPU machine). The semaphore's
  leases expire when their holder dies, so a killed worker does not block the host.
* Failures: a task that raises is a `failed` row (the method's error, as in a serial run); a
  worker that dies loses only its task, which the scheduler retries (`retries=2`) elsewhere.
* References: after the rows, every (scene, view, component) first pass is a task of its own
  (no semaphore: references may fill every core), rendered into the content-addressed reference
  cache (written atomically), which the client then reads. On a multi-host cluster the cache
  folder (`GIBENCH_CACHE_DIR`) must be shared, or the client renders what it cannot find.
"""
from __future__ import annotations

import logging
import os
import socket
import time

_STATE: dict = {}   # per worker process: the GL context, loaded scenes, the uploaded scene


def timing_lock_name(host: str | None = None) -> str:
    return f"gibench-timing-{host or socket.gethostname()}"


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
    if held is not None:
        held[1].release()
    gpu = GpuScene(ctx, scene, seed=seed, facts=facts)
    _STATE["gpu"] = (key, gpu)
    return gpu


def render_task(cfg, scene_ref, view: str, method: str, params: dict) -> dict:
    """One row on a worker: render_outcome under the host's timing semaphore, plus its wall time."""
    from distributed import Semaphore

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
    with Semaphore(max_leases=1, name=timing_lock_name()):
        t0 = time.perf_counter()
        gpu = _worker_gpu(ctx, scene, facts, cfg.seed)
        t1 = time.perf_counter()
        outcome = render_outcome(ctx, gpu, cfg, cls, scene, facts, view, params)
        outcome["seconds"] = time.perf_counter() - t1
        outcome["upload_seconds"] = t1 - t0
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
    may fill every core: no timing semaphore); one line per reference, in completion order."""
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
