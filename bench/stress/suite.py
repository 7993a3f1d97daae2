"""`gibench stress`: the numerical stability stress suite (issue #12).

Runs perturbed variants of corpus scenes through every method (bench.run.harness.run_method, the
runner's own machinery) and through the Mitsuba references (reference.api.get_reference, the
content-addressed cache), and writes one table row per (scene, perturbation, target), target
being a method or a reference component:

* `nan_pixels`, `inf_pixels`, `negative_pixels`: pixels with a NaN / infinite / negative channel
  (a method's direct and indirect images together; a reference component's mean);
* `change`, `change_indirect`: relative L1 change sum|I - I0| / sum|I0| of the combined (a
  reference: the component) and the indirect image against the unperturbed case I0 (same
  method, default parameters, same seed);
* `mean_change`: mean(I) / mean(I0) - 1 (signed), the bias a per-pixel figure hides in noise;
* `error`, `error_base`, `error_change`: relMSE of the combined image against the Mitsuba
  reference (direct + indirect_visible) of the perturbed and of the unperturbed scene, and
  error / error_base - 1;
* `tolerance`, `criterion`, `verdict` (pass / fail / documented / skipped).

Perturbations (`--quick` runs the marked subset, 32x24, 16 spp references):

  family      name                   kind         what
  determinism repeat                 invariance   the unperturbed case again, same seed (every figure exactly 0)
  scale       scale=1e-04 .. 1e+04   invariance   every position x s, point/spot intensity x s^2   (quick: 1e-04, 1e+04)
  translate   translate=1e+03R ..    invariance   moved by 1e3 .. 1e5 scene radii                  (quick: 1e+04R)
  degenerate  zero_area, sliver,     invariance   injected on 32 host triangles (bench.stress.perturb) (quick: sliver, t_junction)
              duplicate, flipped, t_junction, coplanar
  grazing     grazing_camera,        robustness   a view along the largest plane; lights on a surface (quick: grazing_camera)
              grazing_light
  params      params:NAME=VALUE      robustness   each declared Param at its low and high end, each
                                                  choice, the other boolean (quick: quality knobs at their low end)
  invalid     nan_vertex, ...        rejection    NaN / Inf input must raise SceneError, one line
  fuzz        toml_fuzz              property     hypothesis fuzzing of the TOML reader (bench.stress.fuzz)

`--only FAMILY,...` runs some families (the unperturbed renders always run: they are the baseline).

Verdicts. Every image must have no NaN, Inf or negative pixel. An *invariance* must also keep
the image: `change` (and a method's `change_indirect`) and |`mean_change`| within the row's
tolerances. A method's are max(TOLERANCE_FLOOR, NOISE_FACTOR x the same figure between its
seed s and seed s + 1 renders of the unperturbed scene), so a stochastic method is judged
against its own noise; a reference's are max(TOLERANCE_FLOOR, NOISE_FACTOR x the expected
figure for two independent estimates, from the two variance images). The `repeat` row renders
the unperturbed case twice with the same seed: every figure must be exactly 0. A *robustness*
perturbation only requires finite, non-negative images (its change and error figures are
reported, not judged). A run that raises is a failure; SkipRow is "skipped".

"documented": a failure that the target's manual documents. A method's manual is its docstring
(or a `stress_limits` ClassVar {pattern: reason}); a line

    Stress limit translate=1e+05R: float32 positions, shadow acne above 1e4 radii (change 0.3)

documents every perturbation whose name matches the fnmatch pattern (`translate=*`, `params:mu=*`);
the reason is the rest of that one line (a wrapped continuation is not read: keep it one line).
The references' manual is the docstring of the `reference` package and of reference.integrators.

Run folder: `stress.csv` (the table), `stress.json` (configuration, machine, fuzz outcome),
`stress.html` (the report page, reports/templates/stress.html), `images/<scene>/<variant>/<target>/*.exr`.
`isolate` runs cases in a child process with a timeout and a memory cap (`params`, the default of
the full suite: the parameter extremes, where a count at its maximum may exhaust the machine).
"""
from __future__ import annotations

import datetime as _dt
import fnmatch
import json
import os
import re
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from bench.stress import perturb
from bench.protocol.method import FrameOutput, SkipRow, resolve_params
from bench.model.scene import Scene, SceneError

# the procedural scenes of the corpus (each isolates one difficulty; the real ones are too large for
# dozens of perturbed copies at interactive cost)
STRESS_SCENES = ("cornell_spot", "hidden_bounce", "big_floor", "sphere_inside", "rooms")
TOLERANCE_FLOOR = 0.01        # relative L1 change accepted for any image (float32 rounding, rasteriser ties)
NOISE_FACTOR = 3.0            # x the target's own noise (seed-to-seed, or reference variance)
QUICK_RESOLUTION = (32, 24)
FULL_RESOLUTION = (64, 48)
QUICK_REFERENCE_SPP = 16
FULL_REFERENCE_SPP = 64
SHADOW_RESOLUTION = 512       # shared shadow maps: 8x the largest image side of the suite, a quarter of the runner's cost
CASE_TIMEOUT_S = 300.0
WORKER_MEMORY_BYTES = 6 << 30
REFERENCE_COMPONENTS = ("direct", "indirect_unshadowed", "indirect_visible")
FAMILIES = ("determinism", "scale", "translate", "degenerate", "grazing", "params", "invalid", "fuzz")
COLUMNS = ("scene", "view", "family", "perturbation", "kind", "target", "name", "params", "status", "nan_pixels",
           "inf_pixels", "negative_pixels", "min_value", "change", "change_indirect", "mean_change", "error_base", "error",
           "error_change", "tolerance", "criterion", "verdict", "note", "image_dir")


# ---------------------------------------------------------------------------- perturbations
@dataclass(frozen=True)
class Variant:
    """One scene perturbation: `build(scene, view) -> Scene`."""
    name: str
    family: str
    kind: str                   # "invariance" or "robustness"
    build: Callable
    quick: bool = False


def scene_variants(quick: bool) -> list[Variant]:
    out = []
    for s in (1e-4, 1e-2, 1e2, 1e4):
        out.append(Variant(f"scale={s:.0e}", "scale", "invariance",
                           lambda sc, v, s=s: perturb.scale(sc, s), quick=s in (1e-4, 1e4)))
    for k in (1e3, 1e4, 1e5):
        out.append(Variant(f"translate={k:.0e}R", "translate", "invariance",
                           lambda sc, v, k=k: perturb.translate(sc, k), quick=k == 1e4))
    for name, fn in perturb.DEGENERATE.items():
        out.append(Variant(name, "degenerate", "invariance", lambda sc, v, fn=fn: fn(sc),
                           quick=name in ("sliver", "t_junction")))
    out.append(Variant("grazing_camera", "grazing", "robustness", lambda sc, v: perturb.grazing_camera(sc, v), quick=True))
    out.append(Variant("grazing_light", "grazing", "robustness", lambda sc, v: perturb.grazing_light(sc)))
    return [v for v in out if v.quick or not quick]


def param_variants(cls, quick: bool) -> list[tuple[str, dict]]:
    """(name, overrides) of `cls`'s parameters at the ends of their declared ranges.

    Full: every numeric Param at its low and high end, every other choice, the other boolean.
    Quick: the quality knobs (the counts a user turns down first) at their low end."""
    out = []
    for pname, p in cls.params.items():
        if quick:
            if p.quality and p.low is not None and p.low != p.default:
                out.append((pname, p.low))
            continue
        if p.choices is not None:
            out += [(pname, c) for c in p.choices if c != p.default]
        elif isinstance(p.default, bool):
            out.append((pname, not p.default))
        else:
            for end in (p.low, p.high):
                if end is not None and end != p.default:
                    out.append((pname, int(end) if isinstance(p.default, int) else float(end)))
    return [(f"params:{k}={v:g}" if isinstance(v, float) else f"params:{k}={v}", {k: v}) for k, v in out]


# ---------------------------------------------------------------------------- image figures
def pixel_counts(*images) -> dict:
    """NaN / Inf / negative pixel counts over `images` together (a pixel counts once per image)."""
    nan = inf = neg = 0
    low = np.inf
    for img in images:
        a = np.asarray(img, dtype=np.float64)[..., :3]
        nan += int(np.isnan(a).any(axis=-1).sum())
        inf += int(np.isinf(a).any(axis=-1).sum())
        neg += int((a < 0).any(axis=-1).sum())
        finite = a[np.isfinite(a)]
        if finite.size:
            low = min(low, float(finite.min()))
    return {"nan_pixels": nan, "inf_pixels": inf, "negative_pixels": neg, "min_value": low if np.isfinite(low) else np.nan}


def finite(img) -> np.ndarray:
    return np.nan_to_num(np.asarray(img, dtype=np.float64)[..., :3], nan=0.0, posinf=0.0, neginf=0.0)


def relative_change(image, base) -> float:
    """sum |I - I0| / sum |I0| over every pixel and channel (non-finite values count as 0)."""
    a, b = finite(image), finite(base)
    if a.shape != b.shape:
        return float("nan")
    denom = float(np.abs(b).sum())
    diff = float(np.abs(a - b).sum())
    if denom == 0.0:
        return 0.0 if diff == 0.0 else float("inf")
    return diff / denom


def mean_change(image, base) -> float:
    """mean(I) / mean(I0) - 1 (signed; non-finite values count as 0)."""
    a, b = float(finite(image).mean()), float(finite(base).mean())
    if b == 0.0:
        return 0.0 if a == 0.0 else float("inf")
    return a / b - 1.0


def reference_mean_noise(base, other) -> float:
    """Standard deviation of mean(I) / mean(I0) - 1 for two independent estimates (variance images)."""
    n = np.asarray(base.variance).size
    var = float(np.asarray(base.variance, np.float64).sum() + np.asarray(other.variance, np.float64).sum()) / n ** 2
    denom = float(finite(base.mean).mean())
    return float(np.sqrt(var)) / denom if denom > 0 else 0.0


def reference_noise_change(base, other) -> float:
    """Expected relative L1 difference of two independent estimates (means + variance images)."""
    var = np.asarray(base.variance, np.float64) + np.asarray(other.variance, np.float64)
    denom = float(np.abs(finite(base.mean)).mean())
    if denom == 0.0:
        return 0.0
    return float(np.sqrt(2.0 / np.pi * var.mean())) / denom


def error_of(images: dict, refs: dict | None) -> dict:
    """relMSE of combined and indirect against the references (NaN without references)."""
    if not refs or any(refs.get(c) is None for c in REFERENCE_COMPONENTS):
        return {"combined": float("nan"), "indirect": float("nan")}
    from bench.analysis.evaluation import coverage_mask
    from bench.analysis.metrics import relmse
    imgs = {k: finite(v).astype(np.float32) for k, v in images.items()}
    imgs["combined"] = imgs["direct"] + imgs["indirect"]
    ref_means = {c: finite(refs[c].mean).astype(np.float32) for c in REFERENCE_COMPONENTS}
    mask = coverage_mask(imgs, ref_means)
    if not mask.any():
        return {"combined": float("nan"), "indirect": float("nan")}
    return {"combined": float(relmse(imgs["combined"], ref_means["direct"] + ref_means["indirect_visible"], mask)),
            "indirect": float(relmse(imgs["indirect"], ref_means["indirect_unshadowed"], mask))}


# ---------------------------------------------------------------------------- documented limits
# "Stress limit <pattern>: <reason>": the pattern may itself hold colons (params:NAME=VALUE), so
# it ends at the last colon followed by white space.
_LIMIT_LINE = re.compile(r"^\s*[-*]?\s*Stress limit\s+(\S+)\s*:\s+(.+?)\s*$", re.MULTILINE)


def documented_limits(target) -> dict:
    """{fnmatch pattern: reason} from a method class (docstring lines and `stress_limits`), or for
    the string "reference" from the reference package's docstrings."""
    texts, limits = [], {}
    if target == "reference":
        import importlib
        for mod in ("reference", "reference.integrators"):
            try:
                texts.append(importlib.import_module(mod).__doc__ or "")
            except Exception:  # a reference package that fails to import documents nothing
                pass
    else:
        # the manual is the method module's docstring; a class may also carry its own
        import sys
        module = sys.modules.get(getattr(target, "__module__", ""), None)
        texts.append(getattr(module, "__doc__", "") or "")
        texts.append(getattr(target, "__doc__", "") or "")
        limits.update(dict(getattr(target, "stress_limits", {}) or {}))
    for text in texts:
        for pattern, reason in _LIMIT_LINE.findall(text):
            limits.setdefault(pattern, reason)
    return limits


def match_limit(limits: dict, perturbation: str) -> str | None:
    for pattern, reason in limits.items():
        if fnmatch.fnmatchcase(perturbation, pattern):
            return reason
    return None


# ---------------------------------------------------------------------------- running one case
def _probe(cls):
    """A subclass of method `cls` that keeps frame 0's raw images (NaN and Inf included) and hands
    the harness finite ones, so NaN / Inf / negative pixels are counted instead of aborting."""
    from bench.run.harness import to_numpy

    def render(self, frame, prof):
        out = cls.render(self, frame, prof)
        if frame.index != 0:
            return out
        shape = (frame.height, frame.width, 3)
        raw = {"direct": to_numpy(out.direct, shape).copy(), "indirect": to_numpy(out.indirect, shape).copy()}
        type(self).raw = raw
        return FrameOutput(np.nan_to_num(raw["direct"], nan=0.0, posinf=0.0, neginf=0.0),
                           np.nan_to_num(raw["indirect"], nan=0.0, posinf=0.0, neginf=0.0),
                           out.skipped_stages, out.extra)

    probe = type(cls.__name__, (cls,), {"render": render, "raw": None, "__module__": cls.__module__,
                                         "__doc__": cls.__doc__})
    return probe


@dataclass
class CaseResult:
    status: str                       # "ok", "skipped: ...", "failed: ..."
    images: dict | None = None        # {"direct", "indirect"} raw float32 HxWx3


def run_case(ctx, cls, scene: Scene, view: str, width: int, height: int, params: dict, seed: int) -> CaseResult:
    """One method on one view through bench.run.harness.run_method (1 warm-up frame, 1 timed frame)."""
    from bench.run.harness import run_method
    probe = _probe(cls)
    try:
        run_method(ctx, probe, scene, view, width, height, params, seed=seed, warmup=1, frames=1,
                   shadow_resolution=SHADOW_RESOLUTION)
    except SkipRow as exc:
        return CaseResult(f"skipped: {exc}")
    except Exception as exc:
        ctx.error  # clear a pending GL error so the next case starts clean
        reason = " ".join(str(exc).split()) or type(exc).__name__
        return CaseResult(f"failed: {type(exc).__name__}: {reason}"[:300])
    if probe.raw is None:
        return CaseResult("failed: no frame rendered")
    return CaseResult("ok", probe.raw)


def run_case_isolated(spec: dict, timeout: float) -> CaseResult:
    """`run_case` in a child process (python -m bench.stress.suite SPEC.json) with a timeout and a memory cap."""
    with tempfile.TemporaryDirectory(prefix="gibench-stress-") as tmp:
        spec = dict(spec, out=str(Path(tmp) / "case.npz"))
        spec_path = Path(tmp) / "case.json"
        spec_path.write_text(json.dumps(spec))
        try:
            proc = subprocess.run([sys.executable, "-m", "bench.stress.suite", str(spec_path)], capture_output=True,
                                  text=True, timeout=timeout, env=dict(os.environ, PYTHONUNBUFFERED="1"))
        except subprocess.TimeoutExpired:
            return CaseResult(f"failed: timeout after {timeout:g} s")
        if proc.returncode < 0:
            return CaseResult(f"failed: crashed (signal {-proc.returncode})")
        if proc.returncode != 0:
            lines = [l for l in proc.stderr.strip().splitlines() if l.strip()]
            return CaseResult(f"failed: worker exit {proc.returncode}: {lines[-1] if lines else '?'}"[:300])
        result = json.loads((Path(tmp) / "case.json.out").read_text())
        if result["status"] != "ok":
            return CaseResult(result["status"])
        with np.load(spec["out"]) as z:
            return CaseResult("ok", {"direct": z["direct"], "indirect": z["indirect"]})


def _worker_main(spec_path: str) -> int:
    import resource
    try:
        resource.setrlimit(resource.RLIMIT_DATA, (WORKER_MEMORY_BYTES, WORKER_MEMORY_BYTES))
    except (ValueError, OSError):
        pass
    spec = json.loads(Path(spec_path).read_text())
    from bench.model.corpus import load_scene
    from bench.gl import create_context
    from bench.protocol.registry import load_method
    scene = load_scene(spec["scene"])
    if spec.get("variant"):
        variant = next(v for v in scene_variants(False) if v.name == spec["variant"])
        scene = variant.build(scene, spec["view"])
    res = run_case(create_context(), load_method(spec["method"]), scene, spec["view"], spec["width"],
                   spec["height"], spec["params"], spec["seed"])
    if res.images is not None:
        np.savez(spec["out"], **res.images)
    Path(spec_path + ".out").write_text(json.dumps({"status": res.status}))
    return 0


# ---------------------------------------------------------------------------- the suite
@dataclass
class StressConfig:
    scenes: list
    methods: list                               # registered names or method classes
    width: int | None = None
    height: int | None = None
    quick: bool = False
    out: Path | None = None
    seed: int = 0
    views: list | None = None                   # one camera per scene: "main" or the first, unless given
    references: bool = True
    reference_spp: int | None = None
    isolate: str | None = None                  # "none", "params" (full default), "all"
    case_timeout: float = CASE_TIMEOUT_S
    fuzz_examples: int | None = None
    families: list | None = None                # None: all of FAMILIES

    def resolve(self) -> "StressConfig":
        w, h = QUICK_RESOLUTION if self.quick else FULL_RESOLUTION
        self.width, self.height = int(self.width or w), int(self.height or h)
        for name, value in (("width", self.width), ("height", self.height)):
            if not 8 <= value <= 8192:
                raise ValueError(f"{name}={value} outside [8, 8192]")
        if self.reference_spp is None:
            self.reference_spp = QUICK_REFERENCE_SPP if self.quick else FULL_REFERENCE_SPP
        if int(self.reference_spp) < 2:
            raise ValueError(f"--reference-spp {self.reference_spp} must be >= 2")
        self.isolate = self.isolate or ("none" if self.quick else "params")
        if self.isolate not in ("none", "params", "all"):
            raise ValueError(f"--isolate {self.isolate!r} is not one of none, params, all")
        if self.fuzz_examples is None:
            self.fuzz_examples = 50 if self.quick else 500
        unknown = sorted(set(self.families or ()) - set(FAMILIES))
        if unknown:
            raise ValueError(f"--only: unknown famil{'y' if len(unknown) == 1 else 'ies'} {', '.join(unknown)} "
                             f"(known: {', '.join(FAMILIES)})")
        self.families = list(self.families or FAMILIES)
        if not self.scenes:
            raise ValueError("no scene given")
        if not self.methods:
            raise ValueError("no method given")
        return self


class StressSuite:
    def __init__(self, cfg: StressConfig, log=print):
        from bench.run.plan import default_run_dir, prepare_run_dir as _prepare_run_dir
        self.cfg = cfg.resolve()
        self.log = log
        if cfg.out:
            self.run_dir = Path(cfg.out)
        else:
            stamp = default_run_dir(Path("runs"))
            self.run_dir = stamp.with_name("stress-" + stamp.name)
        _prepare_run_dir(self.run_dir)
        self.rows: list[dict] = []
        self.references_off: str | None = None if cfg.references else "disabled (--no-reference)"
        self.fuzz: dict | None = None

    # -------------------------------------------------------------- inputs
    def _methods(self) -> list:
        from bench.protocol.registry import load_method
        out = []
        for m in self.cfg.methods:
            if isinstance(m, str):
                try:
                    out.append((m, load_method(m)))
                except Exception as exc:
                    out.append((m, exc))
            else:
                out.append((m.name, m))
        return out

    def _scene(self, item) -> tuple[Scene, str | None]:
        if isinstance(item, Scene):
            return item, None
        from bench.model.corpus import load_scene
        return load_scene(item), str(item)

    def _view(self, scene: Scene) -> str:
        for v in self.cfg.views or ():
            if v in scene.cameras:
                return v
        if self.cfg.views:
            raise SceneError(f"scene '{scene.name}' has none of the cameras {self.cfg.views}; cameras: {sorted(scene.cameras)}")
        return "main" if "main" in scene.cameras else sorted(scene.cameras)[0]

    # -------------------------------------------------------------- references
    def _references(self, scene: Scene, view: str, spp: dict | None = None) -> dict | None:
        """The three reference components of a view ({component: Reference or "failed: ..."}), each
        with at least `spp[component]` samples (default: the configured count)."""
        if self.references_off is not None:
            return None
        try:
            from reference.api import ReferenceUnavailable, get_reference
        except ImportError as exc:
            self.references_off = f"reference package unavailable ({exc})"
            self.log(f"gibench stress: {self.references_off}; reference rows left out")
            return None
        refs = {}
        for comp in REFERENCE_COMPONENTS:
            try:
                refs[comp] = get_reference(scene, view, self.cfg.width, self.cfg.height, comp,
                                           spp_cap=int((spp or {}).get(comp, self.cfg.reference_spp)))
            except ReferenceUnavailable as exc:
                self.references_off = str(exc).splitlines()[0] if str(exc) else "Mitsuba unavailable"
                self.log(f"gibench stress: {self.references_off}; reference rows left out")
                return None
            except Exception as exc:
                refs[comp] = f"failed: {type(exc).__name__}: {' '.join(str(exc).split())}"[:300]
        return refs

    # -------------------------------------------------------------- rows
    def _row(self, scene_name, view, variant_name, family, kind, target, name, **kw) -> dict:
        row = {c: np.nan for c in COLUMNS}
        row.update(scene=scene_name, view=view, family=family, perturbation=variant_name, kind=kind, target=target,
                   name=name, params="{}", note="", image_dir="")
        row.update(kw)
        self.rows.append(row)
        return row

    @staticmethod
    def _judge(row: dict, limits: dict, tolerances: dict | None = None) -> None:
        """Set row["verdict"] (and the note): skipped, pass, fail or documented."""
        status = str(row["status"])
        if status.startswith("skipped"):
            row["verdict"] = "skipped"
            return
        problems = []
        if status != "ok":
            problems.append(status)
        else:
            for col, what in (("nan_pixels", "NaN"), ("inf_pixels", "Inf"), ("negative_pixels", "negative")):
                if row[col] > 0:
                    problems.append(f"{int(row[col])} {what} pixels")
            for col, tol in (tolerances or {}).items():
                v = abs(float(row[col]))
                if not np.isnan(v) and not v <= tol:
                    problems.append(f"{col} {v:.3g} > {tol:.3g}")
        if not problems:
            row["verdict"] = "pass"
            return
        reason = match_limit(limits, str(row["perturbation"]))
        row["verdict"] = "documented" if reason else "fail"
        note = "; ".join(problems) + (f" (documented: {reason})" if reason else "")
        row["note"] = f"{note}; {row['note']}" if row["note"] else note

    def _save_images(self, rel: str, images: dict) -> str:
        from bench.model.imageio import write_exr
        for comp, img in images.items():
            write_exr(self.run_dir / rel / f"{comp}.exr", np.asarray(img, dtype=np.float32))
        return rel

    def _method_case(self, ctx, cls, scene, view, params, spec: dict | None, isolated: bool) -> CaseResult:
        cfg = self.cfg
        if isolated and spec is not None:
            return run_case_isolated(dict(spec, method=cls.name, params=params, view=view, width=cfg.width,
                                          height=cfg.height, seed=cfg.seed), cfg.case_timeout)
        return run_case(ctx, cls, scene, view, cfg.width, cfg.height, params, cfg.seed)

    # -------------------------------------------------------------- main loop
    def run(self) -> pd.DataFrame:
        from bench.gl import create_context
        cfg = self.cfg
        ctx = create_context()
        methods = self._methods()
        for item in cfg.scenes:
            scene, spec = self._scene(item)
            view = self._view(scene)
            self.log(f"gibench stress: {scene.name}/{view}: unperturbed")
            base_refs = self._references(scene, view)
            base = self._unperturbed(ctx, scene, view, methods)
            for variant in [v for v in scene_variants(cfg.quick) if v.family in cfg.families]:
                self._scene_variant(ctx, scene, spec, view, variant, methods, base, base_refs)
                self._write_table()
            for mname, cls in methods if "params" in cfg.families else ():
                if isinstance(cls, Exception):
                    continue
                for pname, overrides in param_variants(cls, cfg.quick):
                    self._param_variant(ctx, scene, spec, view, mname, cls, pname, overrides, base, base_refs)
                self._write_table()
        if "invalid" in cfg.families:
            self._invalid_inputs()
        if "fuzz" in cfg.families:
            self._fuzz()
        return self.finish()

    def _unperturbed(self, ctx, scene, view, methods) -> dict:
        """Each method's unperturbed images (seed s), its seed s + 1 images (its noise) and a row
        that checks determinism: the same seed twice must give the same image."""
        cfg = self.cfg
        base: dict = {}
        for mname, cls in methods:
            if isinstance(cls, Exception):
                self._row(scene.name, view, "load", "load", "robustness", "method", mname,
                          status=f"failed: {' '.join(str(cls).split())}"[:300], verdict="fail",
                          criterion="the method loads")
                continue
            res = run_case(ctx, cls, scene, view, cfg.width, cfg.height, {}, cfg.seed)
            noisy = again = None
            if res.images is not None:
                self._save_images(f"images/{scene.name}/unperturbed/{mname}", res.images)
                again = run_case(ctx, cls, scene, view, cfg.width, cfg.height, {}, cfg.seed)
                noisy = run_case(ctx, cls, scene, view, cfg.width, cfg.height, {}, cfg.seed + 1)
            base[mname] = (res, noisy)
            if "determinism" not in cfg.families:
                continue
            row = self._row(scene.name, view, "repeat", "determinism", "invariance", "method", mname,
                            status=again.status if again is not None else res.status,
                            criterion="finite, >= 0, change <= 0, change_indirect <= 0, |mean_change| <= 0 "
                                      "(the same seed twice gives the same image)")
            if again is not None and again.images is not None:
                row.update(pixel_counts(again.images["direct"], again.images["indirect"]))
                comb = lambda im: finite(im["direct"]) + finite(im["indirect"])
                row["change"] = relative_change(comb(again.images), comb(res.images))
                row["change_indirect"] = relative_change(again.images["indirect"], res.images["indirect"])
                row["mean_change"] = mean_change(comb(again.images), comb(res.images))
                row["tolerance"] = 0.0
            self._judge(row, documented_limits(cls), {"change": 0.0, "change_indirect": 0.0, "mean_change": 0.0})
        return base

    def _tolerances(self, base_entry) -> tuple[float, float, float, str]:
        """Tolerances of change, change_indirect and |mean_change|: the floor or the method's own
        seed-to-seed figures times NOISE_FACTOR."""
        res, noisy = base_entry
        if noisy is None or noisy.images is None:
            return TOLERANCE_FLOOR, TOLERANCE_FLOOR, TOLERANCE_FLOOR, f"floor {TOLERANCE_FLOOR:g}"
        comb = lambda r: finite(r.images["direct"]) + finite(r.images["indirect"])
        n_comb = relative_change(comb(noisy), comb(res))
        n_ind = relative_change(noisy.images["indirect"], res.images["indirect"])
        n_mean = abs(mean_change(comb(noisy), comb(res)))
        tols = [max(TOLERANCE_FLOOR, NOISE_FACTOR * n) for n in (n_comb, n_ind, n_mean)]
        return (*tols, f"max({TOLERANCE_FLOOR:g}, {NOISE_FACTOR:g} x seed-to-seed change "
                       f"{n_comb:.2g} / {n_ind:.2g} / {n_mean:.2g})")

    def _method_row(self, base_name, scene, view, variant_name, family, kind, mname, cls, res: CaseResult,
                    base_entry, refs, base_refs, params: dict, judge_change: bool, compare_image: bool) -> dict:
        row = self._row(base_name, view, variant_name, family, kind, "method", mname, status=res.status,
                        params=json.dumps(params, sort_keys=True))
        base_res = base_entry[0] if base_entry else None
        if res.images is not None:
            row.update(pixel_counts(res.images["direct"], res.images["indirect"]))
            row["image_dir"] = self._save_images(f"images/{scene.name}/{variant_name}/{mname}".replace(":", "_"),
                                                 res.images)
            if compare_image and base_res is not None and base_res.images is not None:
                comb = lambda im: finite(im["direct"]) + finite(im["indirect"])
                row["change"] = relative_change(comb(res.images), comb(base_res.images))
                row["change_indirect"] = relative_change(res.images["indirect"], base_res.images["indirect"])
                row["mean_change"] = mean_change(comb(res.images), comb(base_res.images))
            row["error"] = error_of(res.images, refs)["combined"]
            if base_res is not None and base_res.images is not None:
                row["error_base"] = error_of(base_res.images, base_refs)["combined"]
                if np.isfinite(row["error"]) and np.isfinite(row["error_base"]) and row["error_base"] > 0:
                    row["error_change"] = row["error"] / row["error_base"] - 1.0
        if base_res is not None and base_res.images is None:
            row["note"] = f"unperturbed case: {base_res.status}"
        tolerances = None
        if judge_change and base_res is not None and base_res.images is not None:
            tol_c, tol_i, tol_m, how = self._tolerances(base_entry)
            tolerances = {"change": tol_c, "change_indirect": tol_i, "mean_change": tol_m}
            row["tolerance"] = tol_c
            row["criterion"] = (f"finite, >= 0, change <= {tol_c:.3g}, change_indirect <= {tol_i:.3g}, "
                                f"|mean_change| <= {tol_m:.3g} ({how})")
        else:
            row["criterion"] = "runs; finite, >= 0"
        self._judge(row, documented_limits(cls), tolerances)
        return row

    def _scene_variant(self, ctx, scene, spec, view, variant: Variant, methods, base, base_refs) -> None:
        cfg = self.cfg
        self.log(f"gibench stress: {scene.name}/{view}: {variant.name}")
        try:
            pscene = variant.build(scene, view)
        except Exception as exc:
            self._row(scene.name, view, variant.name, variant.family, variant.kind, "scene", "perturbation",
                      status=f"failed: {type(exc).__name__}: {' '.join(str(exc).split())}"[:300], verdict="fail",
                      criterion="the perturbed scene builds")
            return
        invariance = variant.kind == "invariance"
        if variant.family == "degenerate":
            self._row(scene.name, view, variant.name, variant.family, variant.kind, "scene", "scene model",
                      status="ok", verdict="pass", criterion="information",
                      note=f"{pscene.triangle_count - scene.triangle_count:+d} triangles, "
                           f"{pscene.dropped_degenerate} dropped as zero-area, "
                           f"{pscene.dropped_duplicates} dropped as repeated")
        refs = self._align_references(scene, pscene, view, base_refs)
        ref_limits = documented_limits("reference")
        for comp in REFERENCE_COMPONENTS if refs is not None else ():
            ref, b = refs[comp], (base_refs or {}).get(comp)
            row = self._row(scene.name, view, variant.name, variant.family, variant.kind, "reference", comp,
                            status="ok" if not isinstance(ref, str) else ref, criterion="finite, >= 0")
            tolerances = None
            if not isinstance(ref, str):
                row.update(pixel_counts(ref.mean))
                row["note"] = f"{ref.spp} spp"
                if invariance and b is not None and not isinstance(b, str):
                    row["change"] = relative_change(ref.mean, b.mean)
                    row["mean_change"] = mean_change(ref.mean, b.mean)
                    noise, mean_noise = reference_noise_change(b, ref), reference_mean_noise(b, ref)
                    row["tolerance"] = max(TOLERANCE_FLOOR, NOISE_FACTOR * noise)
                    tol_m = max(TOLERANCE_FLOOR, NOISE_FACTOR * mean_noise)
                    tolerances = {"change": row["tolerance"], "mean_change": tol_m}
                    row["criterion"] = (f"finite, >= 0, change <= {row['tolerance']:.3g}, |mean_change| <= {tol_m:.3g} "
                                        f"(max({TOLERANCE_FLOOR:g}, {NOISE_FACTOR:g} x the expected difference of "
                                        f"two independent estimates, {noise:.2g} / {mean_noise:.2g}))")
            self._judge(row, ref_limits, tolerances)
        isolated = cfg.isolate == "all" and spec is not None
        for mname, cls in methods:
            if isinstance(cls, Exception):
                continue
            res = self._method_case(ctx, cls, pscene, view, {}, {"scene": spec, "variant": variant.name}, isolated)
            self._method_row(scene.name, pscene, view, variant.name, variant.family, variant.kind, mname, cls, res,
                             base.get(mname), refs, base_refs, {}, invariance, variant.name != "grazing_camera")

    def _align_references(self, scene, pscene, view, base_refs) -> dict | None:
        """The perturbed view's references at the unperturbed ones' sample counts. The cache may hold
        more samples for one of them: the other is then continued to the same count (in place in
        `base_refs`), so errors and changes compare estimates of equal noise."""
        valid = lambda r: r is not None and not isinstance(r, str)
        spp = {c: r.spp for c, r in (base_refs or {}).items() if valid(r)}
        refs = self._references(pscene, view, spp)
        if refs is None or base_refs is None:
            return refs
        more = {c: r.spp for c, r in refs.items() if valid(r) and valid(base_refs.get(c)) and r.spp > base_refs[c].spp}
        if more:
            upgraded = self._references(scene, view, {c: more.get(c, spp.get(c, self.cfg.reference_spp))
                                                      for c in REFERENCE_COMPONENTS})
            for c in more:
                if upgraded is not None and valid(upgraded.get(c)):
                    base_refs[c] = upgraded[c]
        return refs

    def _param_variant(self, ctx, scene, spec, view, mname, cls, pname, overrides, base, base_refs) -> None:
        try:
            resolve_params(cls, overrides)
        except Exception as exc:
            self._row(scene.name, view, pname, "params", "robustness", "method", mname,
                      status=f"failed: {' '.join(str(exc).split())}"[:300], verdict="fail",
                      params=json.dumps(overrides), criterion="a declared end of the range is accepted")
            return
        isolated = self.cfg.isolate in ("params", "all") and spec is not None
        self.log(f"gibench stress: {scene.name}/{view}: {mname} {pname}")
        res = self._method_case(ctx, cls, scene, view, overrides, {"scene": spec, "variant": None}, isolated)
        self._method_row(scene.name, scene, view, pname, "params", "robustness", mname, cls, res, base.get(mname),
                         base_refs, base_refs, overrides, False, True)

    # -------------------------------------------------------------- input rejection and fuzzing
    def _invalid_inputs(self) -> None:
        for name, problem in invalid_input_checks().items():
            self._row("-", "-", name, "invalid", "rejection", "scene model", "Scene / scene file reader",
                      status="ok" if problem is None else f"failed: {problem}",
                      verdict="pass" if problem is None else "fail",
                      criterion="SceneError, one line, naming the culprit", note=problem or "")

    def _fuzz(self) -> None:
        from bench.stress import fuzz as stress_fuzz
        try:
            import hypothesis  # noqa: F401
        except ImportError:
            self._row("-", "-", "toml_fuzz", "fuzz", "property", "scene reader", "load_scene_file",
                      status="skipped: hypothesis is not installed", verdict="skipped")
            return
        self.log(f"gibench stress: fuzzing the scene file reader ({self.cfg.fuzz_examples} examples)")
        with tempfile.TemporaryDirectory(prefix="gibench-fuzz-") as tmp:
            self.fuzz = stress_fuzz.run_fuzz(self.cfg.fuzz_examples, Path(tmp), seed=self.cfg.seed)
        failure = self.fuzz["failure"]
        note = (f"{self.fuzz['examples']} examples: {self.fuzz['scenes']} scenes, {self.fuzz['errors']} one-line errors"
                if failure is None else f"{failure['problem']} on {failure['document']!r} with mesh {failure['mesh']}")
        self._row("-", "-", "toml_fuzz", "fuzz", "property", "scene reader", "load_scene_file",
                  status="ok" if failure is None else f"failed: {failure['problem']}"[:300],
                  verdict="pass" if failure is None else "fail",
                  criterion="a Scene or one SceneError line naming the file", note=note)

    # -------------------------------------------------------------- output
    def _write_table(self) -> pd.DataFrame:
        """stress.csv, written atomically (after every perturbation, so a stopped suite keeps its rows)."""
        df = pd.DataFrame(self.rows, columns=list(COLUMNS))
        tmp = self.run_dir / f".stress.csv.tmp{os.getpid()}"
        df.to_csv(tmp, index=False)
        os.replace(tmp, self.run_dir / "stress.csv")
        return df

    def finish(self) -> pd.DataFrame:
        from bench.protocol import results as store
        from bench.run.manifest import package_versions
        from bench.protocol.versioning import git_commit
        df = self._write_table()
        cfg = {k: (str(v) if isinstance(v, Path) else v) for k, v in self.cfg.__dict__.items()
               if k not in ("scenes", "methods")}
        cfg["scenes"] = [getattr(s, "name", s) for s in self.cfg.scenes]
        cfg["methods"] = [getattr(m, "name", m) for m in self.cfg.methods]
        from bench.gl import create_context, gl_info
        meta = {"created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
                "git_commit": git_commit(), "config": cfg, "machine": gl_info(create_context()),
                "versions": package_versions(), "references": self.references_off or "Mitsuba 3",
                "tolerance_floor": TOLERANCE_FLOOR, "noise_factor": NOISE_FACTOR, "fuzz": self.fuzz,
                "counts": summary_counts(df)}
        store.atomic_write_text(self.run_dir / "stress.json", json.dumps(meta, indent=2, default=str))
        try:
            from reports.build import build_stress_report
        except ImportError:
            return df
        build_stress_report(self.run_dir)
        return df


def invalid_input_checks() -> dict:
    """{check name: None if bad input is rejected with one clear SceneError line, else the problem}."""
    from bench.model.scene import Camera, PointLight
    from bench.model.scenefile import load_scene_file
    out = {}
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    light, cam = [PointLight([0, 0, 1], 1.0)], {"main": Camera([0, 0, 3], [0, 0, 0])}

    def expect(name, fn, must_contain):
        try:
            fn()
        except SceneError as exc:
            msg = str(exc)
            if len(msg.splitlines()) != 1:
                out[name] = f"multi-line error {msg!r}"
            elif not any(word in msg for word in must_contain):
                out[name] = f"error does not name the culprit: {msg!r}"
            else:
                out[name] = None
            return
        except Exception as exc:
            out[name] = f"{type(exc).__name__} instead of SceneError: {' '.join(str(exc).split())}"
            return
        out[name] = "accepted"

    for label, value in (("nan", np.nan), ("inf", np.inf), ("-inf", -np.inf)):
        bad = v.copy()
        bad[1, 0] = value
        expect(f"{label}_vertex", lambda bad=bad: Scene.build("s", bad, [[0, 1, 2]], 0.5, light, cam), ("vertex 1",))
        expect(f"{label}_normal", lambda value=value: Scene.build("s", v, [[0, 1, 2]], 0.5, light, cam,
                                                                  normals=np.where(v == 1, value, 0.0) + [0, 0, 1]),
               ("normal",))
        expect(f"{label}_light", lambda value=value: PointLight([0, value, 1], 1.0), ("position",))
        expect(f"{label}_camera", lambda value=value: Camera([0, 0, value], [0, 0, 0]), ("eye",))
    with tempfile.TemporaryDirectory(prefix="gibench-invalid-") as tmp:
        d = Path(tmp)
        from bench.stress.fuzz import MESH_FILES, VALID_DOC, toml_document
        for mesh in ("nan_vertex", "inf_vertex"):
            (d / f"{mesh}.obj").write_text(MESH_FILES[mesh])
            doc = json.loads(json.dumps(VALID_DOC))
            doc["mesh"][0]["file"] = f"{mesh}.obj"
            (d / f"{mesh}.toml").write_text(toml_document(doc))
            expect(f"obj_{mesh}", lambda p=d / f"{mesh}.toml": load_scene_file(p), (f"{mesh}.obj",))
        (d / "m.obj").write_text(MESH_FILES["quad"])
        for key, where, value in (("translate", "mesh", float("nan")), ("scale", "mesh", float("inf")),
                                  ("position", "light", float("nan")), ("eye", "camera", float("-inf"))):
            doc = json.loads(json.dumps(VALID_DOC))
            table = doc["mesh"][0] if where == "mesh" else doc["light"][0] if where == "light" else doc["camera"]["main"]
            table[key] = [value, 0.0, 0.0] if key != "scale" else value
            path = d / f"toml_{key}.toml"
            path.write_text(toml_document(doc))
            expect(f"toml_{where}_{key}_nonfinite", lambda p=path: load_scene_file(p), (f"'{key}'",))
        for label, scale_value, shift, culprit in (("toml_mesh_huge_scale", 1e300, 0.0, "'scale'"),
                                                   ("toml_mesh_overflow", 1e29, 9.5e29, "vertex")):
            doc = json.loads(json.dumps(VALID_DOC))
            doc["mesh"][0]["scale"] = scale_value
            doc["mesh"][0]["translate"] = [shift, 0.0, 0.0]
            path = d / f"{label}.toml"
            path.write_text(toml_document(doc))
            expect(label, lambda p=path: load_scene_file(p), (culprit,))
        for label, table in (("light_direction", doc["light"][2]), ("camera_eye", doc["camera"]["main"])):
            doc = json.loads(json.dumps(VALID_DOC))
            key = "direction" if label == "light_direction" else "eye"
            (doc["light"][2] if label == "light_direction" else doc["camera"]["main"])[key] = [1e155, 0.0, 1.0]
            path = d / f"toml_{label}_overflow.toml"
            path.write_text(toml_document(doc))
            expect(f"toml_{label}_overflow", lambda p=path: load_scene_file(p), (f"'{key}'", key))
    return out


def summary_counts(df: pd.DataFrame) -> dict:
    return {k: int(v) for k, v in df["verdict"].value_counts().items()} if len(df) else {}


def summary_text(df: pd.DataFrame) -> str:
    """The verdict counts and one line per failing row."""
    counts = summary_counts(df)
    lines = [", ".join(f"{counts.get(k, 0)} {k}" for k in ("pass", "fail", "documented", "skipped"))]
    for r in df[df["verdict"] == "fail"].to_dict("records"):
        where = f"{r['scene']}/{r['perturbation']}" if r["scene"] != "-" else str(r["perturbation"])
        lines.append(f"FAIL {where} {r['target']} {r['name']}: {r['note'] or r['status']}")
    return "\n".join(lines)


def run_stress(cfg: StressConfig, log=print) -> tuple[pd.DataFrame, StressSuite]:
    suite = StressSuite(cfg, log=log)
    return suite.run(), suite


if __name__ == "__main__":
    sys.exit(_worker_main(sys.argv[1]))
