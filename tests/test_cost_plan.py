"""The cost plan and the time budget (issue #29): bench.run.cost, bench.run.budget, `run --plan`,
`run --budget`, `run --quick` as a budget.

The selection tests use a cost model whose every figure is set here (a row costs ROW_S, a view's
shared passes SHARED_S), so which rows a budget keeps is exact; the fitted prior is checked for
what it must be (every method of the registry predicted, finite, positive), not for its numbers.
"""
from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from bench.protocol.cost import CostFacts
from bench.protocol.method import resolve_params
from bench.protocol.registry import load_method
from bench.run import budget, cost, serial
from bench.run.config import RunConfig
from tests.conftest import make_open_box

ROW_S, SHARED_S = 300.0, 300.0


def fixed_model() -> cost.CostModel:
    """Every rendered row costs ROW_S (its timed frames), every view's shared passes SHARED_S, nothing else."""
    return cost.CostModel(timed=cost.Linear(const=ROW_S), setup=cost.Linear(), metrics_s_per_pixel=0.0)


@pytest.fixture
def fixed_costs(monkeypatch, tmp_path):
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))   # rows render, none from an earlier test
    model = fixed_model()
    monkeypatch.setattr(cost.CostModel, "prior", classmethod(lambda cls: model))
    monkeypatch.setattr(cost.CostModel, "local", lambda self, *a, **k: self)
    monkeypatch.setattr(cost, "record_history", lambda entry: None)
    return model


def small_config(tmp_path, **kw) -> RunConfig:
    base = dict(scenes=[make_open_box()], methods=["direct", "ssdo"], width=32, height=24, frames=1, warmup=1,
                references=False, ladders=True, error_frames=1, progress=False, out=tmp_path / "run",
                budget_margin=0.0)   # the budgets below are exact sums of the fixed costs
    base.update(kw)
    return RunConfig(**base)


# ---------------------------------------------------------------------------- durations
@pytest.mark.parametrize("text, seconds", [("90", 90), ("90s", 90), ("10m", 600), ("1h30m", 5400), ("2.5m", 150),
                                           ("1h", 3600), ("1m30s", 90)])
def test_durations(text, seconds):
    assert budget.parse_duration(text) == seconds


@pytest.mark.parametrize("text", ["", "m", "10x", "-5m", "1.2.3s", "ten minutes"])
def test_bad_durations_are_refused(text):
    with pytest.raises(ValueError, match="not a duration"):
        budget.parse_duration(text)


@pytest.mark.parametrize("value", ["abc", "0s", "30d"])
def test_bad_budget_is_one_line_before_any_work(value, capsys, tmp_path):
    import bench.cli as cli
    with pytest.raises(SystemExit) as exit_:
        cli.main(["run", "--budget", value, "--out", str(tmp_path / "run")])
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "--budget" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "run").exists()


# ---------------------------------------------------------------------------- the fit
def test_fit_recovers_a_known_linear_cost():
    rng = np.random.default_rng(3)
    rows = [{"pixels": float(p), "pixel_vpls": float(p * v)} for p, v in
            zip(rng.integers(1000, 100000, 40), rng.integers(16, 4096, 40))]
    truth = cost.Linear(coef={"pixels": 2e-7, "pixel_vpls": 1e-9}, const=0.01)
    fitted = cost.fit_linear(rows, [truth(r) for r in rows])
    for r in rows:
        assert fitted(r) == pytest.approx(truth(r), rel=1e-3)
    assert all(v >= 0 for v in fitted.coef.values()) and fitted.const >= 0


def test_fit_predicts_the_total_of_rows_whose_cost_per_unit_varies():
    """A budget spends totals. Many cheap rows of small scenes and a few heavy rows of real ones,
    whose cost per unit is higher (view-dependent work no term sees, as dss's near fields on sponza):
    the fit predicts the rows' total, and the heavy rows' own total within 30%. (Fitted on relative
    error and rescaled to the median row, it predicted the default run's dss rows at 0.3x.)"""
    rng = np.random.default_rng(5)
    cheap = [{"surfels": float(u)} for u in rng.integers(2_000, 12_000, 40)]
    heavy = [{"surfels": float(u)} for u in rng.integers(60_000, 400_000, 6)]
    y = [1e-5 * r["surfels"] * rng.uniform(0.5, 2.0) for r in cheap] + \
        [4e-5 * r["surfels"] * rng.uniform(0.8, 1.25) for r in heavy]
    fitted = cost.fit_linear(cheap + heavy, y)
    assert sum(fitted(r) for r in cheap + heavy) == pytest.approx(sum(y), rel=1e-6)
    assert sum(fitted(r) for r in heavy) == pytest.approx(sum(y[len(cheap):]), rel=0.3)


def test_model_round_trips_through_json():
    model = cost.CostModel.prior()
    again = cost.CostModel.from_json(json.loads(json.dumps(model.to_json())))
    assert again.to_json() == model.to_json()


def test_the_shipped_prior_predicts_every_method_at_every_rung():
    """Every registered method has fitted frame and preparation costs, and predicts a finite,
    positive row for each rung on a procedural and a real scene's size (or says its guard skips it)."""
    from bench.protocol.registry import list_methods
    model = cost.CostModel.prior()
    assert model.provenance.get("rows", 0) > 100, "the prior was fitted from measured rows (gibench cost-model)"
    for size in (CostFacts(320, 180, 36, 20.0, 3.0), CostFacts(320, 180, 66_450, 1500.0, 20.0)):
        for name in list_methods():
            cls = load_method(name)
            assert name in model.frame, f"{name}: no fitted frame cost in cost_prior.json"
            for rung in (cls.ladder or ({},)):
                terms = cost.row_terms(cls, resolve_params(cls, dict(rung)), size)
                if terms is None:
                    continue
                assert all(math.isfinite(v) and v >= 0 for v in terms.values()), (name, rung, terms)
                seconds = model.row(name, terms, frames=3, warmup=1, timing_budget_s=1.0, error_frames=8,
                                    renders=8, images=9, judged=True)
                assert all(math.isfinite(v) and v >= 0 for v in seconds.values()), (name, rung, seconds)
                assert seconds["timing"] > 0


def test_a_slower_machine_scales_the_prior():
    """The local model multiplies a method's prior by its cached rows' measured/predicted ratio."""
    prior = cost.CostModel(frame={"m": cost.Linear(coef={"pixels": 1e-6})})
    sample = cost.Sample(method="m", terms={"pixels": 1e5, "triangles": 10.0}, own_frame_s=0.3, shared_frame_s=0.0,
                         prepare_s=0.0, frames_total_s=1.0, error_s=0.0, error_frames=1, error_renders=0,
                         timing_budget_s=None, frames=3, warmup=1, other_s=None, images=3)
    local = prior.local([sample] * cost.MIN_LOCAL_ROWS)
    assert local.method_scale("m") == pytest.approx(3.0)
    assert local.method_scale("other") == pytest.approx(3.0)   # the machine's overall ratio
    assert prior.method_scale("m") == 1.0                       # the prior itself is unchanged


def test_a_fresh_machine_scales_the_prior_by_its_speed():
    """With nothing measured locally, the prior is scaled by this machine's probe over the prior's own:
    the methods (and shared passes) by the GL probe, metrics and set-up by the numpy one."""
    from bench.run.probe import speed_ratios
    prior = cost.CostModel(frame={"m": cost.Linear(coef={"pixels": 1e-6})}, metrics_s_per_pixel=1e-6,
                           setup=cost.Linear(const=10.0), provenance={"probe": {"gl_s": 0.04, "cpu_s": 0.10}})
    local = prior.local([], [], [], probe=lambda: {"gl_s": 0.02, "cpu_s": 0.15})
    assert local.method_scale("m") == pytest.approx(0.5)
    assert local.method_scale("anything") == pytest.approx(0.5)
    assert local.metrics_s_per_pixel == pytest.approx(1.5e-6)
    assert local.setup({"triangles": 1e6}) == pytest.approx(15.0)
    assert local.provenance["speed"] == {"gl": pytest.approx(0.5), "cpu": pytest.approx(1.5)}
    assert prior.method_scale("m") == 1.0 and prior.metrics_s_per_pixel == 1e-6   # the prior is unchanged
    # a prior without a probe (or a failed measurement) is not scaled
    assert speed_ratios({"gl_s": 0.02}, None) == {"gl": 1.0, "cpu": 1.0}
    assert speed_ratios({"gl_s": 0.0, "cpu_s": 0.1}, {"gl_s": 0.04, "cpu_s": 0.1}) == {"gl": 1.0, "cpu": 1.0}


def test_what_the_machine_measured_beats_its_probe():
    """Cached rows and earlier runs scale the prior; the probe is then not even measured."""
    prior = cost.CostModel(frame={"m": cost.Linear(coef={"pixels": 1e-6})}, provenance={"probe": {"gl_s": 1, "cpu_s": 1}})
    sample = cost.Sample(method="m", terms={"pixels": 1e5, "triangles": 10.0}, own_frame_s=0.3, shared_frame_s=0.0,
                         prepare_s=0.0, frames_total_s=1.0, error_s=0.0, error_frames=1, error_renders=0,
                         timing_budget_s=None, frames=3, warmup=1, other_s=None, images=3)
    history = [{"setup_s": 3.0, "triangles": 1000, "metrics_s_per_pixel": 2e-6},
               {"setup_s": 5.0, "triangles": 3000, "metrics_s_per_pixel": 4e-6}]

    def no_probe():
        raise AssertionError("the probe ran although the machine's own measurements were there")
    local = prior.local([sample] * cost.MIN_LOCAL_ROWS, [], history, probe=no_probe)
    assert local.method_scale("m") == pytest.approx(3.0)
    assert local.metrics_s_per_pixel == pytest.approx(3e-6)


def test_the_probe_measures_gl_and_numpy_work():
    from bench.gl.context import create_context
    from bench.run import probe
    probe._MEASURED.clear()
    measured = probe.machine_probe(create_context())
    assert set(measured) == {"gl_s", "cpu_s"} and all(0 < v < 60 for v in measured.values())
    assert probe.machine_probe(None) == measured   # once per process


# ---------------------------------------------------------------------------- the plan
def test_plan_prints_and_renders_nothing(monkeypatch, capsys, tmp_path, fixed_costs):
    import bench.cli as cli
    import bench.run.execute

    def no_render(*a, **k):
        raise AssertionError("--plan rendered a row")
    monkeypatch.setattr(bench.run.execute, "render_outcome", no_render)
    monkeypatch.setattr(bench.run.serial, "render_outcome", no_render)
    out = tmp_path / "run"
    code = cli.main(["run", "--plan", "--scenes", "cornell_spot", "--methods", "direct,ssdo", "--res", "32x24",
                     "--no-reference", "--out", str(out)])
    assert code == 0
    text = capsys.readouterr().out
    assert "cornell_spot/main" in text and "ssdo" in text and "predicted:" in text and "total" in text
    assert not out.exists()


def test_budget_keeps_defaults_then_ladder_ends_then_middles(tmp_path, fixed_costs):
    # direct opens the view (SHARED_S + ROW_S), ssdo's defaults follow (ROW_S): 900 s; then the ends
    # of ssdo's 5-rung ladder, a second visit of the view (SHARED_S again): the first fits (1500 s),
    # the last does not, nor do the middles
    plan = serial.plan_only(small_config(tmp_path, budget_s=1550.0))
    kept = [(r.job.method, r.job.params) for r in plan.rows if r.status == "render"]
    ssdo = load_method("ssdo")
    assert kept == [("direct", {}), ("ssdo", dict(ssdo.ladder[0])), ("ssdo", {})]
    over = [r for r in plan.rows if r.status == "over budget"]
    assert {tuple(sorted(r.job.params.items())) for r in over} == \
        {tuple(sorted(dict(rung).items())) for rung in ssdo.ladder if dict(rung) and rung != ssdo.ladder[0]}
    # the prediction a skipped row names is its own and, for a view's first row of a level, the view's
    assert all(re.fullmatch(r"over budget \(predicted (301|601) s\)", r.reason) for r in over), [r.reason for r in over]
    assert plan.total() == pytest.approx(2 * SHARED_S + 3 * ROW_S, abs=0.1)
    order = [(j.method, j.params) for j in plan.ordered_jobs()]   # the order the run takes them
    assert order[:3] == [("direct", {}), ("ssdo", {}), ("ssdo", dict(ssdo.ladder[0]))]
    assert "over budget" in plan.table()


def test_a_param_grid_has_its_first_set_as_defaults(tmp_path, fixed_costs):
    """A method run over a --param grid (no `{}` set) keeps its first set at the defaults' priority."""
    cfg = small_config(tmp_path, methods=["direct", "ssdo"], budget_s=901.0,
                       params={"ssdo": [{"sample_count": 8}, {"sample_count": 16}, {"sample_count": 64}]})
    plan = serial.plan_only(cfg)
    kept = [(r.job.method, r.job.params) for r in plan.rows if r.status == "render"]
    assert kept == [("direct", {}), ("ssdo", {"sample_count": 8})]
    assert [r.priority for r in plan.rows] == [0, 0, 2, 1]   # direct; the grid: first, middle, last


def test_budget_run_records_the_rows_it_skips_and_the_plan(tmp_path, fixed_costs):
    from bench.protocol import results as store
    cfg = small_config(tmp_path, budget_s=1000.0)
    df, runner = serial.run(cfg, log=lambda m: None)
    status = {(r["method"], r["params"]): r["status"] for r in df.to_dict("records")}
    rendered = [k for k, v in status.items() if v == "ok"]
    assert sorted(m for m, _ in rendered) == ["direct", "ssdo"]          # the two defaults
    skipped = [v for v in status.values() if v != "ok"]
    assert len(skipped) == len(load_method("ssdo").ladder) - 1
    assert all(re.fullmatch(r"skipped: over budget \(predicted (301|601) s\)", v) for v in skipped), skipped
    manifest = json.loads((cfg.out / "manifest.json").read_text())
    assert manifest["plan"]["budget_s"] == 1000.0
    assert manifest["plan"]["predicted_total_s"] == pytest.approx(SHARED_S + 2 * ROW_S, abs=0.1)
    pva = manifest["phases_predicted_vs_actual"]
    assert pva["timing"]["predicted_s"] == pytest.approx(SHARED_S + 2 * ROW_S, abs=0.1)
    assert pva["total"]["actual_s"] > 0
    assert store.load_results(cfg.out).shape[0] == len(status)
    from reports import build_report   # the report shows each phase measured beside its prediction
    html = build_report(cfg.out, tmp_path / "report").read_text()
    assert "as the cost plan predicted it" in html and re.search(r"\(predicted 900\.\d s\)", html) and "budget</dt>" in html


def test_no_row_starts_once_the_budget_is_spent(tmp_path, monkeypatch):
    """With every row predicted free, the runner still stops starting rows when the clock passes the budget."""
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))
    model = cost.CostModel(setup=cost.Linear(), metrics_s_per_pixel=0.0)
    monkeypatch.setattr(cost.CostModel, "prior", classmethod(lambda cls: model))
    monkeypatch.setattr(cost.CostModel, "local", lambda self, *a, **k: self)
    monkeypatch.setattr(cost, "record_history", lambda entry: None)
    account = serial.Runner._account_row

    def spend_after_first_row(self, row, seconds):
        account(self, row, seconds)
        self.started -= 10_000.0        # as if the first row had taken the whole budget
    monkeypatch.setattr(serial.Runner, "_account_row", spend_after_first_row)
    df, _ = serial.run(small_config(tmp_path, budget_s=600.0), log=lambda m: None)
    statuses = df["status"].tolist()
    assert statuses[0] == "ok"
    assert all(s.startswith("skipped: over budget: the budget was spent") for s in statuses[1:]), statuses


def test_history_feeds_the_next_plan(tmp_path, monkeypatch):
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))
    cost.record_history({"setup_s": 3.0, "triangles": 1000, "metrics_s_per_pixel": 2e-6})
    cost.record_history({"setup_s": 5.0, "triangles": 3000, "metrics_s_per_pixel": 4e-6})
    local = cost.CostModel.prior().local([], [], cost.read_history())
    assert local.setup({"triangles": 2000}) == pytest.approx(4.0, rel=1e-3)   # 2 s + 1 ms per thousand triangles
    assert local.metrics_s_per_pixel == pytest.approx(3e-6)


# ---------------------------------------------------------------------------- quick is a budget
def test_quick_is_a_five_minute_budget_over_the_default_corpus(monkeypatch):
    from bench.cli import options
    from tests.conftest import cli_run_config
    cfg = cli_run_config(monkeypatch, ["run", "--quick"])
    assert cfg.budget_s == options.QUICK_BUDGET_S == 300.0
    assert cfg.budget_margin == options.QUICK_BUDGET_MARGIN == 0.25 > cli_run_config(monkeypatch, ["run"]).budget_margin
    assert list(cfg.scenes) == list(options.DEFAULT_SCENES) and cfg.ladders
    assert cli_run_config(monkeypatch, ["run", "--quick", "--budget", "2m"]).budget_s == 120.0
    assert cli_run_config(monkeypatch, ["run"]).budget_s is None
    assert cli_run_config(monkeypatch, ["run", "--quick", "--budget", "none"]).budget_s is None


def test_a_budget_keeps_the_same_rows_when_the_cache_holds_them(tmp_path, fixed_costs):
    """The budget chooses on cold costs: a second run of the same command keeps the same rows (from the
    cache) and renders nothing new, rather than filling its budget with the rows the first left out."""
    first, _ = serial.run(small_config(tmp_path, budget_s=1000.0), log=lambda m: None)
    again, runner = serial.run(small_config(tmp_path, budget_s=1000.0, out=tmp_path / "again"), log=lambda m: None)
    kept = lambda df: sorted((r["method"], r["params"]) for r in df.to_dict("records")  # noqa: E731
                             if not str(r["status"]).startswith("skipped"))
    assert kept(again) == kept(first) and len(kept(first)) == 2
    assert runner.counts["ok"] == 0 and runner.counts["cached"] == 2


def test_the_reference_model_follows_what_runs_measured(tmp_path, monkeypatch):
    """Runs that made a plan record the references predicted and measured: the next plan's reference
    cost is scaled by their median ratio."""
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))
    prior = cost.CostModel(reference={"s/direct": 1e-6}, reference_spp={"s/direct": 1.0})
    for predicted, actual in ((100.0, 50.0), (80.0, 48.0), (60.0, 30.0)):
        cost.record_history({"predicted_s": {"references": predicted}, "actual_s": {"references": actual}})
    local = prior.local([], [], cost.read_history())
    assert local.reference_scale == pytest.approx(0.5)
    assert local.reference_seconds("s", "direct", 1000, 64, 0, 64) == pytest.approx(0.5 * 64 * 1000 * 1e-6)


def test_the_defaults_of_the_cheapest_views_come_first():
    """A budget too small for every view's defaults keeps as many views as it can: the cheapest
    views' defaults first, whatever their order in the corpus; then the ladders as before."""
    from bench.run.plan import Job

    def row(scene, method, priority, seconds):
        return budget.PlannedRow(Job(scene, "main", method, 0, {}), priority, "render", {"timing": seconds},
                                 cold=seconds)
    views = {(s, "main"): {"shared_passes": 0.0, "references": r, "references_refinement": 0.0,
                           "cold_references": r, "cold_shared": 0.0}
             for s, r in (("costly", 500.0), ("cheap_a", 100.0), ("cheap_b", 150.0))}
    rows = [row("costly", "direct", 0, 10.0), row("costly", "ssdo", 0, 10.0),
            row("cheap_a", "direct", 0, 10.0), row("cheap_a", "ssdo", 0, 10.0), row("cheap_a", "ssdo", 1, 10.0),
            row("cheap_b", "direct", 0, 10.0), row("cheap_b", "ssdo", 0, 10.0)]
    plan = budget.apply_budget(budget.RunPlan(rows=rows, views=views, setup_s=0.0), 400.0)
    kept = [(r.job.scene, r.job.method, r.priority) for r in plan.rows if r.status == "render"]
    # cheap_a (120 s) and cheap_b (170 s) fit; costly (520 s) does not; then cheap_a's ladder row (10 s)
    assert kept == [("cheap_a", "direct", 0), ("cheap_a", "ssdo", 0), ("cheap_a", "ssdo", 1),
                    ("cheap_b", "direct", 0), ("cheap_b", "ssdo", 0)]
    assert all(r.status == "over budget" for r in plan.rows if r.job.scene == "costly")
    # and a budgeted run takes them in that order: a run that falls behind cuts the costly view, then ladders
    assert [(j.scene, j.method) for j in plan.ordered_jobs()][:5] == \
        [("cheap_a", "direct"), ("cheap_a", "ssdo"), ("cheap_b", "direct"), ("cheap_b", "ssdo"), ("costly", "direct")]


def test_what_earlier_runs_taught_the_local_model_does_not_change_the_choice(tmp_path, fixed_costs, monkeypatch):
    """The budget chooses by the shipped prior's cold costs; the local model (here: a machine 3x
    slower than the prior, as learned from earlier runs) changes the predicted time, not the rows."""
    cfg = small_config(tmp_path, budget_s=1550.0)
    before = serial.plan_only(cfg)
    slower = fixed_model()
    slower.timed = cost.Linear(const=3 * ROW_S)
    slower.setup = cost.Linear(const=2 * ROW_S)   # set-up learned from the history: not what the budget chooses by
    monkeypatch.setattr(cost.CostModel, "local", lambda self, *a, **k: slower)
    after = serial.plan_only(cfg)
    assert [r.status for r in after.rows] == [r.status for r in before.rows]
    assert after.total() > before.total() + 2 * ROW_S


def test_a_budget_leaves_a_margin_for_timing_noise(tmp_path, fixed_costs):
    """Rows are chosen to fill (1 - budget_margin) of the budget (the default margin 0.15: a run that
    is 10-20% slower than predicted still ends the rows it chose, and a second run renders nothing)."""
    from bench.run.config import RunConfig as Config
    assert Config(scenes=["cornell_spot"], methods=["direct"]).budget_margin == 0.15
    full = serial.plan_only(small_config(tmp_path, budget_s=1550.0))
    margin = serial.plan_only(small_config(tmp_path, budget_s=1550.0, budget_margin=0.15))
    kept = lambda p: sum(r.status != "over budget" for r in p.rows)
    assert kept(margin) < kept(full)
    assert margin.total() <= 0.85 * 1550.0 < full.total()
    assert "rows chosen for 85% of it" in margin.summary() and "rows chosen" not in full.summary()
    with pytest.raises(ValueError, match="budget_margin"):
        small_config(tmp_path, budget_s=1550.0, budget_margin=1.0).validate()


def test_a_guarded_row_costs_nothing_and_opens_no_view():
    """A row its method's guard skips renders nothing and fetches no reference: the run's clock
    neither counts its view's references nor refuses the rows after it (a default run refused all
    its scenes in motion at a third of its budget: the guarded rows of views the budget had left
    out had opened them, and their reference refinement was counted as still to come)."""
    import time
    from types import SimpleNamespace
    from bench.run.plan import Job
    views = {("big", "main"): {"shared_passes": 0.0, "references": 500.0, "references_refinement": 450.0,
                               "cold_references": 500.0, "cold_shared": 0.0},
             ("small", "main"): {"shared_passes": 0.0, "references": 10.0, "references_refinement": 5.0,
                                 "cold_references": 10.0, "cold_shared": 0.0}}
    guarded = budget.PlannedRow(Job("big", "main", "manylights", 0, {}), 0, "guard", {}, "its method's guard skips it")
    small = budget.PlannedRow(Job("small", "main", "direct", 0, {}), 0, "render", {"timing": 20.0}, cold=20.0)
    plan = budget.RunPlan(rows=[guarded, small], views=views, setup_s=0.0, budget_s=100.0)
    runner = serial.Runner.__new__(serial.Runner)
    runner.cfg, runner.plan, runner.started = SimpleNamespace(budget_s=100.0), plan, time.perf_counter()
    runner._opened_views, runner.rows, runner._planned_done = set(), [], 0.0
    assert runner._over_budget(guarded.job) is None
    assert ("big", "main") not in runner._opened_views and runner._planned_done == 0.0
    assert runner._over_budget(small.job) is None
    assert runner._opened_views == {("small", "main")}


def test_the_timed_frames_count_the_stage_clocks_own_frames():
    """Under a finish-fenced stage clock the harness renders the stage frames apart, after the timed
    ones: a row costs warm-up + timed + stage frames. A model that left them out fitted one factor
    for rows of 4 frames (a slow method at the minimum count) and of 100 (a fast one filling its
    timing budget), and under-predicted the slow ones (quick mode's timing: 132 s predicted, 191 s)."""
    def sample(own_s, budget_s, stage):
        timed = min(max(3, budget_s / own_s), cost.TIMED_MAX_FRAMES)
        return cost.Sample(method="m", terms={"pixels": 1.0}, own_frame_s=own_s, shared_frame_s=0.0, prepare_s=0.0,
                           frames_total_s=(1 + timed + stage) * own_s, error_s=None, error_frames=1, error_renders=0,
                           timing_budget_s=budget_s, frames=3, warmup=1, other_s=None, images=2, stage_frames=stage)
    samples = [sample(own, budget, stage) for own in (0.002, 0.02, 0.2, 2.0) for budget in (0.3, 1.0)
               for stage in (0, 3)]
    model = cost.CostModel.fit(samples)
    for s in samples:
        predicted = model.timed(cost.timed_terms(s.own_frame_s, s.frames, s.timing_budget_s, s.warmup, s.stage_frames))
        assert predicted == pytest.approx(s.frames_total_s, rel=1e-6)
    row = {"status": "ok", "method": "direct", "params": "{}", "width": 32, "height": 24, "frame_ms": 5.0,
           "frames": 3, "warmup": 1, "frames_total_ms": 40.0, "stage_clock": "finish_wall"}
    facts = {"triangle_count": 12, "total_area_m2": 6.0, "scene_radius": 1.0}
    assert cost.sample_of(row, facts, 0.3, 1).stage_frames == 3
    assert cost.sample_of({**row, "stage_clock": "timer_query"}, facts, 0.3, 1).stage_frames == 0


def test_a_budget_is_filled_at_this_machines_speed(tmp_path, monkeypatch):
    """The budget chooses by the prior at this machine's speed, the probe measured once per machine
    and kept in the cache: on a machine twice as fast as the prior's, a row costs half and twice as
    many fit (the prior alone filled a 3-minute budget with 1m45s of work on such a machine), and
    every later plan on the machine chooses the same rows without measuring again."""
    from bench.run import probe
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(cost, "record_history", lambda entry: None)
    frame = {m: cost.Linear(const=10.0) for m in ("direct", "ssdo")}
    prior = cost.CostModel(frame=frame, prepare={m: cost.Linear() for m in frame},
                           timed=cost.Linear(coef={"rendered_s": 1.0}), setup=cost.Linear(), metrics_s_per_pixel=0.0,
                           provenance={"probe": {"gl_s": 0.04, "cpu_s": 0.1}})
    monkeypatch.setattr(cost.CostModel, "prior", classmethod(lambda cls: prior))
    measured = []

    def probe_at(gl_s):
        def machine_probe(ctx):
            measured.append(gl_s)
            return {"gl_s": gl_s, "cpu_s": 0.1}
        return machine_probe

    monkeypatch.setattr(probe, "machine_probe", probe_at(0.04))   # the prior's own machine
    row_s = next(r.cold for r in serial.plan_only(small_config(tmp_path)).rows if r.status == "render")
    budget_s = 2.5 * row_s
    same = serial.plan_only(small_config(tmp_path, budget_s=budget_s))
    assert sum(r.status == "render" for r in same.rows) == 2
    assert measured == [0.04]                                     # measured once, then read from the cache
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache2"))   # another machine, twice as fast
    monkeypatch.setattr(probe, "machine_probe", probe_at(0.02))
    fast = serial.plan_only(small_config(tmp_path, budget_s=budget_s))
    assert [r.cold for r in fast.rows] == pytest.approx([0.5 * r.cold for r in same.rows])
    assert sum(r.status == "render" for r in fast.rows) == 5 > 2
    assert fast.total() <= budget_s and fast.model["cold_speed"]["gl"] == pytest.approx(0.5)
    again = serial.plan_only(small_config(tmp_path, budget_s=budget_s))
    assert [r.status for r in again.rows] == [r.status for r in fast.rows] and measured == [0.04, 0.02]


def test_mitsubas_start_is_counted_once_per_run():
    """A run that renders references pays Mitsuba's start once (its import and kernels: 20 s in the
    fitted prior), with its first view's references: a quick run's five small views took 48 s of
    references for 28 s of samples, the default run's eleven 302 s for 247 s."""
    from bench.run.plan import Job
    views = {(v, "main"): {"shared_passes": 0.0, "references": 10.0, "references_refinement": 5.0,
                           "cold_references": 10.0, "cold_shared": 0.0} for v in ("a", "b")}
    rows = [budget.PlannedRow(Job(v, "main", "direct", 0, {}), 0, "render", {"timing": 1.0}, cold=1.0) for v in ("a", "b")]
    plan = budget.RunPlan(rows=rows, views=views, setup_s=0.0, cold_setup_s=0.0, reference_start_s=20.0)
    assert plan.phases()["references"] == pytest.approx(40.0)
    budget.apply_budget(plan, 42.0)                      # (1 + 10 + 20) + (1 + 10)
    assert [r.status for r in plan.rows] == ["render", "render"]
    budget.apply_budget(plan, 41.0)
    assert [r.status for r in plan.rows][1] == "over budget" and "(predicted 11 s)" in plan.rows[1].reason
    cached = budget.RunPlan(rows=rows, views={k: dict(v, references=0.0) for k, v in views.items()}, setup_s=0.0,
                            reference_start_s=20.0)
    assert cached.phases()["references"] == 0.0          # every reference stored: Mitsuba does not start
    fitted = cost.CostModel.prior()   # the refit of 2026-12-03 puts the start at 0 (absorbed by the scale)
    assert fitted.reference_start_s >= 0 and fitted.reference_scale > 0
