"""Reference API used by the runner and the CLI.

    get_reference(scene, view, width, height, component, spp_cap=256, target_mse=None) -> Reference
    build_references(scenes, width, height, processes, spp_cap)     (`gibench reference build`)

Convergence control: samples are added in batches that double the count (4, 4, 8, 16, ...),
each batch with its own deterministic seed; after each batch the noise floor (mean over
covered pixels of the per-pixel variance of the mean, i.e. the reference's own expected MSE)
is estimated, and rendering stops when it is <= `target_mse` (if given), exactly 0 (direct
light of delta emitters at pixel centres), or the count reaches `spp_cap`. The accumulated
moments are cached (reference.cache): a request the cache already satisfies renders nothing,
one asking for more continues from the stored moments.
"""
from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.model.scene import Scene, SceneError
from reference import cache
from reference.env import ReferenceUnavailable, load_mitsuba  # noqa: F401  (re-exported)
from reference.integrators import COMPONENTS, DEFAULT_MAX_LAYERS, EXTRA_COMPONENTS
from reference.render import PIXEL_SAMPLING, Moments, render_moments

FIRST_BATCH_SPP = 4
MIN_SPP = 2  # a variance estimate needs two samples


@dataclass
class Reference:
    """One converged (or capped) reference image of one component of one view."""
    component: str
    mean: np.ndarray            # HxWx3 float32, row 0 at the top
    variance: np.ndarray        # HxWx3 float32, variance of the mean estimate per pixel
    coverage: np.ndarray        # HxW bool, the primary ray hit a surface
    key: str
    spp: int
    noise_floor_mse: float      # mean over covered pixels of `variance`: the reference's own MSE
    curve: list = field(default_factory=list)   # [{"spp", "seconds", "mse_estimate"}] as spp grew
    seconds: float = 0.0        # wall seconds of all Mitsuba renders of this entry
    rendered_spp: int = 0       # samples per pixel rendered by this call (0: cache hit)
    variant: str = ""
    meta: dict = field(default_factory=dict)


_SCENES: dict = {}  # per-process cache of loaded Mitsuba scenes, keyed by (content, view, size)


def _mitsuba_view(mi, scene: Scene, view: str, width: int, height: int):
    from reference.convert import build_view
    key = (scene.content_hash(), view, width, height)
    if key not in _SCENES:
        if len(_SCENES) >= 4:
            _SCENES.pop(next(iter(_SCENES)))
        _SCENES[key] = build_view(mi, scene, view, width, height)
    return _SCENES[key]


_WARM: set = set()


def _warm_up(mi, mscene, component, width, height, pixel_sampling, max_layers, lights) -> None:
    """Render one untimed sample per pixel once per process and kernel shape, so Dr.Jit's
    kernel compilation is not counted in the convergence curve's seconds (the curve times
    the path tracer's steady state, as a method's frame time excludes shader compilation)."""
    key = (id(mscene), component, width, height, pixel_sampling, max_layers, lights is not None)
    if key in _WARM or not mi.variant().startswith(("llvm_", "cuda_")):
        return
    render_moments(mi, mscene, component, width, height, 1, 0xFFFFFFFF, 0, pixel_sampling, max_layers, lights)
    _WARM.add(key)


def key_payload(scene: Scene, view: str, width: int, height: int, component: str, settings: dict,
                mitsuba_version: str, variant: str) -> dict:
    return {"scene": scene.content_hash(), "scene_name": scene.name, "view": view,
            "camera": scene.cameras[view].to_dict(), "width": int(width), "height": int(height),
            "component": component, "settings": dict(sorted(settings.items())), "code": cache.code_version(),
            "mitsuba": mitsuba_version, "variant": variant}


def _check(scene, view, width, height, component, spp_cap, target_mse, pixel_sampling):
    if not isinstance(scene, Scene):
        raise TypeError(f"reference: expected a bench.model.scene.Scene, got {type(scene).__name__}")
    if view not in scene.cameras:
        raise SceneError(f"scene '{scene.name}' has no camera '{view}'; cameras: {sorted(scene.cameras)}")
    if component not in COMPONENTS + EXTRA_COMPONENTS:
        raise ValueError(f"reference: unknown component '{component}' (expected one of {', '.join(COMPONENTS)})")
    if not (8 <= int(width) <= 8192 and 8 <= int(height) <= 8192):
        raise ValueError(f"reference: resolution {width}x{height} outside [8, 8192]")
    if int(spp_cap) < MIN_SPP:
        raise ValueError(f"reference: spp_cap={spp_cap} must be >= {MIN_SPP} (a variance needs two samples)")
    if target_mse is not None and not (np.isfinite(target_mse) and target_mse >= 0):
        raise ValueError(f"reference: target_mse={target_mse} must be a finite number >= 0")
    if pixel_sampling not in PIXEL_SAMPLING:
        raise ValueError(f"reference: pixel_sampling '{pixel_sampling}' is not one of {PIXEL_SAMPLING}")


def _converged(moments: Moments, spp_cap: int, target_mse) -> bool:
    if moments.n >= spp_cap:
        return True
    if moments.n < MIN_SPP:
        return False
    floor = moments.noise_floor()
    return floor == 0.0 or (target_mse is not None and floor <= target_mse)


def get_reference(scene: Scene, view: str, width: int, height: int, component: str, spp_cap: int = 256,
                  target_mse: float | None = None, *, pixel_sampling: str = "center", seed: int = 0,
                  max_layers: int = DEFAULT_MAX_LAYERS, light_sampling: bool = True, cache_dir=None,
                  log=None) -> Reference:
    """The reference of one component of one view: from the cache, continued, or rendered.

    pixel_sampling: "center" (every sample through the pixel centre, like the rasteriser) or
    "box" (uniform over the pixel). light_sampling: combine BSDF and light sampling (MIS) in
    the one-bounce components (False: BSDF sampling only; both unbiased).

    Raises ReferenceUnavailable when Mitsuba cannot be used (the message says what to install).
    """
    _check(scene, view, width, height, component, spp_cap, target_mse, pixel_sampling)
    width, height, spp_cap = int(width), int(height), int(spp_cap)
    mi = load_mitsuba()
    settings = {"pixel_sampling": pixel_sampling, "seed": int(seed), "max_layers": int(max_layers),
                "light_sampling": bool(light_sampling)}
    payload = key_payload(scene, view, width, height, component, settings, mi.__version__, mi.variant())
    key = cache.cache_key(payload)
    root = None if cache_dir is None else Path(cache_dir)
    stored = cache.load(key, root)
    if stored is not None and stored[0].mean.shape == (height, width, 3):
        moments, meta = stored
    else:
        moments, meta = Moments.empty(width, height), {"payload": payload, "curve": [], "seconds": 0.0}
    curve, seconds = list(meta.get("curve", [])), float(meta.get("seconds", 0.0))
    rendered = 0
    mview = None
    while not _converged(moments, spp_cap, target_mse):
        batch = min(max(FIRST_BATCH_SPP, moments.n), spp_cap - moments.n)
        if mview is None:
            mview = _mitsuba_view(mi, scene, view, width, height)
            lights = mview.lights if light_sampling else None
            _warm_up(mi, mview.scene, component, width, height, pixel_sampling, max_layers, lights)
        t0 = time.perf_counter()
        new = render_moments(mi, mview.scene, component, width, height, batch, seed, moments.n, pixel_sampling,
                             max_layers, lights)
        seconds += time.perf_counter() - t0
        moments = moments.merge(new)
        rendered += batch
        curve.append({"spp": moments.n, "seconds": round(seconds, 6), "mse_estimate": moments.noise_floor()})
    if rendered:
        meta.update({"payload": payload, "key": key, "spp": moments.n, "curve": curve, "seconds": seconds,
                     "noise_floor_mse": moments.noise_floor(), "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())})
        cache.store(key, moments, meta, root)
        if log is not None:
            log(f"reference {scene.name}/{view}/{component}: {moments.n} spp ({rendered} rendered) in "
                f"{seconds:.2f} s, noise floor {moments.noise_floor():.3g}")
    variance = moments.variance_of_mean()
    return Reference(component=component, mean=moments.mean.astype(np.float32),
                     variance=np.nan_to_num(variance, nan=0.0).astype(np.float32), coverage=moments.coverage(),
                     key=key, spp=moments.n, noise_floor_mse=moments.noise_floor(), curve=curve,
                     seconds=seconds, rendered_spp=rendered, variant=mi.variant(), meta=meta)


# ---------------------------------------------------------------------------- bulk precompute
def stored_reference(scene: Scene, view: str, width: int, height: int, component: str, *,
                     pixel_sampling: str = "center", seed: int = 0, max_layers: int = DEFAULT_MAX_LAYERS,
                     light_sampling: bool = True, cache_dir=None) -> dict:
    """What the cache already holds of a reference, without rendering or verifying it (a cost
    plan's question): {"spp": samples stored (0: none), "seconds": the time they took, "noise_floor_mse"}."""
    mi = load_mitsuba()
    settings = {"pixel_sampling": pixel_sampling, "seed": int(seed), "max_layers": int(max_layers),
                "light_sampling": bool(light_sampling)}
    key = cache.cache_key(key_payload(scene, view, width, height, component, settings, mi.__version__, mi.variant()))
    meta = cache.peek_meta(key, None if cache_dir is None else Path(cache_dir)) or {}
    return {"spp": int(meta.get("spp", 0) or 0), "seconds": float(meta.get("seconds", 0.0) or 0.0),
            "noise_floor_mse": meta.get("noise_floor_mse")}


def _build_one(job):
    scene, view, width, height, component, spp_cap, threads = job
    try:
        if threads:
            import drjit as dr
            load_mitsuba()
            dr.set_thread_count(threads)
        ref = get_reference(scene, view, width, height, component, spp_cap=spp_cap)
        state = ("cached" if ref.rendered_spp == 0 else
                 "built" if ref.rendered_spp == ref.spp else f"continued from {ref.spp - ref.rendered_spp} spp")
        return (f"{scene.name}/{view}/{component}: {state}, {ref.spp} spp, {ref.seconds:.1f} s of rendering, "
                f"noise floor {ref.noise_floor_mse:.3g} (key {ref.key[:12]})")
    except ReferenceUnavailable:
        raise
    except Exception as exc:  # one bad scene does not stop the others
        return f"{scene.name}/{view}/{component}: failed: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"


def build_references(scenes, width: int, height: int, processes: int = 2, spp_cap: int = 256,
                     components=COMPONENTS, out=print) -> list[str]:
    """Precompute (or find cached) the references of every camera of every scene, in parallel
    processes (each with its own Mitsuba); prints one line per reference."""
    load_mitsuba()  # fail early, with the install message, before starting processes
    jobs = []
    processes = max(1, int(processes))
    threads = max(1, (os.cpu_count() or 1) // processes) if processes > 1 else 0
    for scene in scenes:
        for view in sorted(scene.cameras):
            for component in components:
                _check(scene, view, width, height, component, spp_cap, None, "center")
                jobs.append((scene, view, int(width), int(height), component, int(spp_cap), threads))
    lines = []
    if processes == 1 or len(jobs) <= 1:
        for job in jobs:
            lines.append(_build_one(job))
            out(f"reference {lines[-1]}")
        return lines
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor
    # spawn: Dr.Jit's thread pool and LLVM state do not survive fork
    with ProcessPoolExecutor(max_workers=processes, mp_context=mp.get_context("spawn")) as pool:
        for line in pool.map(_build_one, jobs):
            lines.append(line)
            out(f"reference {line}")
            sys.stdout.flush()
    return lines
