"""The run's cost model: what each phase of a run will take, predicted before any work (issue #29).

Three layers:
* What a row's cost scales with is declared by its method (`cost_terms`, beside its parameters:
  bench.protocol.cost) and extended here with the terms every row has (pixels, triangles).
* The shape of the cost is fitted from measured rows by non-negative least squares on relative
  error, one coefficient per term: a method's own frame time and its preparation per method;
  how the harness turns a frame time into the wall time of the timed frames (the calibrated
  timing budget), of the error frames and of the rest of a row (read-back, EXRs, cache) over all
  methods; the view's shared passes; the Mitsuba references per sample and pixel of each scene
  and component; the metrics per pixel. `gibench cost-model --fit RUNS... --write` fits it from
  run folders (results table + manifest) and writes `cost_prior.json`, shipped with the checkout:
  the prior, measured on the project's 2-core llvmpipe machine (its provenance is in the file).
* On the user's machine the prior is scaled by the timings the local caches already hold
  (`CostModel.local`): each method's frame and preparation by the median ratio of measured to
  predicted over its cached rows (over every cached row where a method has fewer than
  MIN_LOCAL_ROWS), the references by the cached references' own seconds, the metrics and the
  run's set-up by the history of earlier runs (`record_history`: predicted and actual phases of
  each finished run, `<cache>/cost/history.jsonl`).

Everything here is arithmetic on declared terms and measured seconds: nothing renders.
"""
from __future__ import annotations

import datetime as _dt
import json
import math
import os
import statistics
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.protocol.cost import CostFacts, base_terms
from bench.run.config import cache_root

PRIOR_FILE = Path(__file__).with_name("cost_prior.json")
MIN_LOCAL_ROWS = 3          # cached rows of a method before its own local scale is used
HISTORY_KEEP = 200          # runs kept in the history file
METRICS_PRIOR_S_PER_PIXEL = 1.5e-5   # before any run has measured them: ~0.9 s a row at 320x180
REFERENCE_FIRST_BATCH_SPP = 4   # reference.api.FIRST_BATCH_SPP
REFERENCE_FIRST_PASS_SPP = 64   # bench.run.references.ReferenceProvider.REFERENCE_FIRST_PASS_SPP
TIMED_MAX_FRAMES = 100      # bench.run.harness.TimingBudget.max_frames
SETUP_PRIOR_S = 12.0        # imports, GL context, scene loading, the plan (Mitsuba's import): the default corpus, cold


def history_file() -> Path:
    return cache_root() / "cost" / "history.jsonl"


# ---------------------------------------------------------------------------- a fitted linear form
@dataclass
class Linear:
    """seconds = const + sum(coef[t] * terms[t]); every coefficient >= 0."""
    coef: dict = field(default_factory=dict)
    const: float = 0.0

    def __call__(self, terms: dict) -> float:
        return self.const + sum(c * float(terms.get(t, 0.0)) for t, c in self.coef.items())

    def to_json(self) -> dict:
        return {"const": self.const, "coef": self.coef}

    @classmethod
    def from_json(cls, d: dict) -> "Linear":
        return cls(coef={k: float(v) for k, v in (d.get("coef") or {}).items()}, const=float(d.get("const", 0.0)))


def fit_linear(rows: list[dict], y: list[float], const: bool = True) -> Linear:
    """Non-negative least squares of y on the rows' terms, each equation weighted by 1/sqrt(y) (its
    squared error over y, as for counts), then rescaled so the rows' total is predicted exactly.
    A budget spends totals: on relative error (each row weighed alike) and rescaled to the median
    row, the fit let the many cheap rows of small scenes decide and predicted dss's real-scene rows
    at 0.16-0.3x (the default run's dss rows: 59 s predicted, 192 s measured); on absolute error the
    few 10 s rows would decide alone. Terms are scaled to unit norm first."""
    from scipy.optimize import nnls
    pairs = [(r, v) for r, v in zip(rows, y) if v is not None and math.isfinite(v) and v > 0]
    if not pairs:
        return Linear()
    names = sorted({t for r, _ in pairs for t in r})
    cols = names + (["__const"] if const else [])
    design = np.array([[float(r.get(t, 0.0)) for t in names] + ([1.0] if const else []) for r, _ in pairs])
    y = np.array([v for _, v in pairs])
    weight = 1.0 / np.sqrt(y)
    weighted = design * weight[:, None]
    norms = np.linalg.norm(weighted, axis=0)
    norms[norms == 0] = 1.0
    x, _ = nnls(weighted / norms, y * weight, maxiter=50 * len(cols))
    x = x / norms
    predicted = float((design @ x).sum())
    k = float(y.sum()) / predicted if predicted > 0 else 1.0
    coef = {t: k * float(v) for t, v in zip(cols, x) if t != "__const" and v > 0}
    return Linear(coef=coef, const=k * float(x[-1]) if const else 0.0)


# ---------------------------------------------------------------------------- one measured row
@dataclass
class Sample:
    """What a measured row tells the model."""
    method: str
    terms: dict             # base + declared terms
    own_frame_s: float      # the method's own frame (shared passes excluded)
    shared_frame_s: float   # the shared stages it was charged for
    prepare_s: float        # preparation, and the first frame's excess over a steady one (a method that converges there)
    frames_total_s: float   # wall of warm-up + timed frames, the first frame's excess excluded
    error_s: float | None   # wall of the error frames' statistics (read-backs, sums, untimed frames); None: unknown
    error_frames: int       # frames the error statistics were taken over (1: none)
    error_renders: int      # of those, read back (2 for a method whose frames are identical)
    timing_budget_s: float | None
    frames: int
    warmup: int
    other_s: float | None   # the row's wall beyond the method's parts (read-back, EXRs, cache)
    images: int             # EXRs the row wrote
    scene: str = ""
    error_rendered: int = 0  # of error_renders, rendered for the statistics alone (after the timed frames)
    stage_frames: int = 0    # frames rendered apart for the stage times (a finish-fenced stage clock)



def row_terms(cls, params: dict, size: CostFacts) -> dict | None:
    """The terms of a row (None: its method's guard skips it)."""
    declared = cls.cost_terms(params, size)
    if declared is None:
        return None
    return {**base_terms(size), **{k: float(v) for k, v in declared.items()}}


def error_renders(cls, params: dict, error_frames: int) -> int:
    if error_frames <= 1:
        return 0
    try:
        identical = bool(cls.frames_identical(params))
    except Exception:
        identical = False
    return 2 if identical else int(error_frames)


def _num(v, default=None):
    try:
        f = float(v)
    except (TypeError, ValueError):
        return default
    return f if math.isfinite(f) else default


def sample_of(row: dict, scene_facts, timing_budget_s, error_frames: int) -> Sample | None:
    """A Sample from a measured row (results table or row cache), None when it cannot be one."""
    from bench.protocol.method import resolve_params
    from bench.protocol.registry import load_method
    from bench.run.row_cache import row_image_names
    if str(row.get("status")) not in ("ok", "cached") or scene_facts is None:
        return None
    frame = _num(row.get("frame_ms"))
    if frame is None:
        return None
    own = _num(row.get("extra.own_frame_ms"), frame)
    try:
        cls = load_method(row["method"])
        params = json.loads(row["params"]) if isinstance(row.get("params"), str) else dict(row.get("params") or {})
        params = resolve_params(cls, {k: v for k, v in params.items() if k in cls.params})
        size = CostFacts.of(scene_facts, row["width"], row["height"])
        terms = row_terms(cls, params, size)
    except Exception:   # a method or parameter this checkout no longer has
        return None
    if terms is None:
        return None
    err_frames = int(_num(row.get("extra.error_frames"), error_frames) or 1)
    prepare, total = _num(row.get("prepare_ms"), 0.0) / 1e3, _num(row.get("frames_total_ms"), 0.0) / 1e3
    error = _num(row.get("error_frames_ms"), 0.0) / 1e3
    wall = _num(row.get("row_wall_ms"))
    other = None if wall is None else max(wall / 1e3 - prepare - total - error, 0.0)
    # the first frame's excess over a steady frame (pbgi converges its amortised gather there) is
    # a cost of starting, as the preparation is: it recurs when a sequence restarts the method
    first = _num(row.get("extra.first_frame_ms"))
    stage = int(_num(row.get("frames"), 3)) if str(row.get("stage_clock")) == "finish_wall" else 0
    if first is not None:
        excess = max(first - own, 0.0) / 1e3
    else:   # older rows: the frames' total less as many steady frames as were rendered
        timed = int(_num(row.get("extra.timing_frames"), _num(row.get("frames"), 3)))
        rendered_frames = int(_num(row.get("warmup"), 1)) + timed + stage
        excess = max(total - rendered_frames * own / 1e3, 0.0)
    prepare, total = prepare + excess, total - excess
    renders = error_renders(cls, params, err_frames)
    rendered = _num(row.get("extra.error_frames_rendered"))
    if rendered is None and err_frames > 1:
        # a row of a run before the error frames were the timed instance's: a fresh instance,
        # prepared (and converged) again, rendered all of them; what is left of its wall must be
        # those frames, or the row tells the error model nothing (None)
        rendered, error = renders, error - prepare
        if error < 0.5 * renders * own / 1e3:
            error = None
    return Sample(method=row["method"], terms=terms, own_frame_s=own / 1e3, shared_frame_s=max(frame - own, 0.0) / 1e3,
                  prepare_s=prepare, frames_total_s=total, error_s=error, error_frames=err_frames,
                  error_renders=renders, error_rendered=int(rendered or 0), timing_budget_s=timing_budget_s,
                  frames=int(_num(row.get("frames"), 3)), warmup=int(_num(row.get("warmup"), 1)), other_s=other,
                  images=len(row_image_names(err_frames)), scene=str(row.get("scene", "")), stage_frames=stage)


def samples_from_run(run_dir: Path) -> list[Sample]:
    """Every measured row of a run folder (its results table and its manifest's scene facts)."""
    from bench.protocol import results as store
    manifest = json.loads((Path(run_dir) / "manifest.json").read_text())
    facts = manifest.get("scene_facts") or {}
    args = manifest.get("arguments") or {}
    df = store.load_results(Path(run_dir))
    out = []
    for row in df.to_dict("records"):
        s = sample_of(row, facts.get(row.get("scene")), args.get("timing_budget_s"), int(args.get("error_frames") or 1))
        if s is not None:
            out.append(s)
    return out


# ---------------------------------------------------------------------------- the model
def timed_terms(own_s: float, frames: int, budget_s, warmup: int = 1, stage_frames: int = 0) -> dict:
    """What the wall time of a row's warm-up, timed and stage frames scales with: the frames the
    harness renders (at least `frames` timed; with a calibrated timing budget, about as many as fill
    it, at most TimingBudget.max_frames; then, under a finish-fenced stage clock, `stage_frames` more
    with the profiler on) times the method's own frame, and their count (the per-frame read-back and
    bookkeeping). The shared passes are lent, measured once per view."""
    n = float(frames)
    if budget_s:
        n = min(max(n, float(budget_s) / own_s if own_s > 0 else TIMED_MAX_FRAMES), TIMED_MAX_FRAMES)
    n += warmup + stage_frames
    return {"rendered_s": n * own_s, "rendered": n}


def error_terms(own_s: float, rendered: float, read: int, pixels: float) -> dict:
    """What the error frames' statistics cost: the frames rendered for them alone (those the timing
    did not reach) and the frames read back and summed (per pixel)."""
    return {"rendered": rendered * own_s, "read_pixels": read * pixels}


def error_frames_rendered(read: int, timed_rendered: float) -> float:
    """The error frames the timed frames (warm-up included) do not reach: rendered after them."""
    return max(float(read) - float(timed_rendered), 0.0)


@dataclass
class CostModel:
    frame: dict = field(default_factory=dict)       # method -> Linear (own frame seconds)
    prepare: dict = field(default_factory=dict)     # method -> Linear
    timed: Linear = field(default_factory=Linear)   # warm-up + timed frames wall, from timed_terms
    error: Linear = field(default_factory=Linear)   # error frames wall, from error_terms
    other: Linear = field(default_factory=Linear)   # rest of a row, terms pixel_images
    shared: Linear = field(default_factory=Linear)  # shared stages per frame of a view, terms pixels/triangles
    reference: dict = field(default_factory=dict)   # "scene/component" -> seconds per sample per pixel
    reference_spp: dict = field(default_factory=dict)   # "scene/component" -> fraction of the cap reached
    reference_scale: float = 1.0                    # measured / predicted reference time of runs made with a plan
    reference_start_s: float = 0.0                  # once per run that renders references (Mitsuba's start, its kernels)
    sequence_scale: float = 1.0                     # measured / predicted sequence rows of runs made with a plan
    metrics_s_per_pixel: float = METRICS_PRIOR_S_PER_PIXEL
    setup: Linear = field(default_factory=lambda: Linear(const=SETUP_PRIOR_S))   # terms: triangles (every scene loaded)
    scale: dict = field(default_factory=dict)       # method -> local scale of frame and prepare
    provenance: dict = field(default_factory=dict)

    # -------------------------------------------------------------- fit, save, load
    @classmethod
    def fit(cls, samples: list[Sample], reference_metas: list[dict] = (), provenance: dict | None = None) -> "CostModel":
        model = cls(provenance=dict(provenance or {}))
        by_method: dict = {}
        for s in samples:
            by_method.setdefault(s.method, []).append(s)
        for method, group in sorted(by_method.items()):
            model.frame[method] = fit_linear([s.terms for s in group], [s.own_frame_s for s in group])
            model.prepare[method] = fit_linear([s.terms for s in group], [s.prepare_s for s in group])
        model.timed = fit_linear([timed_terms(s.own_frame_s, s.frames, s.timing_budget_s, s.warmup, s.stage_frames)
                                  for s in samples], [s.frames_total_s for s in samples], const=True)
        with_errors = [s for s in samples if s.error_frames > 1]
        # the read-back term is told apart from the rendering only by rows whose timed frames
        # covered some error frames; rows of older runs rendered them all (the terms collinear)
        separable = any(s.error_rendered < s.error_renders for s in with_errors)
        model.error = fit_linear([{k: v for k, v in error_terms(s.own_frame_s, s.error_rendered, s.error_renders,
                                                                 s.terms["pixels"]).items()
                                   if separable or k == "rendered"} for s in with_errors],
                                 [s.error_s for s in with_errors], const=True)
        with_other = [s for s in samples if s.other_s is not None]
        model.other = fit_linear([{"pixel_images": s.terms["pixels"] * s.images} for s in with_other],
                                 [s.other_s for s in with_other], const=True)
        with_shared = [s for s in samples if s.shared_frame_s > 0]
        model.shared = fit_linear([{"pixels": s.terms["pixels"], "triangles": s.terms["triangles"]} for s in with_shared],
                                  [s.shared_frame_s for s in with_shared], const=True)
        model.reference, model.reference_spp = fit_references(reference_metas)
        return model

    def to_json(self) -> dict:
        return {"format": 1, "provenance": self.provenance,
                "frame": {m: f.to_json() for m, f in sorted(self.frame.items())},
                "prepare": {m: f.to_json() for m, f in sorted(self.prepare.items())},
                "timed": self.timed.to_json(), "error": self.error.to_json(), "other": self.other.to_json(),
                "shared": self.shared.to_json(), "reference": dict(sorted(self.reference.items())),
                "reference_spp": dict(sorted(self.reference_spp.items())), "reference_scale": self.reference_scale,
                "reference_start_s": self.reference_start_s, "sequence_scale": self.sequence_scale,
                "metrics_s_per_pixel": self.metrics_s_per_pixel, "setup": self.setup.to_json()}

    @classmethod
    def from_json(cls, d: dict) -> "CostModel":
        return cls(frame={m: Linear.from_json(v) for m, v in (d.get("frame") or {}).items()},
                   prepare={m: Linear.from_json(v) for m, v in (d.get("prepare") or {}).items()},
                   timed=Linear.from_json(d.get("timed") or {}), error=Linear.from_json(d.get("error") or {}),
                   other=Linear.from_json(d.get("other") or {}), shared=Linear.from_json(d.get("shared") or {}),
                   reference={k: float(v) for k, v in (d.get("reference") or {}).items()},
                   reference_spp={k: float(v) for k, v in (d.get("reference_spp") or {}).items()},
                   reference_scale=float(d.get("reference_scale", 1.0)),
                   reference_start_s=float(d.get("reference_start_s", 0.0)),
                   sequence_scale=float(d.get("sequence_scale", 1.0)),
                   metrics_s_per_pixel=float(d.get("metrics_s_per_pixel", METRICS_PRIOR_S_PER_PIXEL)),
                   setup=Linear.from_json(d.get("setup") or {"const": SETUP_PRIOR_S}),
                   provenance=dict(d.get("provenance") or {}))

    @classmethod
    def prior(cls) -> "CostModel":
        try:
            return cls.from_json(json.loads(PRIOR_FILE.read_text()))
        except (OSError, ValueError):
            return cls(provenance={"source": "none: no cost_prior.json"})

    def at_speed(self, probe) -> "CostModel":
        """This prior at a machine's speed (a copy; the prior is unchanged): `probe`, a callable
        returning the machine's bench.run.probe.machine_probe (called only when the prior records
        its fitting machine's), over the prior's own; the methods and the shared passes by the GL
        ratio, the metrics and the set-up by the numpy one. What a budget chooses by
        (bench.run.budget.make_plan): the cold costs of this machine, whatever its caches hold."""
        from bench.run.probe import speed_ratios
        model = CostModel.from_json(self.to_json())
        here = probe() if probe is not None and self.provenance.get("probe") else None
        speed = speed_ratios(here, self.provenance.get("probe"))
        model.scale = {**self.scale, "*": self.method_scale("*") * speed["gl"]}
        model.metrics_s_per_pixel = self.metrics_s_per_pixel * speed["cpu"]
        model.setup = Linear({k: v * speed["cpu"] for k, v in self.setup.coef.items()}, self.setup.const * speed["cpu"])
        model.provenance = dict(model.provenance, probe_here=here, speed=speed)
        return model

    def local(self, samples: list[Sample], reference_metas: list[dict] = (), history: list[dict] = (),
              probe=None) -> "CostModel":
        """This prior scaled to the machine: methods by their cached rows, references by the cached
        references' seconds, metrics and set-up by earlier runs (a copy; the prior is unchanged).
        Where those have measured nothing, by the machine's speed: `probe`, a callable returning this
        machine's bench.run.probe.machine_probe (called only then), over the prior's own probe."""
        model = CostModel.from_json(self.to_json())
        ratios: dict = {}
        for s in samples:
            predicted = self._method_frame(s.method, s.terms)
            if predicted > 0 and s.own_frame_s > 0:
                ratios.setdefault(s.method, []).append(s.own_frame_s / predicted)
        everyone = [r for rs in ratios.values() for r in rs]
        metrics = [h["metrics_s_per_pixel"] for h in history if _num(h.get("metrics_s_per_pixel"))]
        setups = [h for h in history if _num(h.get("setup_s")) and _num(h.get("triangles")) is not None]
        speed = {"gl": 1.0, "cpu": 1.0}
        if probe is not None and (not everyone or not metrics or len(setups) < 2):
            from bench.run.probe import speed_ratios
            here = probe()
            speed = speed_ratios(here, self.provenance.get("probe"))
            model.provenance["probe_here"] = here
        overall = statistics.median(everyone) if everyone else speed["gl"]
        model.scale = {m: (statistics.median(rs) if len(rs) >= MIN_LOCAL_ROWS else overall) for m, rs in ratios.items()}
        model.scale["*"] = overall
        refs, spp = fit_references(reference_metas)
        model.reference.update(refs)
        model.reference_spp.update(spp)
        ratios = [phase_ratio(h, "references") for h in history[-10:]]
        ratios = [r for r in ratios if r is not None]
        if ratios:   # the references measured against what the plan predicted for them
            model.reference_scale = self.reference_scale * statistics.median(ratios)
        ratios = [r for r in (phase_ratio(h, "sequences") for h in history[-10:]) if r is not None]
        if ratios:   # the sequence rows likewise
            model.sequence_scale = self.sequence_scale * statistics.median(ratios)
        if metrics:
            model.metrics_s_per_pixel = statistics.median(metrics[-10:])
        else:
            model.metrics_s_per_pixel = self.metrics_s_per_pixel * speed["cpu"]
        if len(setups) >= 2:
            model.setup = fit_linear([{"triangles": h["triangles"]} for h in setups[-20:]],
                                     [h["setup_s"] for h in setups[-20:]])
        else:
            model.setup = Linear({k: v * speed["cpu"] for k, v in self.setup.coef.items()}, self.setup.const * speed["cpu"])
        model.provenance = dict(model.provenance, local_rows=len(samples), local_references=len(reference_metas),
                                local_runs=len(history), reference_scale=model.reference_scale,
                                sequence_scale=model.sequence_scale, speed=speed)
        return model

    # -------------------------------------------------------------- predictions
    def _method_frame(self, method: str, terms: dict) -> float:
        f = self.frame.get(method)
        return f(terms) if f is not None else self._unknown(terms)

    def _unknown(self, terms: dict) -> float:
        """A method without fitted rows (a new plugin): the median method's cost per pixel."""
        per_pixel = [f({"pixels": 1.0}) for f in self.frame.values()]
        return (statistics.median(per_pixel) if per_pixel else 1e-6) * terms.get("pixels", 0.0)

    def method_scale(self, method: str) -> float:
        return self.scale.get(method, self.scale.get("*", 1.0))

    def row(self, method: str, terms: dict, *, frames: int, warmup: int, timing_budget_s, error_frames: int, renders: int,
            images: int, judged: bool, stage_frames: int = 0) -> dict:
        """Predicted seconds of one row's phases: precompute, timing, error_frames, rows_other, metrics."""
        k = self.method_scale(method)
        own = k * self._method_frame(method, terms)
        prep_fit = self.prepare.get(method)
        prepare = k * (prep_fit(terms) if prep_fit is not None else own)
        timed = timed_terms(own, frames, timing_budget_s, warmup, stage_frames)
        timing = self.timed(timed)
        # the error frames the warm-up, timed and stage frames (a fenced stage clock's) do not reach
        error = (self.error(error_terms(own, error_frames_rendered(renders, timed["rendered"]), renders,
                                        terms["pixels"])) if renders else 0.0)
        other = self.other({"pixel_images": terms["pixels"] * images})
        metrics = self.metrics_s_per_pixel * terms["pixels"] if judged else 0.0
        return {"precompute": prepare, "timing": timing, "error_frames": error, "rows_other": other,
                "metrics": metrics, "frame": own}

    def shared_passes(self, pixels: float, triangles: float, frames: int, warmup: int, timing_budget_s) -> float:
        """A view's shared passes, rendered and timed once for its rows."""
        per_frame = self.method_scale("*") * self.shared({"pixels": pixels, "triangles": triangles})
        return self.timed(timed_terms(per_frame, frames, timing_budget_s, warmup))

    def reference_seconds(self, scene: str, component: str, pixels: float, spp_cap: int, stored_spp: int,
                          first_pass_spp: int) -> float:
        """Samples still to render for one reference component, at the scene's measured cost."""
        per = self.reference.get(f"{scene}/{component}")
        if per is None:
            known = [v for k, v in self.reference.items() if k.endswith("/" + component)]
            per = statistics.median(known) if known else 1e-6
        frac = self.reference_spp.get(f"{scene}/{component}")
        if frac is None:
            known = [v for k, v in self.reference_spp.items() if k.endswith("/" + component)]
            frac = statistics.median(known) if known else 1.0
        if frac == 0.0:   # a noise floor of 0 (direct light of delta emitters) stops after the first batch
            target = min(REFERENCE_FIRST_BATCH_SPP, spp_cap)
        else:
            target = max(min(first_pass_spp, spp_cap), min(spp_cap, frac * spp_cap))
        return max(target - stored_spp, 0.0) * pixels * per * self.reference_scale


def phase_ratio(entry: dict, phase: str, floor_s: float = 5.0) -> float | None:
    """Measured over predicted seconds of one phase of a run (a history entry or a manifest's
    phases_predicted_vs_actual), None when the prediction was too small to say."""
    if "predicted_s" in entry and isinstance(entry.get("predicted_s"), dict):
        predicted, actual = _num((entry["predicted_s"] or {}).get(phase)), _num((entry.get("actual_s") or {}).get(phase))
    else:
        both = entry.get(phase) or {}
        predicted, actual = _num(both.get("predicted_s")), _num(both.get("actual_s"))
    if predicted is None or actual is None or predicted < floor_s:
        return None
    return actual / predicted


def fit_references(metas: list[dict]) -> tuple[dict, dict]:
    """Per "scene/component": median seconds per sample per pixel of the cached references, and the
    median fraction of the cap they stopped at (1 for references that ran to it; a component whose
    noise floor reaches 0 stops after a few samples)."""
    per: dict = {}
    frac: dict = {}
    for meta in metas:
        payload = meta.get("payload") or {}
        spp, seconds = _num(meta.get("spp")), _num(meta.get("seconds"))
        px = int(payload.get("width", 0)) * int(payload.get("height", 0))
        key = f"{payload.get('scene_name')}/{payload.get('component')}"
        if not spp or not seconds or px <= 0:
            continue
        per.setdefault(key, []).append(seconds / (spp * px))
        floor = _num(meta.get("noise_floor_mse"))
        frac.setdefault(key, []).append(0.0 if floor == 0.0 else 1.0)
    return ({k: statistics.median(v) for k, v in per.items()},
            {k: statistics.median(v) for k, v in frac.items()})


def run_phases(run_dir: Path) -> dict | None:
    """A run folder's set-up seconds and metrics seconds per judged row's pixel (its manifest's
    phases and its table), as `record_history` keeps them; None without phases, or for a run made
    before the cost plan existed (its set-up did not make one, its metrics were the slower ones)."""
    from bench.protocol import results as store
    try:
        manifest = json.loads((Path(run_dir) / "manifest.json").read_text())
        phases = manifest["phases_s"]
        if "plan" not in manifest:
            return None
        df = store.load_results(Path(run_dir))
    except (OSError, ValueError, KeyError):
        return None
    out = {"setup_s": float(phases.get("setup", 0.0)) + float(phases.get("scene_upload", 0.0)),
           "triangles": sum(int(f.get("triangle_count", 0)) for f in (manifest.get("scene_facts") or {}).values()),
           "references_ratio": phase_ratio(manifest.get("phases_predicted_vs_actual") or {}, "references"),
           "reference_scale": float(((manifest.get("plan") or {}).get("model") or {}).get("reference_scale", 1.0)),
           "sequences_ratio": phase_ratio(manifest.get("phases_predicted_vs_actual") or {}, "sequences"),
           "sequence_scale": float(((manifest.get("plan") or {}).get("model") or {}).get("sequence_scale", 1.0)),
           "probe": ((manifest.get("plan") or {}).get("model") or {}).get("probe_here")}
    judged = df[df["status"].astype(str).isin(["ok", "cached"])] if "status" in df else df.iloc[0:0]
    pixels = (judged["width"] * judged["height"]).sum() if len(judged) else 0
    if pixels and float(phases.get("metrics", 0.0)) > 0:
        out["metrics_s_per_pixel"] = float(phases["metrics"]) / float(pixels)
    return out


def run_reference_seconds(model: "CostModel", run_dir: Path) -> tuple[float, float] | None:
    """(measured, predicted at reference_scale 1 without the start) seconds of a cold run's
    references: the manifest's `references` phase, and `model`'s samples for every static view the
    run judged, from none stored (bench.run.budget.reference_seconds, cold). None for a run
    without references."""
    from bench.protocol import results as store
    from bench.protocol.vocabulary import REFERENCE_COMPONENTS
    try:
        manifest = json.loads((Path(run_dir) / "manifest.json").read_text())
        args, actual = manifest["arguments"], float(manifest["phases_s"]["references"])
        df = store.load_results(Path(run_dir))
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if not args.get("references") or actual <= 0 or not len(df):
        return None
    static = df[df["status"].astype(str).isin(["ok", "cached"])]
    if "sequence" in static:
        static = static[static["sequence"].isna() | (static["sequence"].astype(str) == "")]
    cap = int(args.get("reference_spp_cap") or 1024)
    first = min(cap, REFERENCE_FIRST_PASS_SPP)
    predicted = 0.0
    for (scene, _view, width, height), _ in static.groupby(["scene", "view", "width", "height"]):
        predicted += sum(model.reference_seconds(scene, c, float(width) * float(height), cap, 0, first)
                         for c in REFERENCE_COMPONENTS) / (model.reference_scale or 1.0)
    return (actual, predicted) if predicted > 0 else None


# ---------------------------------------------------------------------------- local data
def reference_metas(root: Path | None = None) -> list[dict]:
    root = Path(root) if root else cache_root() / "references"
    out = []
    for f in root.glob("*/*/meta.json"):
        try:
            out.append(json.loads(f.read_bytes()))
        except (OSError, ValueError):
            continue
    return out


def cached_samples(facts_by_hash: dict, root: Path | None = None) -> list[Sample]:
    """Samples from the row cache's entries whose scene facts are known (by content hash: the
    run's own scenes, or the facts a row recorded)."""
    root = Path(root) if root else cache_root() / "rows"
    out = []
    for f in root.glob("*/*/row.json"):
        try:
            row = json.loads(f.read_bytes()).get("row") or {}
        except (OSError, ValueError):
            continue
        facts = facts_by_hash.get(row.get("scene_hash")) or row.get("scene_facts")
        s = sample_of(row, facts, row.get("timing_budget_s"), int(_num(row.get("extra.error_frames"), 1) or 1))
        if s is not None:
            out.append(s)
    return out


def read_history() -> list[dict]:
    try:
        lines = history_file().read_text().splitlines()
    except OSError:
        return []
    out = []
    for line in lines:
        try:
            out.append(json.loads(line))
        except ValueError:
            continue
    return out


def record_history(entry: dict) -> None:
    """Append a finished run's predicted and actual phases (the local model's metrics and set-up)."""
    path = history_file()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        kept = read_history()[-(HISTORY_KEEP - 1):]
        entry = dict(entry, date=_dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"))
        tmp = path.with_suffix(f".tmp{os.getpid()}")
        tmp.write_text("".join(json.dumps(e) + "\n" for e in kept + [entry]))
        tmp.replace(path)
    except OSError:
        pass   # the history is an aid to prediction, never a reason to fail a run
