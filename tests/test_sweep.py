"""Sweeps: parameter-set expansion, Pareto fronts, Mitsuba equal-error time (log-log interpolation,
1/t extrapolation), speed-up tables on hand-made numbers, and one tiny end-to-end `gibench sweep`."""
from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from bench.protocol.method import MethodBase, Param, ParamError
from bench.analysis.curves import (combined_curve, declared_defaults, mitsuba_seconds_for_error, pareto_front,
                                   pareto_table, sweep_table, variant_labels)
from bench.run.sweep import sweep_param_sets


class OneKnob(MethodBase):
    name = "one_knob"
    params = {"n": Param(4, "count", 1, 64, quality=True, sweep=(1, 4, 16)), "eps": Param(0.1, "eps", 0.0, 1.0)}


class TwoKnobs(MethodBase):
    name = "two_knobs"
    params = {"n": Param(4, "count", 1, 64, quality=True, sweep=(1, 4, 16)),
              "level": Param(2, "level", 0, 8, quality=True, sweep=(0, 2, 4)),
              "eps": Param(0.1, "eps", 0.0, 1.0)}


class NoSweepValues(MethodBase):
    name = "no_values"
    params = {"n": Param(4, "count", 1, 64, quality=True)}


class OutOfRange(MethodBase):
    name = "out_of_range"
    params = {"n": Param(4, "count", 1, 64, quality=True, sweep=(4, 128))}


def test_param_sets():
    assert sweep_param_sets(MethodBase) == [{}]
    assert sweep_param_sets(OneKnob) == [{"n": 1}, {"n": 4}, {"n": 16}]
    # one knob at a time around the defaults; the default set appears once, first
    assert sweep_param_sets(TwoKnobs) == [{}, {"n": 1}, {"n": 16}, {"level": 0}, {"level": 4}]
    with pytest.raises(ValueError, match="'n' declares no sweep values"):
        sweep_param_sets(NoSweepValues)
    with pytest.raises(ParamError, match="out_of_range.*'n'=128"):
        sweep_param_sets(OutOfRange)


def test_pareto_front():
    t = [1.0, 2.0, 3.0, 2.0, 5.0, np.nan, 1.0, 4.0]
    e = [9.0, 4.0, 5.0, 4.0, 1.0, 0.1, 10.0, 1.0]
    # (3,5) dominated by (2,4); (1,10) by (1,9); (5,1) by (4,1); NaN never on the front; the two (2,4) both kept
    assert pareto_front(t, e).tolist() == [True, True, False, True, False, False, False, True]
    assert pareto_front([], []).tolist() == []
    with pytest.raises(ValueError, match="3 times but 2 errors"):
        pareto_front([1, 2, 3], [1, 2])


CURVE = [{"spp": s, "seconds": 0.1 * s, "mse_estimate": 0.8 / s} for s in (1, 4, 16, 64)]  # MSE = 0.08 / t


def test_mitsuba_time_interpolates_log_log():
    s, x = mitsuba_seconds_for_error(CURVE, 0.05)  # between spp 16 (0.05) exactly
    assert s == pytest.approx(1.6) and not x
    s, x = mitsuba_seconds_for_error(CURVE, 0.1)  # between spp 4 and 16: on the 1/t line, t = 0.8
    assert s == pytest.approx(0.8, rel=1e-12) and not x
    # log-log interpolation between two points not on a 1/t line: halfway in log MSE is halfway in log t
    curve = [{"spp": 1, "seconds": 1.0, "mse_estimate": 1.0}, {"spp": 2, "seconds": 4.0, "mse_estimate": 0.01}]
    s, x = mitsuba_seconds_for_error(curve, 0.1)
    assert s == pytest.approx(2.0) and not x


def test_mitsuba_time_extrapolates_along_one_over_t():
    s, x = mitsuba_seconds_for_error(CURVE, 0.8 / 640)  # 10x below the last point
    assert s == pytest.approx(64.0) and x
    s, x = mitsuba_seconds_for_error(CURVE, 8.0)  # above the first point
    assert s == pytest.approx(0.01) and x
    # noisy curve: a point that got worse is ignored (the running minimum)
    noisy = CURVE[:2] + [{"spp": 8, "seconds": 0.8, "mse_estimate": 0.5}] + CURVE[2:]
    assert mitsuba_seconds_for_error(noisy, 0.1) == pytest.approx((0.8, False))
    for bad in (0.0, -1.0, float("nan")):
        s, x = mitsuba_seconds_for_error(CURVE, bad)
        assert math.isnan(s) and not x
    assert math.isnan(mitsuba_seconds_for_error([], 0.1)[0])
    with pytest.raises(ValueError, match="point 0 lacks"):
        mitsuba_seconds_for_error([{"spp": 1}], 0.1)


def test_combined_curve_adds_times_and_mse():
    curves = {"s/v/direct": [{"spp": 1, "seconds": 1.0, "mse_estimate": 0.5}, {"spp": 4, "seconds": 4.0, "mse_estimate": 0.125}],
              "s/v/indirect_visible": [{"spp": 4, "seconds": 8.0, "mse_estimate": 0.25}]}
    assert combined_curve(curves, "s/v") == [{"spp": 4, "seconds": 12.0, "mse_estimate": 0.375}]
    # a noiseless direct reference that stopped at 4 spp stays at its last point
    curves["s/v/direct"] = [{"spp": 4, "seconds": 0.5, "mse_estimate": 0.0}]
    curves["s/v/indirect_visible"].append({"spp": 16, "seconds": 32.0, "mse_estimate": 0.0625})
    assert combined_curve(curves, "s/v") == [{"spp": 4, "seconds": 8.5, "mse_estimate": 0.25},
                                             {"spp": 16, "seconds": 32.5, "mse_estimate": 0.0625}]
    assert combined_curve(curves, "other/v") is None
    with pytest.raises(ValueError, match="s/v/direct: every point needs"):
        combined_curve({"s/v/direct": [{"seconds": 1.0}], "s/v/indirect_visible": curves["s/v/indirect_visible"]}, "s/v")


def _rows():
    return pd.DataFrame([
        {"scene": "s", "view": "v", "method": "a", "params": json.dumps({"n": 1}), "frame_ms": 2.0, "status": "ok",
         "mse.indirect": 0.08, "mse.combined": 0.5},
        {"scene": "s", "view": "v", "method": "a", "params": json.dumps({"n": 4}), "frame_ms": 8.0, "status": "cached",
         "mse.indirect": 0.02, "mse.combined": 0.4},
        {"scene": "s", "view": "v", "method": "b", "params": "{}", "frame_ms": 4.0, "status": "ok",
         "mse.indirect": 0.1, "mse.combined": float("nan")},
        {"scene": "s", "view": "v", "method": "c", "params": "{}", "frame_ms": float("nan"), "status": "failed: boom"},
    ])


def test_sweep_table_speedups_and_pareto():
    curves = {"s/v/indirect_unshadowed": CURVE}
    table = sweep_table(_rows(), curves, {})
    assert list(table["label"]) == ["a n=1", "a n=4", "b"]  # the failed row is dropped
    # a n=1: MSE 0.08 -> Mitsuba t = 0.08/0.08 = 1 s (first curve point is 0.8 at 0.1 s: inside)
    assert table["mitsuba_ms.indirect"].tolist() == pytest.approx([1000.0, 4000.0, 800.0])
    assert table["speedup.indirect"].tolist() == pytest.approx([500.0, 500.0, 200.0])
    assert table["speedup_extrapolated.indirect"].tolist() == [False, False, False]
    assert table["speedup.combined"].isna().all()  # no direct / indirect_visible curve: no claim
    assert not table["speedup_lower_bound.indirect"].any()  # noise floor unknown
    rows = _rows().assign(**{"reference_noise_floor.indirect_unshadowed": 0.045})
    bound = sweep_table(rows, curves, {})["speedup_lower_bound.indirect"]
    assert bound.tolist() == [True, True, False]  # MSE <= 2 x floor: mostly reference noise
    front = pareto_table(table)
    assert list(front["label"]) == ["a n=1", "a n=4"]  # b (4 ms, 0.1) is dominated by a n=1 (2 ms, 0.08)
    assert pareto_table(table.drop(columns=["mse.indirect"])).empty


def test_variant_labels_only_name_varying_params():
    df = pd.DataFrame({"method": ["a", "a", "b"], "params": ['{"n":1,"e":0.1}', '{"n":2,"e":0.1}', '{"n":1}']})
    assert variant_labels(df, {}).tolist() == ["a n=1", "a n=2", "b"]
    # one knob at a time around defaults n=4, k=2: the default row is the bare method name
    sets = [{"n": 4, "k": 2}, {"n": 1, "k": 2}, {"n": 16, "k": 2}, {"n": 4, "k": 0}]
    df = pd.DataFrame({"method": ["a"] * 4, "params": [json.dumps(p) for p in sets]})
    assert variant_labels(df, {}).tolist() == ["a", "a n=1", "a n=16", "a k=0"]


def test_cli_sweep_end_to_end(tmp_path, capsys):
    from bench.cli import main
    out = tmp_path / "sweep"
    assert main(["sweep", "--scenes", "cornell_spot", "--methods", "direct,ir_unshadowed", "--res", "32x24",
                 "--frames", "1", "--warmup", "1", "--no-reference", "--no-progress", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "sweep:" in printed and "pareto:" in printed
    table = pd.read_csv(out / "sweep.csv")
    ir = table[table["method"] == "ir_unshadowed"]
    assert sorted(json.loads(p)["vpl_count"] for p in ir["params"]) == [16, 64, 256, 1024, 4096]
    assert (table[table["method"] == "direct"]["label"] == "direct").all() and len(table) == 6
    assert (table["frame_ms"] > 0).all()
    assert table["speedup.indirect"].isna().all()  # no reference: no speed-up claimed
    assert pd.read_csv(out / "pareto.csv").empty
    # five distinct image folders, and the report builds from the sweep folder
    assert len({p for p in ir["label"]}) == 5
    from reports import build_report
    page = build_report(out).read_text()
    assert "ir_unshadowed vpl_count=4096" in page


def test_cli_sweep_unknown_method(capsys):
    from bench.cli import main
    assert main(["sweep", "--scenes", "cornell_spot", "--methods", "nope", "--no-progress"]) == 2
    assert "unknown method(s) nope" in capsys.readouterr().err


def test_bad_curves_file_names_itself(tmp_path):
    from bench.analysis.curves import load_curves
    assert load_curves(tmp_path) == {}  # absent: Mitsuba was not run
    (tmp_path / "reference_curves.json").write_text("{not json")
    with pytest.raises(ValueError, match="reference_curves.json: not valid JSON"):
        load_curves(tmp_path)
    (tmp_path / "reference_curves.json").write_text("[1, 2]")
    with pytest.raises(ValueError, match="reference_curves.json: expected an object"):
        load_curves(tmp_path)


def test_ladder_labels_name_the_default_rung_by_the_method():
    # a ladder's rungs all differ: the registered defaults, as the run's manifest records them, pick the bare label
    from bench.protocol.registry import load_method
    from bench.run.manifest import method_declaration
    rungs = [{"vpl_count": 64}, {"vpl_count": 256}, {"vpl_count": 1024}, {"vpl_count": 4096}]   # default: 1024
    df = pd.DataFrame({"method": ["ir_unshadowed"] * 4,
                       "params": [json.dumps(dict(p, clamp_distance_rel=1e-4)) for p in rungs]})
    manifest = json.loads(json.dumps({"methods": {"ir_unshadowed": method_declaration(load_method("ir_unshadowed"))}}))
    assert variant_labels(df, declared_defaults(manifest)).tolist() == ["ir_unshadowed vpl_count=64", "ir_unshadowed vpl_count=256",
                                           "ir_unshadowed", "ir_unshadowed vpl_count=4096"]


def _ladder_run(folder, manifest: dict):
    """A run folder of ir_unshadowed's four ladder rungs (no images) with the given manifest."""
    from bench.protocol import results as store
    rows = [{"scene": "cornell_spot", "view": "main", "method": "ir_unshadowed", "params": json.dumps({"vpl_count": n}),
             "seed": 0, "width": 8, "height": 6, "status": "ok", "frame_ms": 1.0 + i, "frame_ms_iqr": 0.1,
             "image_dir": f"images/cornell_spot/main/ir_unshadowed@{n}"} for i, n in enumerate((16, 64, 256, 1024))]
    folder.mkdir()
    store.save_results(folder, rows)
    (folder / "manifest.json").write_text(json.dumps(manifest))
    return folder


def test_labels_come_from_the_run_manifest_not_todays_code(tmp_path):
    from bench.analysis.curves import write_sweep
    from reports import build_report
    # the run declared vpl_count=64 its default (today's class says 256): the 64 rung is the bare method
    run = _ladder_run(tmp_path / "run", {"methods": {"ir_unshadowed": {"version": "old", "defaults": {"vpl_count": 64}}}})
    sweep_path, _ = write_sweep(run)
    assert pd.read_csv(sweep_path)["label"].tolist() == ["ir_unshadowed vpl_count=16", "ir_unshadowed",
                                                         "ir_unshadowed vpl_count=256", "ir_unshadowed vpl_count=1024"]
    page = build_report(run).read_text()
    assert "<td class='l'>ir_unshadowed vpl_count=256</td>" in page and "<td class='l'>ir_unshadowed</td>" in page
    # a run older than the manifest's `methods`: no declared default, every rung is named by its value
    old = _ladder_run(tmp_path / "old", {"git_commit": "abc"})
    sweep_path, _ = write_sweep(old)
    assert pd.read_csv(sweep_path)["label"].tolist() == [f"ir_unshadowed vpl_count={n}" for n in (16, 64, 256, 1024)]
    assert "<td class='l'>ir_unshadowed</td>" not in build_report(old).read_text()


def test_sweep_table_keeps_the_error_over_frames():
    frames = {"bias2.indirect": 0.01, "bias2_ci.indirect": 1e-3, "rel_variance.combined": 0.2,
              "rel_variance_ci.combined": 0.01, "mse_accumulated.indirect_visible": 0.03, "extra.error_frames": 8,
              "mean_ratio.indirect": 0.9}
    table = sweep_table(_rows().assign(**frames), {}, {}, keep=("extra.error_frames",))
    for column in frames:
        if column != "mean_ratio.indirect":
            assert column in table.columns and table[column].notna().all(), column
    assert "mean_ratio.indirect" not in table.columns   # a bias figure, not an error column
    assert "bias2.indirect" not in sweep_table(_rows(), {}, {}).columns   # an old run: nothing new
