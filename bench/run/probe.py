"""How fast this machine is, against the one the cost prior was fitted on (issue #29).

The shipped prior (bench/run/cost_prior.json) holds seconds measured on one machine; a machine
whose caches hold nothing yet (a fresh checkout, CI) has only the prior to predict a run with,
and a software rasteriser's speed differs several-fold between CPUs (llvmpipe's vector width:
a plan of 179 s on an AVX2 machine took 109 s on an AVX-512 one). So a plan first times two
small fixed workloads, each the median of a few repetitions, 1-2 seconds in all:

* `gl_s`: one method's frame on the GL pipeline (ir_unshadowed's gather of 256 VPLs over the shared passes'
  G-buffer, shadow map, direct light and reflective shadow map, on the procedural `cornell_spot`
  at 160x90, frames timed as a row times them): what the rendering phases scale with;
* `cpu_s`: the error metrics of one synthetic row at 96x96 (HDR-FLIP, CIEDE2000, SSIM, the
  decomposition): what the metrics and the harness's numpy work scale with.

`gibench cost-model --write` stores the fitting machine's probe in the prior's provenance;
`CostModel.local` scales the prior by this machine's probe over that one where the local caches
have measured nothing (bench.run.cost). The references are not scaled by it: Mitsuba's LLVM
backend already tracks the prior within ~10% across these machines, and they learn their own
scale from the runs' history.
"""
from __future__ import annotations

import json
import os
import platform
import statistics
import time

import numpy as np

from bench.protocol.vocabulary import FRAME_STAT_IMAGES

PROBE_SCENE, PROBE_CAMERA, PROBE_SIZE = "cornell_spot", "main", (160, 90)
PROBE_METHOD, PROBE_PARAMS = "ir_unshadowed", {"vpl_count": 256}   # a 40 ms frame on llvmpipe, 2 cores
PROBE_FRAMES = 5
CPU_SIZE, CPU_REPEATS = 96, 3

_MEASURED: dict = {}   # per process: a run plans once, the tests many times


def _gl_seconds(ctx) -> float:
    from bench.model.corpus import load_scene
    from bench.protocol.registry import load_method
    from bench.run.harness import run_method
    scene = load_scene(PROBE_SCENE)
    cls = load_method(PROBE_METHOD)
    width, height = PROBE_SIZE
    result = run_method(ctx, cls, scene, PROBE_CAMERA, width, height, dict(PROBE_PARAMS), seed=0, warmup=1,
                        frames=PROBE_FRAMES)
    return float(np.median(result.frame_ms)) / 1e3


def _synthetic_row(size: int):
    rng = np.random.default_rng(0)
    base = (rng.random((size, size, 3)) ** 2).astype(np.float32)
    refs = {"direct": base, "indirect_unshadowed": base * 0.5, "indirect_visible": base * 0.4}
    images = {"direct": base * 1.1, "indirect": base * 0.45, "combined": base * 1.55}
    stats = {name: (rng.random((size, size, 3)) * 0.1).astype(np.float32) for name in FRAME_STAT_IMAGES}
    return images, refs, stats


def _cpu_seconds() -> float:
    from bench.analysis import evaluation
    images, refs, stats = _synthetic_row(CPU_SIZE)
    evaluation.evaluate_row(images, refs, frame_stats=stats, error_frames=4)   # imports, the compiled FLIP loaded
    times = []
    for _ in range(CPU_REPEATS):
        evaluation._PREPARED.clear()   # the references' side too, as a view's first row pays it
        t0 = time.perf_counter()
        evaluation.evaluate_row(images, refs, frame_stats=stats, error_frames=4)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def machine_probe(ctx) -> dict:
    """{"gl_s": ..., "cpu_s": ...} of this machine (measured once per process; `ctx` a GL context)."""
    if not _MEASURED:
        _MEASURED.update(gl_s=_gl_seconds(ctx), cpu_s=_cpu_seconds())
    return dict(_MEASURED)


def machine_key(ctx) -> str:
    """What names this machine's speed: the host, its cores and its GL renderer."""
    renderer = ctx.info.get("GL_RENDERER", "") if ctx is not None else ""
    return f"{platform.node()}|{os.cpu_count()}|{renderer}"


def stored_machine_probe(ctx) -> dict:
    """This machine's probe, measured once and kept in the cache (`<cache>/cost/machine_probe.json`,
    keyed by machine_key): every later plan on the machine scales the prior by the same figures, so a
    budget keeps the same rows run after run (bench.run.budget.make_plan), as a per-run measurement
    would not at the budget's edge (a shared host's probe read 0.022-0.040 s within an hour)."""
    from bench.run.config import cache_root
    path, key = cache_root() / "cost" / "machine_probe.json", machine_key(ctx)
    try:
        stored = json.loads(path.read_text())
    except (OSError, ValueError):
        stored = {}
    if not isinstance(stored, dict):
        stored = {}
    kept = stored.get(key)
    if isinstance(kept, dict) and all(isinstance(kept.get(k), (int, float)) and kept[k] > 0 for k in ("gl_s", "cpu_s")):
        return {"gl_s": float(kept["gl_s"]), "cpu_s": float(kept["cpu_s"])}
    measured = machine_probe(ctx)
    stored[key] = measured
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps(stored, indent=1, sort_keys=True))
        os.replace(tmp, path)
    except OSError:   # a read-only cache: measured again next time
        pass
    return measured


def speed_ratios(here: dict | None, fitted: dict | None) -> dict:
    """{"gl": ..., "cpu": ...}: this machine's probe seconds over the fitting machine's (1 where
    either is missing or not positive): above 1 this machine is slower."""
    out = {}
    for key in ("gl", "cpu"):
        a, b = (here or {}).get(f"{key}_s"), (fitted or {}).get(f"{key}_s")
        ok = all(isinstance(v, (int, float)) and v > 0 for v in (a, b))
        out[key] = float(a) / float(b) if ok else 1.0
    return out
