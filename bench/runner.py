"""The runner: scenes x views x methods x parameter sets -> result rows, images, references.

For each row it builds the GPU scene, the shared passes the method needs, prepares the method
(untimed), renders warm-up + K timed frames (bench.harness), writes linear EXRs of direct,
indirect and combined, and appends one row to the run's results table (written atomically
after every row). A content-addressed row cache means a row whose scene content, method
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
    shadow_resolution: int = 1024

    def validate(self) -> None:
        for name, value, low, high in (("width", self.width, 8, 8192), ("height", self.height, 8, 8192),
                                       ("frames", self.frames, 1, 10000), ("warmup", self.warmup, 1, 1000)):
            if not (low <= int(value) <= high):
                raise ValueError(f"{name}={value} outside [{low}, {high}]")
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
               "shadow_resolution": cfg.shadow_resolution, "renderer": renderer, "stage_clock": stage_clock,
               "harness": harness_version()}
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()[:24]


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
    sets = cfg.params.get(method)
    if not sets:
        return [{}]
    return [dict(s) for s in sets]


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
        from bench.gl import create_context
        cfg = self.cfg
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
        try:
            for scene_name, view, method, index, pset in jobs:
                if progress is not None:
                    progress.set_description(f"{scene_name}/{view}/{method}")
                row = self._run_row(ctx, scenes[scene_name], facts[scene_name], view, method, pset,
                                    renderer, resumable, self.resolved.get((method, index)))
                if references is not None and not str(row["status"]).startswith("failed"):
                    references.evaluate(row, scenes[scene_name], view)
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
        for (scene_name, view), lit in self._view_lit.items():
            if not lit:
                self.log(f"gibench: warning: {scene_name}/{view}: every method rendered an all-black image "
                         f"(does camera '{view}' see a lit surface?)")
        if references is not None:
            references.finish()
        df = store.save_results(self.run_dir, self.kept + self.rows)
        self._state["finished"] = True
        self._write_state()
        from bench.summary import write_summary
        write_summary(self.run_dir)
        return df

    def _run_row(self, ctx, scene, facts, view, method_name, pset, renderer, resumable, resolved=None) -> dict:
        from bench.harness import run_method
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
            return self._failed(row, exc)
        row["params"] = store.params_json(params)
        row["method_version"] = version
        from bench.gl.profiler import default_clock
        key = row_cache_key(scene, view, method_name, version, params, cfg, renderer, default_clock(ctx))
        row["row_key"] = key
        image_dir = self.run_dir / "images" / scene.name / view / self._image_folder(method_name, params, cls)
        row["image_dir"] = str(image_dir.relative_to(self.run_dir))

        if (key, row["image_dir"]) in resumable and (image_dir / "combined.exr").is_file():
            self.counts["resumed"] += 1
            return dict(resumable[(key, row["image_dir"])], **row)
        cached = None if cfg.force else self._cache_lookup(key)
        if cached is not None:
            cached_row, cached_dir = cached
            image_dir.mkdir(parents=True, exist_ok=True)
            for comp in IMAGE_COMPONENTS:
                shutil.copyfile(cached_dir / f"{comp}.exr", image_dir / f"{comp}.exr")
            cached_row.update(row)  # measured values from the cache, every label from this run
            cached_row["status"] = "cached"
            self.counts["cached"] += 1
            return cached_row

        try:
            result = run_method(ctx, cls, scene, view, cfg.width, cfg.height, params, seed=cfg.seed,
                                warmup=cfg.warmup, frames=cfg.frames, facts=facts,
                                shadow_resolution=cfg.shadow_resolution)
        except SkipRow as exc:
            row["status"] = f"skipped: {exc}"
            self.counts["skipped"] += 1
            return row
        except Exception as exc:
            ctx.error  # clear a pending GL error so the next method starts clean
            return self._failed(row, exc)
        images = {"direct": result.direct, "indirect": result.indirect, "combined": result.combined}
        for comp, img in images.items():
            write_exr(image_dir / f"{comp}.exr", img)
        # a view is suspicious only when no method lights it: `direct` alone is black by design
        # where every lit surface is off screen (hidden_bounce, the far room of rooms)
        view_key = (scene.name, view)
        self._view_lit[view_key] = self._view_lit.get(view_key, False) or bool(np.any(np.asarray(result.combined) > 0))
        med, iqr = store.summarize_samples(result.frame_ms)
        row.update({"frame_ms": med, "frame_ms_iqr": iqr, "status": "ok",
                    "skipped_stages": json.dumps(list(result.skipped_stages)),
                    "samples.frame_ms": json.dumps([round(v, 4) for v in result.frame_ms]),
                    "samples.stage_ms": json.dumps({k: [round(v, 4) for v in vs] for k, vs in result.stage_ms.items()})})
        gpu_total = 0.0
        for stage, samples in result.stage_ms.items():
            m, _ = store.summarize_samples(samples)
            row[f"stage_ms.{stage}"] = m
            gpu_total += m
        for stage in result.skipped_stages:
            row.setdefault(f"stage_ms.{stage}", float("nan"))
        row["gpu_ms"] = gpu_total
        row["stage_clock"] = result.stage_clock
        for k, v in result.extra.items():
            if isinstance(v, (int, float, str, bool)):
                row[f"extra.{k}"] = v
        self.counts["ok"] += 1
        self._cache_store(key, row, image_dir)
        return row

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

    Two passes. `evaluate()` (per row) uses a first-pass reference of at most
    REFERENCE_FIRST_PASS_SPP samples per pixel (or the cap, if lower). `finish()` then refines,
    for each view, every component whose noise floor is above 1/10 of the best method's MSE
    against it (bounded by `reference_spp_cap`; the cache continues from the first pass) and
    re-evaluates that view's rows. Each row records the key, spp and noise floor of the
    references it was judged against. Without Mitsuba the run goes on: error columns stay
    empty (NaN), never zero, and the reason is logged once.
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

    def _reference(self, scene, view: str, component: str, target_mse: float | None = None):
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

    def _apply(self, row: dict, refs: dict) -> None:
        from bench.evaluation import evaluate_row
        for comp, ref in refs.items():
            if ref is not None:
                row[f"reference_key.{comp}"] = ref.key
                row[f"reference_noise_floor.{comp}"] = ref.noise_floor_mse
                row[f"reference_spp.{comp}"] = ref.spp
        if all(r is None for r in refs.values()):
            return
        image_dir = self.run_dir / row["image_dir"]
        images = {c: read_exr(image_dir / f"{c}.exr") for c in IMAGE_COMPONENTS}
        row.update(evaluate_row(images, {c: (r.mean if r is not None else None) for c, r in refs.items()}))

    def evaluate(self, row: dict, scene, view: str) -> None:
        if not str(row.get("status", "")).startswith(("ok", "cached")):
            return  # skipped rows have no images to judge
        refs = {c: self._reference(scene, view, c) for c in self.COMPONENTS}
        self._rows.setdefault((scene.name, view), []).append((row, scene))
        self._apply(row, refs)

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
        for (scene_name, view), rows in self._rows.items():
            scene = rows[0][1]
            refs = {c: self._refs.get((scene_name, view, c)) for c in self.COMPONENTS}
            images: dict = {}
            for row, _ in rows:
                for name in set(self.JUDGES.values()):
                    path = self.run_dir / row["image_dir"] / f"{name}.exr"
                    if path.is_file():
                        images.setdefault(name, []).append(read_exr(path))
            changed = False
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
                    changed = True
            if changed:
                for row, _ in rows:
                    self._apply(row, refs)

    def finish(self) -> None:
        self.refine()
        if self._curves:
            store.atomic_write_text(self.run_dir / "reference_curves.json", json.dumps(self._curves, default=_json_default))


def run(cfg: RunConfig, log=print):
    """Run and return (DataFrame, Runner)."""
    runner = Runner(cfg, log=log)
    df = runner.run()
    return df, runner
