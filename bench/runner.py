"""The runner: scenes x views x methods x parameter sets -> result rows, images, references.

Rows run grouped by scene and view. Each scene is uploaded once (GpuScene). Each view's shared
passes (GBuffer, shadow maps, direct light, RSM) are built once with the union of the needs of
the view's rows still to render, rendered and measured once (bench.harness.measure_shared_passes,
the rows' calibrated timing), and lent to every method and rung of the view: a row's frames
render only its method, and its frame time adds the measured medians of the shared stages it
needs (recorded in the row's `extra.shared_*` and in the manifest's `shared_passes`). For each
row the runner prepares the method (untimed), renders warm-up + K timed frames (bench.harness),
writes linear EXRs of direct, indirect and combined, and appends one row to the run's results
table (written atomically after every row). A content-addressed row cache means a row whose scene content, method
version, parameters, resolution, frames, seed and machine are unchanged is not re-run
(`force=True` re-runs); an interrupted run resumes from its results table.
A method that fails (to load, to prepare, to render) becomes a `failed: <reason>` row and the
run goes on with the others.

Trust rules:
* Row cache entries carry sha256 checksums of their row and images (`row.json`, format 2). A
  hit takes the measured values from the entry and every label (scene name, view, paths) from
  the current run; an entry that fails its checks is a miss, evicted with a one-line warning.
* Scene names are unique within a run (two scenes named alike are bad input, not a silent
  overwrite); a hit keyed on scene *content* therefore never mislabels a row.
* An existing `--out` is merged, not replaced: rows of the folder that this run does not
  produce (other methods, resolutions, parameter sets) are kept, and their images are moved
  aside when this run's rows need the same image folder. `run_state.json` records which rows
  the current invocation finished, so an interrupted `force=True` run resumes too (without
  `force`, every finished row of the folder is reused).
* Every `--param` is checked for every method before the first row; a `--param` of a method
  that is not in the run is bad input.
"""
from __future__ import annotations

import concurrent.futures
import datetime as _dt
import hashlib
import json
import os
import platform
import shutil
import sys
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench import results as store
from bench.imageio import read_exr, write_exr
from bench.method import SkipRow
from bench.registry import load_method
from bench.scene import SceneError, compute_facts
from bench.versioning import git_commit, harness_version, method_version

IMAGE_COMPONENTS = ("direct", "indirect", "combined")
RESUBMISSIONS = 2  # a Dask row whose task the cluster lost (not the row's own failure) is submitted again this often


def cache_root() -> Path:
    return Path(os.environ.get("GIBENCH_CACHE_DIR", Path.home() / ".cache" / "gibench"))


@dataclass
class RunConfig:
    scenes: list
    methods: list
    width: int = 128
    height: int = 96
    frames: int = 5
    warmup: int = 2
    seed: int = 0
    out: Path | None = None
    force: bool = False
    views: list | None = None                       # camera names; None: every camera of a scene
    params: dict = field(default_factory=dict)      # method -> list of param dicts (a grid of rows)
    references: bool = True                         # fetch/build Mitsuba references and metrics
    reference_spp_cap: int = 4096                   # refinement stops earlier, at 1/10 of the best MSE
    progress: bool = True
    shadow_resolution: int | None = None            # shadow map tile side; None: from the view (auto_shadow_resolution)
    ladders: bool = False                           # methods without --param run their quality ladder
    timing_budget_s: float | None = None            # calibrated timing (>= `frames` frames), None: `frames` exactly
    scheduler: str | None = None                    # a dask.distributed scheduler address (bench.distributed)
    workers: int | None = None                      # or a LocalCluster of this many worker processes

    def validate(self) -> None:
        for name, value, low, high in (("width", self.width, 8, 8192), ("height", self.height, 8, 8192),
                                       ("frames", self.frames, 1, 10000), ("warmup", self.warmup, 1, 1000)):
            if not (low <= int(value) <= high):
                raise ValueError(f"{name}={value} outside [{low}, {high}]")
        if self.timing_budget_s is not None and not (0.0 <= float(self.timing_budget_s) <= 3600.0):
            raise ValueError(f"timing budget {self.timing_budget_s} s outside [0, 3600]")
        if not self.scenes:
            raise ValueError("no scene given")
        if not self.methods:
            raise ValueError("no method given")


def machine_info(ctx) -> dict:
    from bench.gl import gl_info
    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    from bench.gl.profiler import default_clock
    info = gl_info(ctx)
    info["stage_clock"] = default_clock(ctx)
    info.update({"cpu": cpu, "cores": os.cpu_count(), "python": sys.version.split()[0],
                 "platform": platform.platform()})
    return info


def package_versions() -> dict:
    from importlib.metadata import PackageNotFoundError, version
    out = {}
    for pkg in ("gibench", "moderngl", "numpy", "pandas", "mitsuba", "drjit", "OpenImageIO", "trimesh"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = None
    return out


ROW_CACHE_FORMAT = 2  # row.json = {"format", "row", "row_sha256", "files": {name: sha256}}
RUN_STATE = "run_state.json"


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def row_sha256(row: dict) -> str:
    return hashlib.sha256(json.dumps(row, sort_keys=True, default=_json_default).encode()).hexdigest()


def row_identity(row: dict) -> tuple:
    """What makes two result rows the same row of a run folder (a re-run replaces it)."""
    def num(v):
        try:
            return int(float(v))
        except (TypeError, ValueError):
            return str(v)
    params = row.get("params")
    if isinstance(params, str):
        try:
            params = store.params_json(json.loads(params))
        except json.JSONDecodeError:
            pass
    return (str(row.get("scene")), str(row.get("view")), str(row.get("method")), str(params), num(row.get("seed")),
            num(row.get("width")), num(row.get("height")))


def row_cache_key(scene, camera: str, method: str, version: str, params: dict, cfg: RunConfig, renderer: str,
                  stage_clock: str = "") -> str:
    payload = {"scene": scene.content_hash(), "camera": camera, "camera_def": scene.cameras[camera].to_dict(),
               "method": method, "method_version": version, "params": params, "width": cfg.width,
               "height": cfg.height, "frames": cfg.frames, "warmup": cfg.warmup, "seed": cfg.seed,
               "shadow_resolution": effective_shadow_resolution(cfg), "renderer": renderer, "stage_clock": stage_clock,
               "harness": harness_version()}
    if cfg.timing_budget_s is not None:
        payload["timing_budget_s"] = cfg.timing_budget_s
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()[:24]


def auto_shadow_resolution(width: int, height: int) -> int:
    """Shadow map tile side matched to the view: the smallest power of two >= the image's longer
    side, within [256, 2048]. A cube face spans 90 degrees, a camera about 40-70, so a shadow texel
    then subtends about one screen pixel: shadow edges as sharp as the image can show, while a
    fixed 1024 made the shared shadow pass most of a frame on real scenes at 320x180 (12 faces of
    1024^2 on llvmpipe).

    A directional light's map spans the scene's bounding sphere, so the rule matches its texel to
    a pixel only at about the scene's size: sponza's sun at 320x180 has 8 cm texels against ~7 cm
    pixels at the camera's distance to the scene's centre, but the steep sun stretches them 2.7x
    on the walls, and the shadow lines there are the bulk of `direct`'s relMSE against Mitsuba
    (10.9 at 512^2, 3.1 at 2048^2 for a 7x longer frame on llvmpipe, `gibench run --scenes sponza
    --methods direct --shadow-resolution N`; a tight light-space fit would gain only 10-16% on
    sponza, whose plan is nearly square in light space). RunConfig.shadow_resolution sets it."""
    side = max(int(width), int(height), 1)
    return int(min(max(1 << (side - 1).bit_length(), 256), 2048))


def effective_shadow_resolution(cfg: "RunConfig") -> int:
    return int(cfg.shadow_resolution) if cfg.shadow_resolution else auto_shadow_resolution(cfg.width, cfg.height)


def default_run_dir(root: Path = Path("runs")) -> Path:
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    path = root / stamp
    n = 1
    while path.exists():
        n += 1
        path = root / f"{stamp}-{n}"
    return path


def point_latest(run_dir: Path) -> None:
    latest = run_dir.parent / "latest"
    tmp = run_dir.parent / f".latest.tmp{os.getpid()}"
    try:
        if tmp.is_symlink() or tmp.exists():
            tmp.unlink()
        tmp.symlink_to(run_dir.name)
        os.replace(tmp, latest)
    except OSError:
        pass


def expand_param_sets(cfg: RunConfig, method: str) -> list[dict]:
    """Parameter sets of `method` in this run: its --param grid, else (with `ladders`) its quality
    ladder (fast -> accurate, the defaults among the rungs), else the defaults alone."""
    sets = cfg.params.get(method)
    if sets:
        return [dict(s) for s in sets]
    if cfg.ladders:
        try:
            ladder = load_method(method).ladder
        except Exception:  # a method that fails to load becomes a failed row of its own
            ladder = ()
        if ladder:
            return [dict(s) for s in ladder]
    return [{}]


def reset_peak_rss() -> None:
    """Start a new peak-RSS window (Linux: writing 5 to clear_refs resets VmHWM); no-op elsewhere."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass


def peak_rss_mb() -> float:
    """The process's peak resident memory since the last reset_peak_rss (MB; the lifetime peak
    where the window cannot be reset)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    import resource
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def timing_budget(cfg: RunConfig):
    """The run's calibrated timing (bench.harness.TimingBudget), None for exactly `frames` frames."""
    from bench.harness import TimingBudget
    return None if cfg.timing_budget_s is None else TimingBudget(budget_s=float(cfg.timing_budget_s))


def build_shared_passes(ctx, gpu, cfg: RunConfig, view: str, needs):
    """One view's shared passes for `needs` (the union over the view's rows), built, rendered and
    measured once with the rows' timing settings (SharedViewPasses, passed to render_outcome)."""
    from bench.gl import SharedPasses
    from bench.harness import measure_shared_passes
    passes = SharedPasses(gpu, gpu.view(view, cfg.width, cfg.height), needs,
                          shadow_resolution=effective_shadow_resolution(cfg))
    try:
        return measure_shared_passes(ctx, passes, warmup=cfg.warmup, frames=cfg.frames, timing=timing_budget(cfg))
    except BaseException:
        passes.release()
        raise


def render_outcome(ctx, gpu, cfg: RunConfig, cls, scene, facts, view: str, params: dict, shared=None) -> dict:
    """Render one row, writing nothing: {"status": "ok", "measured": row fields, "images": {...}},
    {"status": "skipped", "reason"} or {"status": "failed", "reason"}. Runs in the runner's process
    or in a Dask worker (bench.distributed). `shared`: the view's shared passes, rendered and
    measured once (build_shared_passes); None renders them in each frame of the row."""
    from bench.harness import run_method
    timing = timing_budget(cfg)
    reset_peak_rss()
    try:
        result = run_method(ctx, cls, scene, view, cfg.width, cfg.height, params, seed=cfg.seed,
                            warmup=cfg.warmup, frames=cfg.frames, facts=facts,
                            shadow_resolution=effective_shadow_resolution(cfg), gpu=gpu, timing=timing,
                            shared=shared)
    except SkipRow as exc:
        return {"status": "skipped", "reason": str(exc)}
    except Exception as exc:
        ctx.error  # clear a pending GL error so the next method starts clean
        if os.environ.get("GIBENCH_DEBUG"):
            traceback.print_exc()
        return {"status": "failed", "reason": str(exc).splitlines()[0] if str(exc) else type(exc).__name__}
    med, iqr = store.summarize_samples(result.frame_ms)
    measured = {"frame_ms": med, "frame_ms_iqr": iqr, "status": "ok",
                "skipped_stages": json.dumps(list(result.skipped_stages)),
                "samples.frame_ms": json.dumps([round(v, 4) for v in result.frame_ms]),
                "samples.stage_ms": json.dumps({k: [round(v, 4) for v in vs] for k, vs in result.stage_ms.items()})}
    gpu_total = 0.0
    for stage, samples in result.stage_ms.items():
        m, _ = store.summarize_samples(samples)
        measured[f"stage_ms.{stage}"] = m
        gpu_total += m
    for stage in result.skipped_stages:
        measured.setdefault(f"stage_ms.{stage}", float("nan"))
    measured.update({"gpu_ms": gpu_total, "stage_clock": result.stage_clock, "prepare_ms": result.prepare_ms,
                     "frames_total_ms": result.frames_total_ms, "peak_rss_mb": peak_rss_mb()})
    for k, v in result.extra.items():
        if isinstance(v, (int, float, str, bool)):
            measured[f"extra.{k}"] = v
    images = {"direct": np.asarray(result.direct, np.float32), "indirect": np.asarray(result.indirect, np.float32),
              "combined": np.asarray(result.combined, np.float32)}
    return {"status": "ok", "measured": measured, "images": images}


class Runner:
    """Runs a RunConfig; `run()` returns the results DataFrame."""

    def __init__(self, cfg: RunConfig, log=print):
        cfg.validate()
        self.cfg = cfg
        self.log = log
        self.resolved = self._validate_params()
        self.run_dir = Path(cfg.out) if cfg.out else default_run_dir()
        _prepare_run_dir(self.run_dir)
        self.rows: list[dict] = []
        self.kept: list[dict] = []   # rows of the folder this run does not produce (merge)
        self.counts = {"ok": 0, "cached": 0, "resumed": 0, "failed": 0, "skipped": 0}
        self._view_lit: dict = {}   # (scene, view) -> did any rendered row have light
        self._gpu = None            # (scene name, GpuScene): uploaded once per scene, shared by its rows
        # the current view's shared passes: key -> SharedViewPasses (None: building failed, rows render their own)
        self._shared: dict = {}
        self._view_needs: dict = {}     # variant -> union of the needs of the current view's rows to render
        self.shared_summary: dict = {}  # "scene/view" -> variant -> measurement summary (manifest)
        self._scene_refs: dict = {}  # scene name -> what a worker loads it from (corpus name / path / Scene)
        # wall seconds per phase of the run (the manifest records them)
        self.phases = {"setup": 0.0, "scene_upload": 0.0, "precompute": 0.0, "timing": 0.0, "rows_other": 0.0,
                       "references": 0.0, "metrics": 0.0}

    def _validate_params(self) -> dict:
        """Every --param of every method, checked before the first row: {(method, i): resolved}."""
        from bench.method import resolve_params
        cfg = self.cfg
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

    # ------------------------------------------------------------------ setup
    def _load_scenes(self):
        """Corpus names, .toml scene files, or Scene objects (tests, scripts)."""
        from bench.scene import Scene
        scenes, given = {}, {}
        for item in self.cfg.scenes:
            if isinstance(item, Scene):
                scene = item
            else:
                from bench.corpus import load_scene
                scene = load_scene(item)
            what = str(item) if not isinstance(item, Scene) else (scene.source or "a Scene object")
            if scene.name in scenes:
                raise ValueError(f"two scenes are named '{scene.name}' ({given[scene.name]} and {what}): "
                                 f"scene names must be unique within a run")
            scenes[scene.name], given[scene.name] = scene, what
            self._scene_refs[scene.name] = item if isinstance(item, str) else scene
        return scenes

    def _write_manifest(self, ctx, scenes, facts) -> None:
        manifest = {
            "schema_version": store.SCHEMA_VERSION,
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "git_commit": git_commit(),
            "machine": machine_info(ctx),
            "versions": package_versions(),
            "arguments": {k: (str(v) if isinstance(v, Path) else v) for k, v in self.cfg.__dict__.items()
                          if k != "scenes"} | {"scenes": [getattr(s, "name", s) for s in self.cfg.scenes]},
            "scene_facts": {name: f.to_dict() for name, f in facts.items()},
            "scene_purposes": {name: s.purpose for name, s in scenes.items()},
            "shadow_resolution": effective_shadow_resolution(self.cfg),
        }
        store.atomic_write_text(self.run_dir / "manifest.json", json.dumps(manifest, indent=2, default=str))

    def _existing_table(self) -> list[dict]:
        """Rows already in the run folder (a corrupt table is an error, never silently dropped)."""
        try:
            df = store.load_results(self.run_dir)
        except FileNotFoundError:
            return []
        return df.to_dict("records")

    @staticmethod
    def _resumable(existing: list[dict], allowed: set | None) -> dict:
        """Finished rows of the folder by (row_key, image_dir); `allowed` limits them to those keys."""
        out = {}
        for rec in existing:
            key = (rec.get("row_key"), rec.get("image_dir"))
            if not isinstance(key[0], str) or not isinstance(key[1], str):
                continue
            if allowed is not None and f"{key[0]}|{key[1]}" not in allowed:
                continue
            if str(rec.get("status", "")).startswith(("ok", "cached", "skipped")):
                out[key] = rec
        return out

    def _invocation_hash(self, scenes) -> str:
        cfg = self.cfg
        payload = {k: v for k, v in cfg.__dict__.items() if k not in ("scenes", "progress", "out")}
        payload["scenes"] = [(name, s.content_hash()) for name, s in scenes.items()]
        return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()[:24]

    def _read_state(self) -> dict:
        try:
            state = json.loads((self.run_dir / RUN_STATE).read_bytes())
        except (OSError, ValueError):
            return {}
        return state if isinstance(state, dict) else {}

    def _write_state(self) -> None:
        store.atomic_write_text(self.run_dir / RUN_STATE, json.dumps(self._state, indent=1))

    def _merge_plan(self, existing: list[dict], jobs: list) -> None:
        """Keep the folder's rows this run does not produce; move their images out of the way of this run's."""
        produced = {ident for ident, _ in jobs}
        new_dirs = {image_dir for _, image_dir in jobs}
        for rec in existing:
            if row_identity(rec) in produced:
                continue
            image_dir = rec.get("image_dir")
            if isinstance(image_dir, str) and image_dir in new_dirs:
                tag = str(rec.get("row_key") or hashlib.sha256(repr(row_identity(rec)).encode()).hexdigest())[:8]
                moved = f"{image_dir}@{tag}"
                src, dst = self.run_dir / image_dir, self.run_dir / moved
                if src.is_dir() and not dst.exists():
                    shutil.move(str(src), str(dst))
                rec = dict(rec, image_dir=moved)
            self.kept.append(rec)
        if self.kept:
            self.log(f"gibench: {self.run_dir}: keeping {len(self.kept)} row(s) of earlier runs "
                     f"(other methods, resolutions or parameters)")

    def _job_identity(self, scene, view, method, index, pset) -> tuple:
        """(row identity, image dir) of a job, as the row will record them."""
        params = self.resolved.get((method, index), pset)
        row = {"scene": scene.name, "view": view, "method": method, "params": store.params_json(params),
               "seed": self.cfg.seed, "width": self.cfg.width, "height": self.cfg.height}
        folder = method
        if (method, index) in self.resolved:
            folder = self._image_folder(method, params, load_method(method))
        return row_identity(row), str(Path("images") / scene.name / view / folder)

    def _save(self) -> None:
        store.save_results(self.run_dir, self.kept + self.rows)

    # ------------------------------------------------------------------ main loop
    def run(self):
        import time
        from bench.gl import create_context
        cfg = self.cfg
        t_setup = time.perf_counter()
        ctx = create_context()
        scenes = self._load_scenes()
        facts = {name: compute_facts(s) for name, s in scenes.items()}
        self._write_manifest(ctx, scenes, facts)
        if cfg.out is None or self.run_dir.parent.name == "runs":
            point_latest(self.run_dir)
        renderer = ctx.info.get("GL_RENDERER", "")

        jobs = []
        for scene_name, scene in scenes.items():
            views = cfg.views or sorted(scene.cameras)
            for view in views:
                if view not in scene.cameras:
                    raise SceneError(f"scene '{scene_name}' has no camera '{view}'; cameras: {sorted(scene.cameras)}")
                for method in cfg.methods:
                    for index, pset in enumerate(expand_param_sets(cfg, method)):
                        jobs.append((scene_name, view, method, index, pset))

        existing = self._existing_table()
        self._merge_plan(existing, [self._job_identity(scenes[s], v, m, i, p) for s, v, m, i, p in jobs])
        invocation = self._invocation_hash(scenes)
        previous = self._read_state()
        if not cfg.force:
            resumable = self._resumable(existing, None)
        elif previous.get("invocation") == invocation and not previous.get("finished", True):
            # the same forced command, interrupted: its finished rows are not re-rendered
            resumable = self._resumable(existing, set(previous.get("done") or []))
        else:
            resumable = {}
        self._state = {"invocation": invocation, "finished": False, "done": []}
        self._write_state()

        progress = None
        if cfg.progress:
            from tqdm import tqdm
            progress = tqdm(total=len(jobs), unit="row", dynamic_ncols=True, file=sys.stderr)
        references = ReferenceProvider(self.run_dir, cfg, self.log) if cfg.references else None
        self.phases["setup"] += time.perf_counter() - t_setup
        if cfg.scheduler or cfg.workers:
            try:
                self._run_distributed(ctx, scenes, jobs, renderer, resumable, references, progress)
            finally:
                if progress is not None:
                    progress.close()
            jobs = []   # done
        try:
            for group in _view_groups(jobs):
                # plan the view's rows first: its shared passes serve the rows that still render
                plans = []
                for scene_name, view, method, index, pset in group:
                    t_plan = time.perf_counter()
                    planned = self._plan_row(ctx, scenes[scene_name], view, method, pset, renderer, resumable,
                                             self.resolved.get((method, index)))
                    plans.append((planned, time.perf_counter() - t_plan))
                self._open_view([planned for planned, _ in plans if not planned["done"]])
                for (scene_name, view, method, index, pset), (planned, plan_s) in zip(group, plans):
                    if progress is not None:
                        progress.set_description(f"{scene_name}/{view}/{method}")
                    t_row = time.perf_counter()
                    row = self._run_row(ctx, scenes[scene_name], facts[scene_name], view, method, pset,
                                        renderer, resumable, self.resolved.get((method, index)), planned=planned)
                    if references is not None and not str(row["status"]).startswith("failed"):
                        references.evaluate(row, scenes[scene_name], view)
                    self._account_row(row, plan_s + time.perf_counter() - t_row)
                    self.rows.append(row)
                    self._save()
                    if not str(row["status"]).startswith("failed") and isinstance(row.get("row_key"), str):
                        self._state["done"].append(f"{row['row_key']}|{row['image_dir']}")
                        self._write_state()
                    if progress is not None:
                        progress.update(1)
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
        df = store.save_results(self.run_dir, self.kept + self.rows)
        self._record_phases()
        self._state["finished"] = True
        self._write_state()
        from bench.summary import write_summary
        write_summary(self.run_dir)
        return df

    def _run_row(self, ctx, scene, facts, view, method_name, pset, renderer, resumable, resolved=None,
                 planned=None) -> dict:
        if planned is None:
            planned = self._plan_row(ctx, scene, view, method_name, pset, renderer, resumable, resolved)
        if planned["done"]:
            return planned["row"]
        import time
        gpu = self._scene_gpu(ctx, scene, facts)
        t_shared = time.perf_counter()
        shared = self._view_shared(ctx, gpu, view, planned["cls"])
        shared_s = time.perf_counter() - t_shared
        outcome = render_outcome(ctx, gpu, self.cfg, planned["cls"], scene, facts, view, planned["params"],
                                 shared=shared)
        row = self._finish_row(planned, outcome)
        row["_shared_seconds"] = shared_s   # the view's, not the row's own time (see _account_row)
        return row

    # ------------------------------------------------------------------ shared passes, once per view
    def _open_view(self, pending: list) -> None:
        """A new view: release the previous view's shared passes and note, per variant, the union
        of the needs of the rows about to render (built lazily, at the first of them)."""
        from bench.gl.passes import expand_needs, shared_variant
        self._release_shared()
        self._view_needs = {}
        for planned in pending:
            cls = planned["cls"]
            if not getattr(cls, "reuses_shared_passes", True):
                continue
            try:
                needs = expand_needs(cls.needs)
            except ValueError:  # the row fails with this message in run_method
                continue
            variant = shared_variant(needs)
            self._view_needs[variant] = self._view_needs.get(variant, frozenset()) | needs

    def _view_shared(self, ctx, gpu, view: str, cls):
        """The current view's shared passes for `cls` (built and measured at the first row that
        needs them), or None: a method that does not reuse them, or building them failed."""
        import time
        from bench.gl.passes import RSM_RESOLUTION, expand_needs, shared_variant
        if not getattr(cls, "reuses_shared_passes", True):
            return None
        try:
            variant = shared_variant(cls.needs)
        except ValueError:
            return None
        needs = self._view_needs.get(variant)
        if needs is None or not expand_needs(cls.needs) <= needs:
            return None
        cfg = self.cfg
        key = (gpu.scene.name, gpu.seed, view, cfg.width, cfg.height, effective_shadow_resolution(cfg),
               RSM_RESOLUTION, variant)   # every input of the shared passes (none is per frame)
        if key not in self._shared:
            t0 = time.perf_counter()
            try:
                self._shared[key] = build_shared_passes(ctx, gpu, cfg, view, needs)
            except Exception as exc:  # the view's rows render passes of their own, as without reuse
                ctx.error
                reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                self.log(f"gibench: {gpu.scene.name}/{view}: shared passes failed ({reason}); "
                         f"each row renders its own")
                self._shared[key] = None
                return None
            shared = self._shared[key]
            seconds = time.perf_counter() - t0
            self.phases["timing"] += shared.frames_total_ms / 1e3
            self.phases["precompute"] += max(seconds - shared.frames_total_ms / 1e3, 0.0)
            self.shared_summary.setdefault(f"{gpu.scene.name}/{view}", {})[variant] = shared.summary()
        return self._shared[key]

    def _release_shared(self) -> None:
        for shared in self._shared.values():
            if shared is not None:
                shared.passes.release()
        self._shared = {}

    def _run_distributed(self, ctx, scenes, jobs, renderer, resumable, references, progress) -> None:
        """Rows as Dask tasks (see bench.distributed); results kept in job order, references after."""
        import time
        from distributed import as_completed

        from bench import distributed as dist
        import dataclasses
        client, cluster = dist.open_client(self.cfg.scheduler, self.cfg.workers)
        try:
            # what a task needs of the configuration (not the scenes, sent once each)
            worker_cfg = dataclasses.replace(self.cfg, scenes=[], params={}, out=None)
            scene_refs = {name: (ref if isinstance(ref, str) else client.scatter(ref, broadcast=True))
                          for name, ref in self._scene_refs.items()}
            done: dict = {}
            futures = {}
            for i, (scene_name, view, method, index, pset) in enumerate(jobs):
                planned = self._plan_row(ctx, scenes[scene_name], view, method, pset, renderer, resumable,
                                         self.resolved.get((method, index)))
                if planned["done"]:
                    done[i] = planned["row"]
                    if progress is not None:
                        progress.update(1)
                    continue
                def submit(scene_name=scene_name, view=view, method=method, planned=planned, i=i, attempt=0):
                    return client.submit(dist.render_task, worker_cfg, scene_refs[scene_name], view, method,
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
                    reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                    outcome = {"status": "failed", "reason": f"worker lost: {reason}"}
                row = self._finish_row(planned, outcome)
                if outcome.get("status") == "ok":
                    method_s = (row["prepare_ms"] + row["frames_total_ms"]) / 1e3
                    self.phases["precompute"] += row["prepare_ms"] / 1e3
                    self.phases["timing"] += row["frames_total_ms"] / 1e3
                    self.phases["scene_upload"] += float(outcome.get("upload_seconds", 0.0))
                    # a worker's view passes, built and measured once per worker (as the serial path does per view)
                    self.phases["timing"] += float(outcome.get("shared_seconds", 0.0))
                    for view_key, variants in (outcome.get("shared_summary") or {}).items():
                        self.shared_summary.setdefault(view_key, {}).update(variants)
                    row_s = float(outcome.get("seconds", method_s))
                    self.phases["rows_other"] += max(row_s - method_s, 0.0)
                    row["row_wall_ms"] = row_s * 1e3
                    row["harness_overhead"] = max(row_s - method_s, 0.0) / row_s if row_s > 0 else float("nan")
                    row["worker"] = outcome.get("worker")
                done[i] = row
                self.rows = [done[k] for k in sorted(done)]
                self._save()
                if not str(row["status"]).startswith("failed") and isinstance(row.get("row_key"), str):
                    self._state["done"].append(f"{row['row_key']}|{row['image_dir']}")
                    self._write_state()
                if progress is not None:
                    progress.set_description(f"{row['scene']}/{row['view']}/{row['method']}")
                    progress.update(1)
            self.rows = [done[k] for k in sorted(done)]
            if references is not None:
                t0 = time.perf_counter()
                views = sorted({(r["scene"], r["view"]) for r in self.rows
                                if str(r.get("status", "")).startswith(("ok", "cached"))})
                cap = min(int(self.cfg.reference_spp_cap), ReferenceProvider.REFERENCE_FIRST_PASS_SPP)
                refs = [client.submit(dist.reference_task, scene_refs[s], v, self.cfg.width, self.cfg.height,
                                      comp, max(cap, 2), retries=2, pure=False)
                        for s, v in views for comp in ReferenceProvider.COMPONENTS]
                for fut in as_completed(refs):
                    try:
                        fut.result()
                    except Exception as exc:  # the client renders (or reports) it itself below
                        self.log(f"gibench: a reference task failed on its worker ({str(exc).splitlines()[0]})")
                self.phases["references"] += time.perf_counter() - t0
                for row in self.rows:
                    if not str(row["status"]).startswith("failed"):
                        references.evaluate(row, scenes[row["scene"]], row["view"])
                        row.pop("_reference_seconds", None)
                self._save()
        finally:
            dist.close_client(client, cluster)

    def _plan_row(self, ctx, scene, view, method_name, pset, renderer, resumable, resolved=None) -> dict:
        """The row's labels, key and image folder; a resumed, cached or failed-to-load row is done here
        ({"done": True, "row": row}), else {"done": False, ...} with what rendering it needs."""
        from bench.method import resolve_params
        cfg = self.cfg
        row = {"scene": scene.name, "scene_hash": scene.content_hash(), "view": view, "method": method_name,
               "params": store.params_json(pset), "seed": cfg.seed, "width": cfg.width, "height": cfg.height,
               "frames": cfg.frames, "warmup": cfg.warmup}
        try:
            cls = load_method(method_name)
            params = resolved if resolved is not None else resolve_params(cls, pset)
            version = method_version(cls)
        except Exception as exc:  # load failure or bad parameter: recorded, the run goes on
            return {"done": True, "row": self._failed(row, exc)}
        row["params"] = store.params_json(params)
        row["method_version"] = version
        from bench.gl.profiler import default_clock
        key = row_cache_key(scene, view, method_name, version, params, cfg, renderer, default_clock(ctx))
        row["row_key"] = key
        image_dir = self.run_dir / "images" / scene.name / view / self._image_folder(method_name, params, cls)
        row["image_dir"] = str(image_dir.relative_to(self.run_dir))

        if (key, row["image_dir"]) in resumable and (image_dir / "combined.exr").is_file():
            self.counts["resumed"] += 1
            return {"done": True, "row": dict(resumable[(key, row["image_dir"])], **row)}
        cached = None if cfg.force else self._cache_lookup(key)
        if cached is not None:
            cached_row, cached_dir = cached
            image_dir.mkdir(parents=True, exist_ok=True)
            for comp in IMAGE_COMPONENTS:
                shutil.copyfile(cached_dir / f"{comp}.exr", image_dir / f"{comp}.exr")
            cached_row.update(row)  # measured values from the cache, every label from this run
            cached_row["status"] = "cached"
            self.counts["cached"] += 1
            return {"done": True, "row": cached_row}
        return {"done": False, "row": row, "cls": cls, "params": params, "key": key, "image_dir": image_dir,
                "scene": scene, "view": view}

    def _finish_row(self, planned: dict, outcome: dict) -> dict:
        """Write a rendered row's images and cache entry (or record its skip / failure)."""
        row, image_dir = planned["row"], planned["image_dir"]
        if outcome["status"] == "skipped":
            row["status"] = f"skipped: {outcome['reason']}"
            self.counts["skipped"] += 1
            return row
        if outcome["status"] == "failed":
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
        self._cache_store(planned["key"], row, image_dir)
        return row

    # ------------------------------------------------------------------ shared scene upload, accounting
    def _scene_gpu(self, ctx, scene, facts):
        """The scene's GpuScene, uploaded once and shared by every row of the scene (rows run
        grouped by scene); the upload is a phase of its own, not part of any row's overhead."""
        import time
        from bench.gl import GpuScene
        if self._gpu is not None and self._gpu[0] == scene.name:
            return self._gpu[1]
        self._release_gpu()
        t0 = time.perf_counter()
        gpu = GpuScene(ctx, scene, seed=self.cfg.seed, facts=facts)
        ctx.finish()
        self.phases["scene_upload"] += time.perf_counter() - t0
        self._gpu = (scene.name, gpu)
        return gpu

    def _release_gpu(self) -> None:
        self._release_shared()
        if self._gpu is not None:
            self._gpu[1].release()
            self._gpu = None

    def _account_row(self, row: dict, seconds: float) -> None:
        """Split a rendered row's wall time into the method's part (prepare, every frame) and the
        harness's (read-back, EXR and cache writes, bookkeeping); reference fetches and metrics
        are phases of their own. `harness_overhead` = the harness's part / the row's time."""
        reference_s = float(row.pop("_reference_seconds", 0.0))
        shared_s = float(row.pop("_shared_seconds", 0.0))   # the view's shared passes: timing + precompute
        if row.get("status") != "ok":
            return
        method_s = (float(row.get("prepare_ms", 0.0)) + float(row.get("frames_total_ms", 0.0))) / 1e3
        row_s = seconds - reference_s - shared_s
        self.phases["precompute"] += float(row.get("prepare_ms", 0.0)) / 1e3
        self.phases["timing"] += float(row.get("frames_total_ms", 0.0)) / 1e3
        self.phases["rows_other"] += max(row_s - method_s, 0.0)
        row["row_wall_ms"] = row_s * 1e3
        row["harness_overhead"] = max(row_s - method_s, 0.0) / row_s if row_s > 0 else float("nan")

    def _record_phases(self) -> None:
        """Add the wall time of each phase (and the harness overhead over the rendered rows) to the manifest."""
        path = self.run_dir / "manifest.json"
        try:
            manifest = json.loads(path.read_text())
        except (OSError, ValueError):
            return
        manifest["phases_s"] = {k: round(v, 3) for k, v in self.phases.items()}
        if self.shared_summary:   # each view's shared passes, measured once, whose medians rows add
            manifest["shared_passes"] = self.shared_summary
        manifest["peak_rss_mb"] = {f"{r['scene']}/{r['view']}/{r['method']}@{r.get('image_dir', '').rsplit('/', 1)[-1]}":
                                   round(float(r["peak_rss_mb"]), 1) for r in self.rows if "peak_rss_mb" in r}
        rendered = [r for r in self.rows if r.get("status") == "ok" and "row_wall_ms" in r]
        total = sum(r["row_wall_ms"] for r in rendered)
        if total > 0:
            manifest["harness_overhead"] = round(self.phases["rows_other"] * 1e3 / total, 4)
        store.atomic_write_text(path, json.dumps(manifest, indent=2, default=str))

    @staticmethod
    def _image_folder(method_name: str, params: dict, cls) -> str:
        """`<method>` for default parameters, `<method>@<hash>` for other parameter sets."""
        defaults = {k: p.default for k, p in cls.params.items()}
        if params == defaults:
            return method_name
        return f"{method_name}@{hashlib.sha256(store.params_json(params).encode()).hexdigest()[:8]}"

    def _failed(self, row: dict, exc: Exception) -> dict:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        row["status"] = f"failed: {reason}"
        self.counts["failed"] += 1
        self.log(f"gibench: {row['scene']}/{row['view']}/{row['method']} failed: {reason}")
        if os.environ.get("GIBENCH_DEBUG"):
            traceback.print_exc()
        return row

    # ------------------------------------------------------------------ row cache
    def _cache_dir(self, key: str) -> Path:
        return cache_root() / "rows" / key[:2] / key

    def _cache_lookup(self, key: str):
        """(row, entry folder) of a verified cache entry, or None; a bad entry is evicted with a warning."""
        d = self._cache_dir(key)
        if not d.is_dir():
            return None
        problem = _cache_entry_problem(d)
        if problem is None:
            entry = json.loads((d / "row.json").read_bytes())
            return dict(entry["row"]), d
        shutil.rmtree(d, ignore_errors=True)
        self.log(f"gibench: warning: row cache entry {d} {problem}: evicted, the row is rendered again")
        return None

    def _cache_store(self, key: str, row: dict, image_dir: Path) -> None:
        d = self._cache_dir(key)
        tmp = d.with_name(d.name + f".tmp{os.getpid()}")
        try:
            if tmp.exists():
                shutil.rmtree(tmp)
            tmp.mkdir(parents=True)
            files = {}
            for comp in IMAGE_COMPONENTS:
                shutil.copyfile(image_dir / f"{comp}.exr", tmp / f"{comp}.exr")
                files[f"{comp}.exr"] = file_sha256(tmp / f"{comp}.exr")
            clean = json.loads(json.dumps(row, default=_json_default))
            entry = {"format": ROW_CACHE_FORMAT, "row": clean, "row_sha256": row_sha256(clean), "files": files}
            (tmp / "row.json").write_text(json.dumps(entry, default=_json_default))
            if d.exists():
                shutil.rmtree(d)
            os.replace(tmp, d)
        except OSError as exc:
            self.log(f"gibench: could not store row cache ({exc})")

    def summary(self) -> str:
        c = self.counts
        total = sum(c.values())
        parts = [f"{c['ok']} rendered", f"{c['cached']} from cache", f"{c['resumed']} resumed",
                 f"{c['skipped']} skipped", f"{c['failed']} failed"]
        msg = f"{total} rows: " + ", ".join(parts)
        if total and c["ok"] == 0 and c["failed"] == 0:
            msg += " (nothing re-run: every row was unchanged)"
        return msg


def _view_groups(jobs: list) -> list:
    """Consecutive jobs of one (scene, view): the runner's unit of shared passes."""
    groups: list = []
    for job in jobs:
        if groups and groups[-1][0][:2] == job[:2]:
            groups[-1].append(job)
        else:
            groups.append([job])
    return groups


def _cache_entry_problem(d: Path) -> str | None:
    """Why a row cache entry cannot be trusted (one phrase), or None when every checksum holds."""
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
    for comp in IMAGE_COMPONENTS:
        name = f"{comp}.exr"
        try:
            ok = files.get(name) == file_sha256(d / name)
        except OSError:
            return f"lacks {name}"
        if not ok:
            return f"has a damaged {name} (checksum mismatch)"
    return None


def _prepare_run_dir(run_dir: Path) -> None:
    """Create the run folder; an unusable --out is bad input (ValueError, one line)."""
    if run_dir.exists() and not run_dir.is_dir():
        raise ValueError(f"--out {run_dir} is a file, not a run folder")
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        probe = run_dir / f".write-test{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise ValueError(f"--out {run_dir} is not a writable folder ({exc.strerror or exc})") from None


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    return str(o)


class ReferenceProvider:
    """Fetches (or builds) the Mitsuba references of each view and adds error columns.

    Two passes. `evaluate()` (per row) fetches a first-pass reference of at most
    REFERENCE_FIRST_PASS_SPP samples per pixel (or the cap, if lower). `finish()` then refines,
    for each view, every component whose noise floor is above 1/10 of the best method's MSE
    against it (bounded by `reference_spp_cap`; the cache continues from the first pass) and
    only then computes every row's error columns, once, against the final references (metrics
    memoised by content in the cache: bench.evaluation). Each row records the key, spp and noise
    floor of the references it was judged against. Without Mitsuba the run goes on: error
    columns stay empty (NaN), never zero, and the reason is logged once.
    """

    COMPONENTS = ("direct", "indirect_unshadowed", "indirect_visible")
    # which method image each reference component judges (bench.evaluation.COMPARISONS)
    JUDGES = {"direct": "direct", "indirect_unshadowed": "indirect", "indirect_visible": "indirect"}
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
        import time
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
            try:
                from reference.api import ReferenceUnavailable, get_reference
            except ImportError as exc:
                self._unavailable = f"reference package unavailable ({exc})"
                self.log(f"gibench: {self._unavailable}; error columns left empty")
                self._refs[key] = None
                return None
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
                reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                self.log(f"gibench: reference {scene.name}/{view}/{component} failed: {reason}")
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
        if not str(row.get("status", "")).startswith(("ok", "cached")):
            return  # skipped rows have no images to judge
        import time
        t0 = time.perf_counter()
        for c in self.COMPONENTS:
            self._reference(scene, view, c)
        self._rows.setdefault((scene.name, view), []).append((row, scene))
        row["_reference_seconds"] = time.perf_counter() - t0   # not the row's own time (see Runner._account_row)

    def judge_all(self) -> None:
        """Every recorded row's error columns against the final references of its view. (In one
        process: a pool of one worker per core measured slower, 340 s against 240 s for the 336
        rows of the default run, HDR-FLIP already keeping the cores busy.)"""
        import time
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
            from tqdm import tqdm
            progress = tqdm(total=len(jobs), unit="row", dynamic_ncols=True, file=sys.stderr, desc="error metrics")
        memo = cache_root() / "metrics"
        try:
            for row, refs in jobs:
                row.update(judge_row(self.run_dir / row["image_dir"], refs, memo))
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
            from tqdm import tqdm
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
            store.atomic_write_text(self.run_dir / "reference_curves.json", json.dumps(self._curves, default=_json_default))


def judge_row(image_dir: Path, refs: dict, memo_dir) -> dict:
    """Error columns of one row (its image folder) against its view's references."""
    from bench.evaluation import evaluate_row
    images = {c: read_exr(Path(image_dir) / f"{c}.exr") for c in IMAGE_COMPONENTS}
    return evaluate_row(images, {c: (r.mean if r is not None else None) for c, r in refs.items()}, memo_dir=memo_dir)


def run(cfg: RunConfig, log=print):
    """Run and return (DataFrame, Runner)."""
    runner = Runner(cfg, log=log)
    df = runner.run()
    return df, runner
