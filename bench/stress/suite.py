"""`gibench stress`: the numerical stability stress suite (issue #12).

Runs perturbed variants of corpus scenes through every method (bench.run.execute.render_outcome,
the function every row of every run is rendered through: bench.stress.case) and through the
Mitsuba references (reference.api.get_reference, the content-addressed cache), and writes one table row per (scene, perturbation, target), target
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

Perturbations (bench.stress.variants; `--quick` runs the marked subset, 32x24, 16 spp references):

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
  invalid     nan_vertex, ...        rejection    NaN / Inf input must raise SceneError, one line (bench.stress.invalid)
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
reported, not judged). A run that raises is a failure; SkipRow is "skipped". The figures:
bench.stress.figures.

"documented": a failure that the target's manual documents (bench.stress.limits). A method's manual
is its docstring (or a `stress_limits` ClassVar {pattern: reason}); a line

    Stress limit translate=1e+05R: float32 positions, shadow acne above 1e4 radii (change 0.3)

documents every perturbation whose name matches the fnmatch pattern (`translate=*`, `params:mu=*`);
the reason is the rest of that one line (a wrapped continuation is not read: keep it one line).
The references' manual is the docstring of the `reference` package and of reference.integrators.

Run folder: `stress.csv` (the table), `stress.json` (configuration, machine, fuzz outcome),
`images/<scene>/<variant>/<target>/*.exr`, and `stress.html`, the report page that `gibench stress`
(bench.cli.stress) builds from the folder after the suite (reports.stress.build_stress_report).
`--isolate` runs cases in a child process with a timeout and a memory cap (bench.stress.isolate;
`params`, the default of the full suite: the parameter extremes, where a count at its maximum may
exhaust the machine).
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from bench.gl import create_context, gl_info
from bench.model.corpus import load_scene
from bench.model.imageio import write_exr
from bench.model.scene import Scene, SceneError, check_path_name
from bench.protocol import results as store
from bench.protocol.method import resolve_params
from bench.protocol.registry import load_method
from bench.protocol.versioning import git_commit
from bench.protocol.vocabulary import REFERENCE_COMPONENTS, Status, failure_reason
from bench.run.manifest import package_versions
from bench.run.plan import RunFolderLock, default_run_dir, prepare_run_dir
from bench.stress import fuzz as stress_fuzz
from bench.stress.case import CaseResult, run_case
from bench.stress.figures import (error_of, image_changes, mean_change, pixel_counts, reference_mean_noise,
                                  reference_noise_change, relative_change)
from bench.stress.invalid import invalid_input_checks
from bench.stress.isolate import CASE_TIMEOUT_S, run_case_isolated
from bench.stress.limits import documented_limits, match_limit
from bench.stress.variants import Variant, param_variants, scene_variants

# the procedural scenes of the corpus (each isolates one difficulty; the real ones are too large for
# dozens of perturbed copies at interactive cost)
STRESS_SCENES = ("cornell_spot", "hidden_bounce", "big_floor", "sphere_inside", "rooms")
TOLERANCE_FLOOR = 0.01        # relative L1 change accepted for any image (float32 rounding, rasteriser ties)
NOISE_FACTOR = 3.0            # x the target's own noise (seed-to-seed, or reference variance)
QUICK_RESOLUTION = (32, 24)
FULL_RESOLUTION = (64, 48)
QUICK_REFERENCE_SPP = 16
FULL_REFERENCE_SPP = 64
FAMILIES = ("determinism", "scale", "translate", "degenerate", "grazing", "params", "invalid", "fuzz")
COLUMNS = ("scene", "view", "family", "perturbation", "kind", "target", "name", "params", "status", "nan_pixels",
           "inf_pixels", "negative_pixels", "min_value", "change", "change_indirect", "mean_change", "error_base", "error",
           "error_change", "tolerance", "criterion", "verdict", "note", "image_dir")


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
        """Fill the defaults and check every value (ValueError, one line): None means the default,
        never 0 or an empty list."""
        w, h = QUICK_RESOLUTION if self.quick else FULL_RESOLUTION
        self.width = int(w if self.width is None else self.width)
        self.height = int(h if self.height is None else self.height)
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
        if not (isinstance(self.case_timeout, (int, float)) and 0 < self.case_timeout < float("inf")):
            raise ValueError(f"--timeout {self.case_timeout!r} must be a number of seconds above 0")
        if self.fuzz_examples is None:
            self.fuzz_examples = 50 if self.quick else 500
        if not (isinstance(self.fuzz_examples, int) and self.fuzz_examples >= 1):
            raise ValueError(f"--fuzz-examples {self.fuzz_examples!r} must be an integer >= 1")
        if not (isinstance(self.seed, int) and self.seed >= 0):
            raise ValueError(f"--seed {self.seed!r} must be an integer >= 0")
        for what, names in (("scene", [s for s in self.scenes if isinstance(s, str)]),
                            ("method", [m for m in self.methods if isinstance(m, str)]),
                            ("view", list(self.views or ())), ("family", list(self.families or ()))):
            repeated = sorted({n for n in names if names.count(n) > 1})
            if repeated:
                raise ValueError(f"{what} {repeated[0]!r} is given twice")
            if what in ("method", "view"):   # folders of the run: images/<scene>/<variant>/<method>
                for name in names:
                    check_path_name(name, f"{what} name")
        if self.views is not None and not self.views:
            raise ValueError("--views: no view given")
        if self.families is not None and not self.families:
            raise ValueError("--only: no family given")
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
    """One run of the suite: its configuration, its run folder and the table's rows so far."""

    def __init__(self, cfg: StressConfig, log=print):
        self.cfg = cfg.resolve()
        self.log = log
        if cfg.out:
            self.run_dir = Path(cfg.out)
        else:
            stamp = default_run_dir(Path("runs"))
            self.run_dir = stamp.with_name("stress-" + stamp.name)
        prepare_run_dir(self.run_dir)
        self.lock = RunFolderLock(self.run_dir)   # one owner of the folder, as a run's
        self.rows: list[dict] = []
        self.references_off: str | None = None if cfg.references else "disabled (--no-reference)"
        self.fuzz: dict | None = None

    # -------------------------------------------------------------- inputs
    def _methods(self) -> list:
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
                refs[comp] = Status.failed(failure_reason(exc))
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
        if Status.kind(status) == Status.SKIPPED:
            row["verdict"] = "skipped"
            return
        problems = []
        if status != Status.OK:
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
        self.lock.acquire()
        try:
            return self._run()
        finally:
            self.lock.release()

    def _run(self) -> pd.DataFrame:
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
        return self.finish(ctx)

    def _unperturbed(self, ctx, scene, view, methods) -> dict:
        """Each method's unperturbed images (seed s), its seed s + 1 images (its noise) and a row
        that checks determinism: the same seed twice must give the same image."""
        cfg = self.cfg
        base: dict = {}
        for mname, cls in methods:
            if isinstance(cls, Exception):
                self._row(scene.name, view, "load", "load", "robustness", "method", mname,
                          status=Status.failed(failure_reason(cls)), verdict="fail",
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
                row.update(image_changes(again.images, res.images))
                row["tolerance"] = 0.0
            self._judge(row, documented_limits(cls), {"change": 0.0, "change_indirect": 0.0, "mean_change": 0.0})
        return base

    def _tolerances(self, base_entry) -> tuple[float, float, float, str]:
        """Tolerances of change, change_indirect and |mean_change|: the floor or the method's own
        seed-to-seed figures times NOISE_FACTOR."""
        res, noisy = base_entry
        if noisy is None or noisy.images is None:
            return TOLERANCE_FLOOR, TOLERANCE_FLOOR, TOLERANCE_FLOOR, f"floor {TOLERANCE_FLOOR:g}"
        noise = image_changes(noisy.images, res.images)
        n_comb, n_ind, n_mean = noise["change"], noise["change_indirect"], abs(noise["mean_change"])
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
            row["image_dir"] = self._save_images(f"images/{scene.name}/{folder_name(variant_name)}/{mname}",
                                                 res.images)
            if compare_image and base_res is not None and base_res.images is not None:
                row.update(image_changes(res.images, base_res.images))
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
                      status=Status.failed(failure_reason(exc)), verdict="fail",
                      criterion="the perturbed scene builds")
            return
        invariance = variant.kind == "invariance"
        if variant.family == "degenerate":
            self._row(scene.name, view, variant.name, variant.family, variant.kind, "scene", "scene model",
                      status=Status.OK, verdict="pass", criterion="information",
                      note=f"{pscene.triangle_count - scene.triangle_count:+d} triangles, "
                           f"{pscene.dropped_degenerate} dropped as zero-area, "
                           f"{pscene.dropped_duplicates} dropped as repeated")
        refs = self._align_references(scene, pscene, view, base_refs)
        ref_limits = documented_limits("reference")
        for comp in REFERENCE_COMPONENTS if refs is not None else ():
            ref, b = refs[comp], (base_refs or {}).get(comp)
            row = self._row(scene.name, view, variant.name, variant.family, variant.kind, "reference", comp,
                            status=Status.OK if not isinstance(ref, str) else ref, criterion="finite, >= 0")
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
                      status=Status.failed(failure_reason(exc)), verdict="fail",
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
                      status=Status.OK if problem is None else Status.failed(problem),
                      verdict="pass" if problem is None else "fail",
                      criterion="SceneError, one line, naming the culprit", note=problem or "")

    def _fuzz(self) -> None:
        try:
            import hypothesis  # noqa: F401
        except ImportError:
            self._row("-", "-", "toml_fuzz", "fuzz", "property", "scene reader", "load_scene_file",
                      status=Status.skipped("hypothesis is not installed"), verdict="skipped")
            return
        self.log(f"gibench stress: fuzzing the scene file reader ({self.cfg.fuzz_examples} examples)")
        with tempfile.TemporaryDirectory(prefix="gibench-fuzz-") as tmp:
            self.fuzz = stress_fuzz.run_fuzz(self.cfg.fuzz_examples, Path(tmp), seed=self.cfg.seed)
        failure = self.fuzz["failure"]
        note = (f"{self.fuzz['examples']} examples: {self.fuzz['scenes']} scenes, {self.fuzz['errors']} one-line errors"
                if failure is None else f"{failure['problem']} on {failure['document']!r} with mesh {failure['mesh']}")
        self._row("-", "-", "toml_fuzz", "fuzz", "property", "scene reader", "load_scene_file",
                  status=Status.OK if failure is None else Status.failed(failure["problem"]),
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

    def finish(self, ctx) -> pd.DataFrame:
        """stress.csv and stress.json (configuration, the machine of GL context `ctx`, fuzz outcome,
        verdict counts). The page, stress.html, is built from the folder by `gibench stress`."""
        df = self._write_table()
        cfg = {k: (str(v) if isinstance(v, Path) else v) for k, v in self.cfg.__dict__.items()
               if k not in ("scenes", "methods")}
        cfg["scenes"] = [getattr(s, "name", s) for s in self.cfg.scenes]
        cfg["methods"] = [getattr(m, "name", m) for m in self.cfg.methods]
        meta = {"created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
                "git_commit": git_commit(), "config": cfg, "machine": gl_info(ctx),
                "versions": package_versions(), "references": self.references_off or "Mitsuba 3",
                "tolerance_floor": TOLERANCE_FLOOR, "noise_factor": NOISE_FACTOR, "fuzz": self.fuzz,
                "counts": summary_counts(df)}
        store.atomic_write_text(self.run_dir / "stress.json", json.dumps(meta, indent=2, default=str))
        return df


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


def folder_name(text: str) -> str:
    """A perturbation's name as a folder: a parameter's name and value come from a plugin's
    declarations, so anything outside the path-safe set is replaced and a hash of the whole name
    keeps two names apart (`params:mode=/../x` stays inside the run folder)."""
    safe = re.sub(r"[^A-Za-z0-9_.+=-]", "_", text).replace("..", "_")
    if safe == text.replace(":", "_"):
        return safe
    return f"{safe[:60]}@{hashlib.sha256(text.encode()).hexdigest()[:8]}"


def run_stress(cfg: StressConfig, log=print) -> tuple[pd.DataFrame, StressSuite]:
    suite = StressSuite(cfg, log=log)
    return suite.run(), suite
