"""A run's cost plan, made before any work, and the rows a time budget keeps (issue #29).

`make_plan` predicts each job with the machine's cost model (bench.run.cost): a row the row cache
holds costs nothing but its metrics, a row its method's guard will skip costs nothing, a rendered
row costs its preparation, timed frames, error frames, the harness's part and its metrics; each
view adds its shared passes once and the Mitsuba samples its references still need (from what
the reference cache already holds). `apply_budget` then keeps the rows that fit a budget, in the
order a user wants them: every method's defaults first (scene by scene, so each method is
represented before any scene gets its ladder), then the ends of the ladders (a two-point
time-vs-error curve), then their middles; the others are recorded as
`skipped: over budget (predicted N s)`. The plan is printed (`gibench run --plan` prints it and
stops), kept in the manifest beside the actual phase times, and the runner stops starting rows
when the budget is spent (bench.run.serial).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from bench.gl.profiler import default_clock
from bench.model.scene import compute_facts
from bench.protocol.cost import CostFacts
from bench.protocol.method import resolve_params
from bench.protocol.registry import load_method
from bench.protocol.versioning import method_version
from bench.protocol.vocabulary import REFERENCE_COMPONENTS
from bench.run import cost
from bench.run.config import RunConfig, sequence_config
from bench.run.plan import Job
from bench.run.probe import stored_machine_probe
from bench.run.row_cache import RowCache, row_cache_key, row_image_names
from bench.run.sequence_rows import last_change, sequence_jobs, sequence_key

ROW_PHASES = ("precompute", "timing", "error_frames", "rows_other", "metrics", "sequences")
PHASES = ("setup", "shared_passes", "references") + ROW_PHASES
REFERENCE_FIRST_PASS_SPP = cost.REFERENCE_FIRST_PASS_SPP   # bench.run.references.ReferenceProvider.REFERENCE_FIRST_PASS_SPP
PRIORITY_NAMES = ("defaults", "ladder ends", "ladder middles")


def parse_duration(text: str) -> float:
    """'90', '90s', '10m', '1h30m', '2.5m' -> seconds; one-line ValueError otherwise."""
    s = str(text).strip().lower()
    if re.fullmatch(r"\d+(\.\d+)?", s):
        return float(s)
    parts = re.fullmatch(r"(?:(\d+(?:\.\d+)?)h)?(?:(\d+(?:\.\d+)?)m)?(?:(\d+(?:\.\d+)?)s)?", s)
    if not s or parts is None or not any(parts.groups()):
        raise ValueError(f"'{text}' is not a duration (examples: 90s, 10m, 1h30m)")
    h, m, sec = (float(g) if g else 0.0 for g in parts.groups())
    return h * 3600 + m * 60 + sec


@dataclass
class PlannedRow:
    job: object                         # bench.run.plan.Job
    priority: int                       # 0 defaults, 1 ladder ends, 2 ladder middles
    status: str                         # "render", "cached", "guard", "over budget"
    seconds: dict = field(default_factory=dict)   # row phase -> predicted seconds (0 for a cached row's rendering)
    reason: str = ""
    cold: float = 0.0                   # what rendering it costs with nothing cached: what a budget chooses by

    @property
    def total(self) -> float:
        return sum(self.seconds.values())


@dataclass
class RunPlan:
    rows: list
    views: dict                         # (scene, view) -> {"shared_passes": s, "references": s}
    setup_s: float
    budget_s: float | None = None
    budget_margin: float = 0.0   # the share of the budget left unchosen (apply_budget)
    cold_setup_s: float | None = None   # the prior's set-up, what a budget chooses by (None: setup_s)
    reference_start_s: float = 0.0      # once when a view's references render (Mitsuba's start)
    model: dict = field(default_factory=dict)      # the model's provenance
    metrics_per_row_s: float = 0.0
    view_cost: dict = field(default_factory=dict)  # (scene, view) -> cold cost of its defaults (apply_budget)

    def kept(self) -> list:
        return [r for r in self.rows if r.status != "over budget"]

    def _kept_views(self) -> set:
        """Views with a row that renders or comes from the cache (a guard-skipped row opens none)."""
        return {(r.job.scene, r.job.view) for r in self.kept() if r.status in ("render", "cached")}

    def phases(self) -> dict:
        """Predicted seconds per phase of the rows and views the run keeps."""
        out = {p: 0.0 for p in PHASES}
        out["setup"] = self.setup_s
        for r in self.kept():
            for p, v in r.seconds.items():
                out[p] += v
        for key in self._kept_views():
            out["references"] += self.views[key]["references"]
        if out["references"] > 0:
            out["references"] += self.reference_start_s
        for key, _ in self._kept_passes():   # under a budget a view is visited once per priority level
            out["shared_passes"] += self.views[key]["shared_passes"]
        return out

    def _kept_passes(self) -> set:
        return {((r.job.scene, r.job.view), r.priority if self.budget_s else 0) for r in self.kept()
                if r.status in ("render", "cached")}

    def total(self) -> float:
        return sum(self.phases().values())

    def rank(self, row) -> tuple:
        """A row's place in a budgeted run: its level, then (defaults) its view's cold cost."""
        key = (row.job.scene, row.job.view)
        return (row.priority, self.view_cost.get(key, 0.0) if row.priority == 0 else 0.0)

    def ordered_jobs(self) -> list:
        """The jobs in the order a budgeted run takes them, the order the budget chose them in:
        every method's defaults (view by view, the cheapest views first), then the ladders' ends,
        then their middles, so that if time runs short it is the middles that go, not a method's
        only row, nor a whole cheap view for an expensive one."""
        return [r.job for r in sorted(self.rows, key=self.rank)]   # stable: job order within a level

    def planned_row(self, job):
        """The plan's row of one job (None for a job the plan does not know)."""
        where = (job.scene, job.view, job.method, job.index)
        for r in self.rows:
            if (r.job.scene, r.job.view, r.job.method, r.job.index) == where:
                return r
        return None

    def job_seconds(self, job) -> float:
        """Predicted seconds of one job's row (0 for a job the plan does not know)."""
        row = self.planned_row(job)
        return row.total if row is not None else 0.0

    def finish_seconds(self, views: set, rows: int) -> float:
        """What the end of a run still costs for `rows` rows over `views`: their metrics and the
        refinement of those views' references (most of a reference's samples come after its first pass)."""
        refine = sum(self.views.get(v, {}).get("references_refinement", 0.0) for v in views)
        return refine + rows * self.metrics_per_row_s

    def skipped_jobs(self) -> dict:
        """job -> the reason it is recorded as skipped without running (over budget)."""
        return {(r.job.scene, r.job.view, r.job.method, r.job.index): r.reason for r in self.rows
                if r.status == "over budget"}

    def summary(self) -> str:
        counts: dict = {}
        for r in self.rows:
            counts[r.status] = counts.get(r.status, 0) + 1
        return (", ".join(f"{n} {status}" for status, n in sorted(counts.items())) + f"; predicted "
                f"{fmt_duration(self.total())}" + self._budget_words())

    def _budget_words(self) -> str:
        if not self.budget_s:
            return ""
        margin = f", rows chosen for {1.0 - self.budget_margin:.0%} of it" if self.budget_margin else ""
        return f" of a {fmt_duration(self.budget_s)} budget{margin}"

    def to_json(self) -> dict:
        counts: dict = {}
        for r in self.rows:
            counts[r.status] = counts.get(r.status, 0) + 1
        return {"budget_s": self.budget_s, "budget_margin": self.budget_margin,
                "predicted_s": {k: round(v, 2) for k, v in self.phases().items()},
                "predicted_total_s": round(self.total(), 2), "rows": counts, "model": self.model}

    def table(self) -> str:
        """The plan as text: rows by scene and method, what is skipped and why, phases and total."""
        lines = [f"{'scene/view':28s} {'method':18s} {'rows':>4s} {'render':>6s} {'cached':>6s} "
                 f"{'skipped':>7s} {'predicted':>10s}"]
        groups: dict = {}
        for r in self.rows:
            groups.setdefault((f"{r.job.scene}/{r.job.view}", r.job.method), []).append(r)
        for (where, method), rows in groups.items():
            kept = [r for r in rows if r.status != "over budget"]
            lines.append(f"{where:28s} {method:18s} {len(rows):4d} {sum(r.status == 'render' for r in rows):6d} "
                         f"{sum(r.status == 'cached' for r in rows):6d} "
                         f"{sum(r.status in ('guard', 'over budget') for r in rows):7d} "
                         f"{sum(r.total for r in kept):9.1f}s")
        for key in sorted(self._kept_views()):
            v = self.views[key]
            if v["references"] > 0 or v["shared_passes"] > 0:
                lines.append(f"{key[0] + '/' + key[1]:28s} {'(view)':18s} references {v['references']:.1f}s, "
                             f"shared passes {v['shared_passes']:.1f}s")
        skipped = [r for r in self.rows if r.status in ("guard", "over budget")]
        if skipped:
            lines.append("skipped:")
            lines += [f"  {r.job.scene}/{r.job.view}/{r.job.method} #{r.job.index}: {r.reason}" for r in skipped]
        phases = self.phases()
        lines.append("predicted: " + ", ".join(f"{p} {v:.0f}s" for p, v in phases.items() if v >= 0.5)
                     + f"; total {fmt_duration(self.total())}"
                     + self._budget_words())
        return "\n".join(lines)


def fmt_duration(seconds: float) -> str:
    seconds = max(float(seconds), 0.0)
    return f"{int(seconds // 60)}m{seconds % 60:04.1f}s" if seconds >= 60 else f"{seconds:.1f}s"


def rung_priority(params: dict, index: int, count: int, has_defaults: bool) -> int:
    """0: a method's defaults (its `{}` rung, or the first set of a --param grid without one, or its
    only set), 1: the ends of its ladder or grid, 2: the middles."""
    if count <= 1 or not params or (not has_defaults and index == 0):
        return 0
    return 1 if index in (0, count - 1) else 2


def make_plan(cfg: RunConfig, scenes: dict, facts: dict, jobs: list, ctx, model: cost.CostModel | None = None,
              resolved: dict | None = None, sequences: dict | None = None) -> RunPlan:
    """Predict every job of a run (nothing renders; the row and reference caches are only read).

    Two models: `model` (by default the prior scaled by what this machine's caches and earlier
    runs measured) predicts what the run will take; the shipped prior at this machine's speed
    (bench.run.probe: about a second of GL and numpy work, measured once per machine and kept in
    the cache) gives the cold costs a budget chooses by, so that the choice depends on the command,
    the checkout and the machine, not on what earlier runs taught the local model (a second run of
    a command keeps its rows, from the cache), and a budget is filled on a fast machine as on a
    slow one. The run's clock (bench.run.serial) still stops rows the machine has no time for.
    Where this machine's caches and earlier runs have measured nothing, `model` is that same
    prior at the machine's speed."""
    renderer, clock = ctx.info.get("GL_RENDERER", ""), default_clock(ctx)

    def probe():
        return stored_machine_probe(ctx)
    shipped = cost.CostModel.prior()
    prior = shipped.at_speed(probe)   # the cold costs of this machine: what a budget chooses by
    if model is None:
        by_hash = {f.content_hash: f for f in facts.values()}
        model = shipped.local(cost.cached_samples(by_hash), cost.reference_metas(), cost.read_history(), probe=probe)
    if prior.provenance.get("probe_here"):
        model.provenance = dict(model.provenance, probe_here=prior.provenance["probe_here"],
                                cold_speed=prior.provenance["speed"])
    rows_cache = RowCache(log=lambda m: None)
    stage_frames = int(cfg.frames) if clock == "finish_wall" else 0   # a fenced stage clock times them apart
    counts: dict = {}
    defaults: set = set()   # (scene, view, method) with a `{}` set among its rows
    for job in jobs:
        counts[(job.scene, job.view, job.method)] = counts.get((job.scene, job.view, job.method), 0) + 1
        if not job.params:
            defaults.add((job.scene, job.view, job.method))
    planned = []
    views_needed: dict = {}
    for job in jobs:
        scene = scenes[job.scene]
        size = CostFacts.of(facts[job.scene], cfg.width, cfg.height)
        try:
            cls = load_method(job.method)
            params = (resolved or {}).get((job.method, job.index)) or resolve_params(cls, job.params)
            terms = cost.row_terms(cls, params, size)
            version = method_version(cls)
        except Exception as exc:   # the run records it as a failed row; it costs nothing
            planned.append(PlannedRow(job, 0, "guard", {}, f"fails to load ({' '.join(str(exc).split())[:80]})"))
            continue
        where = (job.scene, job.view, job.method)
        priority = rung_priority(job.params, job.index, counts[where], where in defaults)
        judged = cfg.references
        metrics_s = model.metrics_s_per_pixel * size.pixels if judged else 0.0
        if terms is None:
            planned.append(PlannedRow(job, priority, "guard", {}, "its method's guard skips it (a declared limit)"))
            continue
        renders = cost.error_renders(cls, params, int(cfg.error_frames))

        def row_seconds(m):
            out = m.row(job.method, terms, frames=cfg.frames, warmup=cfg.warmup, timing_budget_s=cfg.timing_budget_s,
                        error_frames=int(cfg.error_frames), renders=renders,
                        images=len(row_image_names(cfg.error_frames)), judged=judged, stage_frames=stage_frames)
            out.pop("frame")
            return out
        seconds, cold = row_seconds(model), sum(row_seconds(prior).values())
        key = row_cache_key(scene, job.view, job.method, version, params, cfg, renderer, clock)
        if (rows_cache.entry_dir(key) / "row.json").is_file() and not cfg.force:
            planned.append(PlannedRow(job, priority, "cached", {"metrics": metrics_s}, "in the row cache", cold=cold))
            views_needed.setdefault((job.scene, job.view), False)
            continue
        planned.append(PlannedRow(job, priority, "render", seconds, cold=cold))
        views_needed[(job.scene, job.view)] = True
    views = {}
    for (scene_name, view), renders in views_needed.items():
        size = CostFacts.of(facts[scene_name], cfg.width, cfg.height)
        shared = model.shared_passes(size.pixels, size.triangles, cfg.frames, cfg.warmup, cfg.timing_budget_s)
        first, refinement = reference_seconds(model, cfg, scenes[scene_name], view, size) if cfg.references else (0, 0)
        cold = sum(reference_seconds(prior, cfg, scenes[scene_name], view, size, stored_nothing=True)) \
            if cfg.references else 0.0
        views[(scene_name, view)] = {"shared_passes": shared if renders else 0.0, "references": first + refinement,
                                     "references_refinement": refinement, "cold_references": cold,
                                     "cold_shared": prior.shared_passes(size.pixels, size.triangles, cfg.frames,
                                                                        cfg.warmup, cfg.timing_budget_s)}
    for row in planned:   # a view whose rows are all skipped by their guards costs nothing
        views.setdefault((row.job.scene, row.job.view), {"shared_passes": 0.0, "references": 0.0,
                                                         "references_refinement": 0.0, "cold_references": 0.0,
                                                         "cold_shared": 0.0})
    sequence_rows, sequence_views, sequence_facts = plan_sequences(cfg, sequences or {}, model, renderer, prior)
    planned += sequence_rows
    views.update(sequence_views)
    metrics_per_row = model.metrics_s_per_pixel * cfg.width * cfg.height if cfg.references else 0.0
    triangles = {"triangles": sum(f.triangle_count for f in [*facts.values(), *sequence_facts])}
    return RunPlan(rows=planned, views=views, setup_s=model.setup(triangles), cold_setup_s=prior.setup(triangles),
                   reference_start_s=model.reference_start_s if cfg.references else 0.0,
                   model=model.provenance,
                   metrics_per_row_s=metrics_per_row)


def plan_sequences(cfg: RunConfig, sequences: dict, model: cost.CostModel, renderer: str = "",
                   prior: cost.CostModel | None = None) -> tuple:
    """(planned rows, views, scene facts) of a run's sequence rows (bench.run.sequence_rows), each
    predicted whole under the phase `sequences`: its frames (the method's frame and the shared
    passes, every frame), a preparation at frame 0 and in every frame something moved (the
    protocol's default update), the K static frames of `lag_frames`' level (settling frames,
    which only a method that reuses earlier frames renders, are not predicted), the harness's part
    and the metrics of every frame; each sequence view adds the references of its distinct frames (the
    frames at rest share the last one's). Cold costs (what a budget chooses by) from `prior`
    (default: `model`)."""
    prior = prior or model
    scfg = sequence_config(cfg)
    rows, views, facts_of = [], {}, {}
    rows_cache = RowCache(log=lambda m: None)
    for name, view, method, index, pset in sequence_jobs(cfg, sequences):
        seq = sequences[name]
        if name not in facts_of:
            facts_of[name] = compute_facts(seq.base)
        size = CostFacts.of(facts_of[name], scfg.width, scfg.height)
        job = Job(name, view, method, index, pset)
        try:
            cls = load_method(method)
            params = resolve_params(cls, pset)
            terms = cost.row_terms(cls, params, size)
            key = sequence_key(seq, view, method, method_version(cls), params, scfg, renderer)
        except Exception as exc:
            rows.append(PlannedRow(job, 0, "guard", {}, f"fails to load ({' '.join(str(exc).split())[:80]})"))
            continue
        if terms is None:
            rows.append(PlannedRow(job, 0, "guard", {}, "its method's guard skips it (a declared limit)"))
            continue
        moved = sum(1 for t in range(1, seq.frames) if seq.changes(t))
        lag = last_change(seq) < seq.frames - 1 and scfg.references

        def row_seconds(m):
            one = m.row(method, terms, frames=1, warmup=1, timing_budget_s=None, error_frames=1, renders=0, images=3,
                        judged=scfg.references)
            shared = m.method_scale("*") * m.shared({"pixels": size.pixels, "triangles": size.triangles})
            # the static level of lag_frames: K frames of a fresh instance at rest (sequence_rows._static_level)
            at_rest = lag * max(2, int(cfg.error_frames))
            return m.sequence_scale * (seq.frames * (one["frame"] + shared) + (1 + moved + lag) * one["precompute"]
                                       + at_rest * (one["frame"] + shared) + seq.frames * one["rows_other"]
                                       + (seq.frames + at_rest) * one["metrics"])
        total, cold_total = row_seconds(model), row_seconds(prior)
        if (name, view) not in views:
            refs = _sequence_reference_seconds(model, scfg, seq, view, size) if scfg.references else 0.0
            cold = _sequence_reference_seconds(prior, scfg, seq, view, size, True) if scfg.references else 0.0
            views[(name, view)] = {"shared_passes": 0.0, "references": refs, "references_refinement": 0.0,
                                   "cold_references": cold, "cold_shared": 0.0}
        if (rows_cache.entry_dir(key) / "row.json").is_file() and not cfg.force:
            rows.append(PlannedRow(job, 0, "cached", {"sequences": 0.0}, "in the row cache", cold=cold_total))
            continue
        rows.append(PlannedRow(job, 0, "render", {"sequences": total}, cold=cold_total))
    return rows, views, list(facts_of.values())


def _sequence_reference_seconds(model: cost.CostModel, scfg: RunConfig, seq, view: str, size: CostFacts,
                                stored_nothing: bool = False) -> float:
    """The per-frame references a sequence view still needs: one per distinct frame, at the cap
    (`stored_nothing`: as if none were cached)."""
    try:
        from reference.api import stored_reference
    except Exception:
        return 0.0
    cap, total = int(scfg.reference_spp_cap), 0.0
    for t in range(last_change(seq) + 1):
        scene = seq.frame(t)
        for c in REFERENCE_COMPONENTS:
            try:
                stored = 0 if stored_nothing else stored_reference(scene, view, scfg.width, scfg.height, c)["spp"]
            except Exception:   # no Mitsuba: no reference is rendered
                return 0.0
            total += model.reference_seconds(seq.base.name, c, size.pixels, cap, stored, cap)
    return total


def reference_seconds(model: cost.CostModel, cfg: RunConfig, scene, view: str, size: CostFacts,
                      stored_nothing: bool = False) -> tuple:
    """(first pass, refinement) seconds of the Mitsuba samples one view's references still need
    (`stored_nothing`: as if the reference cache held none of them)."""
    try:
        from reference.api import stored_reference
        stored = {c: 0 if stored_nothing else stored_reference(scene, view, cfg.width, cfg.height, c)["spp"]
                  for c in REFERENCE_COMPONENTS}
        if stored_nothing:
            from reference.env import load_mitsuba
            load_mitsuba()   # no Mitsuba: no reference is rendered
    except Exception:   # no Mitsuba: the run leaves error columns empty and renders no reference
        return 0.0, 0.0
    cap = int(cfg.reference_spp_cap)
    first = min(cap, REFERENCE_FIRST_PASS_SPP)
    total = sum(model.reference_seconds(scene.name, c, size.pixels, cap, stored[c], first) for c in REFERENCE_COMPONENTS)
    first_s = sum(model.reference_seconds(scene.name, c, size.pixels, first, stored[c], first)
                  for c in REFERENCE_COMPONENTS)
    return first_s, max(total - first_s, 0.0)


def apply_budget(plan: RunPlan, budget_s: float, margin: float = 0.0) -> RunPlan:
    """Keep the rows that fit (1 - `margin`) of `budget_s` (RunConfig.budget_margin: the rest is
    left for the machine's timing noise, so that the run ends what it chose), by priority
    (defaults, ladder ends, middles; the defaults of the views whose defaults cost least first),
    each view's references and shared passes counted with its first kept row; mark the rest over
    budget.

    The choice is made on the cold costs (every row rendered, every reference rendered): what the
    caches hold does not change which rows a budget keeps, so the same command gives the same
    rows, and a second run of it renders nothing new (a cached row is then cheap: its run is
    shorter, not fuller). A larger budget, or none, is how a run gets more rows."""
    plan.budget_s, plan.budget_margin = float(budget_s), float(margin)
    spent = plan.setup_s if plan.cold_setup_s is None else plan.cold_setup_s   # the prior's: the same rows every run
    started_references = False   # Mitsuba's start, with the first view whose references render
    opened: set = set()       # views whose references and first shared passes are counted
    passes: set = set()       # (view, priority level): a budgeted run visits a view once per level
    # the defaults view by view, the cheapest views first: a budget too small for every view's
    # defaults keeps as many views (static and in motion) as it can, not the first of the corpus
    defaults_cost: dict = {}
    for row in plan.rows:
        if row.priority == 0 and row.status != "guard":
            key = (row.job.scene, row.job.view)
            defaults_cost[key] = defaults_cost.get(key, plan.views[key]["cold_references"]
                                                   + plan.views[key]["cold_shared"]) + row.cold
    plan.view_cost = defaults_cost
    order = sorted(range(len(plan.rows)), key=lambda i: (*plan.rank(plan.rows[i]), i))
    for i in order:
        row = plan.rows[i]
        if row.status == "guard":
            continue
        key = (row.job.scene, row.job.view)
        view = plan.views[key]
        view_cost = (0.0 if key in opened else view["cold_references"]) + \
            (0.0 if (key, row.priority) in passes else view["cold_shared"])
        starts = not started_references and key not in opened and view["cold_references"] > 0
        view_cost += plan.reference_start_s if starts else 0.0
        cost_s = row.cold + view_cost
        if spent + cost_s <= budget_s * (1.0 - margin):
            spent += cost_s
            opened.add(key)
            passes.add((key, row.priority))
            started_references = started_references or starts
        else:
            row.status, row.reason = "over budget", f"over budget (predicted {math.ceil(cost_s)} s)"
    return plan
