"""The run's manifest (`manifest.json`), and the only code that writes it.

It records the machine (GL renderer, CPU, stage clock), package versions, the git commit, the
arguments, the scene facts and purposes, and what each method of the run declared when it ran
(`methods`: version, summary, stages, needs, parameter declarations and defaults, quality
ladder), so that a report of an old run reads its labels and defaults from the run folder, not
from today's code. After the rows it adds the wall time of each phase, the shared passes'
measurements, peak memory per row, the harness overhead and the rows' waits for the host's timing
lock. Each invocation gets a `run_id` (the gate tells repetitions apart by it). Nothing else writes
it: `gibench report` records its own time in the report's folder, never in the run it reads.
"""
from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import sys
import uuid
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from bench.gl import gl_info
from bench.gl.profiler import default_clock
from bench.protocol import results as store
from bench.protocol.results import MANIFEST, load_manifest
from bench.protocol.registry import load_method
from bench.protocol.versioning import git_commit, method_version
from bench.run.config import RunConfig, effective_shadow_resolution

PACKAGES = ("gibench", "moderngl", "numpy", "pandas", "mitsuba", "drjit", "OpenImageIO", "trimesh")


def machine_info(ctx) -> dict:
    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    info = gl_info(ctx)
    info["stage_clock"] = default_clock(ctx)
    info.update({"cpu": cpu, "cores": os.cpu_count(), "python": sys.version.split()[0],
                 "platform": platform.platform()})
    return info


def package_versions() -> dict:
    out = {}
    for pkg in PACKAGES:
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = None
    return out


def _plain(value):
    """A declaration value as JSON can hold it (tuples as lists, numpy scalars as numbers)."""
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if hasattr(value, "item"):
        return value.item()
    return value


def method_declaration(cls) -> dict:
    """What a method class declares, as the manifest records it."""
    params = {name: {"default": _plain(p.default), "low": _plain(p.low), "high": _plain(p.high),
                     "choices": _plain(p.choices), "quality": bool(p.quality), "doc": p.doc}
              for name, p in cls.params.items()}
    return {"version": method_version(cls), "summary": cls.summary, "stages": list(cls.stages),
            "needs": sorted(cls.needs), "defaults": {k: v["default"] for k, v in params.items()},
            "ladder": [_plain(dict(r)) for r in getattr(cls, "ladder", ())], "params": params}


def method_declarations(methods) -> dict:
    """{name: declaration} of the run's methods that load (a failing one is a failed row, not here)."""
    out = {}
    for name in methods:
        try:
            out[name] = method_declaration(load_method(name))
        except Exception:
            continue
    return out


def write_manifest(run_dir: Path, ctx, cfg: RunConfig, scenes: dict, facts: dict, plan: dict | None = None) -> None:
    manifest = {
        "schema_version": store.SCHEMA_VERSION,
        "run_id": uuid.uuid4().hex,   # this invocation: a copy of the folder is the same run, a re-run is not
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "git_commit": git_commit(),
        "machine": machine_info(ctx),
        "versions": package_versions(),
        "arguments": {k: (str(v) if isinstance(v, Path) else v) for k, v in cfg.__dict__.items()
                      if k != "scenes"} | {"scenes": [getattr(s, "name", s) for s in cfg.scenes]},
        "scene_facts": {name: f.to_dict() for name, f in facts.items()},
        "scene_purposes": {name: s.purpose for name, s in scenes.items()},
        "shadow_resolution": effective_shadow_resolution(cfg),
        # an earlier run into the folder keeps its methods' declarations (its rows are kept too)
        "methods": {**((read_manifest(run_dir) or {}).get("methods") or {}), **method_declarations(cfg.methods)},
    }
    if plan is not None:   # the cost plan made before any work (bench.run.budget): predicted phases
        manifest["plan"] = plan
    store.atomic_write_text(Path(run_dir) / MANIFEST, json.dumps(manifest, indent=2, default=str))


def read_manifest(run_dir: Path) -> dict | None:
    """The run folder's manifest, None when it is absent or unreadable (nothing to add to)."""
    try:
        return load_manifest(run_dir) or None
    except (OSError, ValueError):
        return None


def _update(run_dir: Path, fn) -> None:
    manifest = read_manifest(run_dir)
    if manifest is None:
        return
    fn(manifest)
    store.atomic_write_text(Path(run_dir) / MANIFEST, json.dumps(manifest, indent=2, default=str))


TIMING_LOCK_CONTENDED_MS = 10.0   # a longer wait for the host's timing lock: another process was timing


def predicted_vs_actual(predicted: dict, actual: dict) -> dict:
    """The plan's predicted seconds beside the measured ones, per phase of the runner's accounting
    (the plan's shared passes are timed frames and preparation, counted under timing)."""
    pred = dict(predicted)
    pred["timing"] = pred.get("timing", 0.0) + pred.pop("shared_passes", 0.0)
    pred["setup"] = pred.get("setup", 0.0)
    act = dict(actual)
    act["setup"] = act.get("setup", 0.0) + act.pop("scene_upload", 0.0)
    out = {k: {"predicted_s": round(float(pred.get(k, 0.0)), 2), "actual_s": round(float(act.get(k, 0.0)), 2)}
           for k in dict.fromkeys([*pred, *act])}
    out["total"] = {"predicted_s": round(sum(float(v) for v in pred.values()), 2),
                    "actual_s": round(sum(float(v) for v in act.values()), 2)}
    return out


def record_phases(run_dir: Path, phases: dict, shared_summary: dict, rows: list[dict], plan=None) -> None:
    """Add the wall time of each phase, the shared passes' measurements, each rendered row's peak
    memory, the harness overhead over the rendered rows and their waits for the host's timing
    lock (`timing_lock`: rows that waited, seconds in all) to the manifest."""
    def add(manifest):
        manifest["phases_s"] = {k: round(v, 3) for k, v in phases.items()}
        if plan is not None:
            manifest["phases_predicted_vs_actual"] = predicted_vs_actual(plan.phases(), phases)
        if shared_summary:   # each view's shared passes, measured once, whose medians rows add
            manifest["shared_passes"] = shared_summary
        manifest["peak_rss_mb"] = {f"{r['scene']}/{r['view']}/{r['method']}@{r.get('image_dir', '').rsplit('/', 1)[-1]}":
                                   round(float(r["peak_rss_mb"]), 1) for r in rows if "peak_rss_mb" in r}
        rendered = [r for r in rows if r.get("status") == "ok" and "row_wall_ms" in r]
        total = sum(r["row_wall_ms"] for r in rendered)
        if total > 0:
            manifest["harness_overhead"] = round(phases["rows_other"] * 1e3 / total, 4)
        waits = [float(r["timing_lock_wait_ms"]) for r in rows
                 if r.get("status") == "ok" and isinstance(r.get("timing_lock_wait_ms"), (int, float))]
        manifest["timing_lock"] = {"rows_waited": sum(w > TIMING_LOCK_CONTENDED_MS for w in waits),
                                   "waited_s": round(sum(waits) / 1e3, 3)}
    _update(run_dir, add)
