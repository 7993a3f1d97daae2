"""Between-method tables (equal time, equal error) and the paper-reproduction table, on
synthetic runs whose answers are known in closed form."""
import json
import math

import numpy as np
import pandas as pd
import pytest

from bench.analysis import compare

from bench.analysis import reproduction


def row(method, t, e, *, default=False, iqr=0.0, floor=0.0, scene="s", view="v", params=None, **extra):
    image_dir = f"images/{scene}/{view}/{method}" + ("" if default else f"@{abs(hash((t, e))) % 10**8:08d}")
    rec = {"scene": scene, "view": view, "method": method, "frame_ms": t, "frame_ms_iqr": iqr,
           "mse.combined": e, "reference_noise_floor.direct": floor, "reference_noise_floor.indirect_visible": 0.0,
           "image_dir": image_dir, "params": json.dumps(params or {}), "status": "ok"}
    rec.update(extra)
    return rec


def test_envelope_drops_dominated_points():
    t, e = compare.envelope([4, 1, 2, 3], [1, 4, 2, 3])
    assert list(t) == [1, 2, 4] and list(e) == [4, 2, 1]


def test_interpolation_is_log_log_and_not_extended():
    times, errors = [1, 2, 4], [4, 2, 1]  # e = 4 / t
    assert compare.error_at_time(times, errors, math.sqrt(2))[0] == pytest.approx(4 / math.sqrt(2))
    assert compare.time_at_error(times, errors, 3.0)[0] == pytest.approx(4 / 3)
    assert math.isnan(compare.error_at_time(times, errors, 0.5)[0])        # cannot run that fast
    assert compare.error_at_time(times, errors, 10) == (1.0, True)         # no slower rung: capped
    assert math.isnan(compare.time_at_error(times, errors, 0.5)[0])        # never reaches it
    assert compare.time_at_error(times, errors, 8) == (1.0, True)          # reached at its fastest rung


def test_ratios_with_known_answers():
    # A: e = 4 / t over t = 1, 2, 4 (default at 2); B: a single point (2 ms, error 1)
    table = pd.DataFrame([row("A", 1, 4), row("A", 2, 2, default=True), row("A", 4, 1), row("B", 2, 1, default=True)])
    out = compare.compare_view(table, "mse.combined").set_index(["method_a", "method_b", "kind"])
    assert out.loc[("A", "B", "error_at_equal_time"), "ratio"] == pytest.approx(2.0)   # A at 2 ms: error 2
    assert out.loc[("A", "B", "time_at_equal_error"), "ratio"] == pytest.approx(2.0)   # A reaches 1 at 4 ms
    assert out.loc[("B", "A", "error_at_equal_time"), "ratio"] == pytest.approx(0.5)
    capped = out.loc[("B", "A", "time_at_equal_error")]
    assert capped["ratio"] == pytest.approx(1.0) and capped["capped"]
    # without timing spread or reference noise, the interval is the point
    assert out.loc[("A", "B", "error_at_equal_time"), "lo"] == pytest.approx(2.0)
    assert out.loc[("A", "B", "error_at_equal_time"), "hi"] == pytest.approx(2.0)


def test_uncertainty_widens_the_interval():
    table = pd.DataFrame([row("A", 1, 4, iqr=0.2), row("A", 2, 2, default=True, iqr=0.4), row("A", 4, 1, iqr=0.8),
                          row("B", 2, 1, default=True, iqr=0.4, floor=0.5)])
    out = compare.compare_view(table, "mse.combined").set_index(["method_a", "method_b", "kind"])
    r = out.loc[("A", "B", "error_at_equal_time")]
    assert r["lo"] < 2.0 < r["hi"]
    # B's true error may be as low as 0.5 (its floor): A's error 2 at B's time is then up to 4x B's
    assert r["hi"] >= 4.0 - 1e-9


def test_comparison_table_covers_views_and_errors():
    table = pd.DataFrame([row("A", 1, 4, default=True), row("B", 2, 1, default=True),
                          row("A", 1, 4, default=True, view="w"), row("B", 2, 1, default=True, view="w")])
    table["mse.indirect"] = table["mse.combined"] * 2
    out = compare.comparison_table(table)
    assert set(out["view"]) == {"v", "w"} and set(out["error"]) == {"mse.combined", "mse.indirect"}
    assert len(out) == 2 * 2 * 2 * 2  # views x errors x ordered pairs x kinds


def test_flc_table2_ratios_and_claim():
    # DSS 3x FLC's time, FLC 2x direct's, on a scene named like the paper's Sponza
    table = pd.DataFrame([row("direct", 10, 1, default=True, scene="sponza"), row("flc", 20, 1, default=True, scene="sponza"),
                          row("dss", 60, 1, default=True, scene="sponza")])
    out = reproduction.reproduction_table(table, {"sponza": 66e3}).set_index("claim")
    assert out.loc["FLC / direct frame time", "run_value"] == pytest.approx(2.0)
    assert out.loc["FLC / direct frame time", "paper_value"] == pytest.approx(8 / 4)
    dss = out.loc["DSS / FLC frame time (paper: > 1, FLC faster)"]
    assert dss["run_value"] == pytest.approx(3.0) and dss["status"] == "reproduced"
    assert out.loc["SSDO / direct frame time", "status"] == "not measured"


def test_flc_table2_claim_fails_when_dss_is_faster_and_small_scenes_have_no_counterpart():
    table = pd.DataFrame([row("flc", 30, 1, default=True, scene="highpoly_1m"), row("dss", 10, 1, default=True, scene="highpoly_1m"),
                          row("flc", 3, 1, default=True, scene="tiny"), row("dss", 10, 1, default=True, scene="tiny")])
    out = reproduction.reproduction_table(table, {"highpoly_1m": 1e6, "tiny": 1000})
    assert set(out["scene"]) == {"highpoly_1m"}
    claim = out[out["claim"].str.startswith("DSS")].iloc[0]
    assert claim["status"] == "not reproduced" and "Oil Platform" in claim["note"]


def test_val_fig10_convergence_in_cluster_count():
    def val(count, e):
        return row("val_clustered", 10 + count, e, params={"cluster_count": count, "vpl_count": 1024},
                   **{"mse.indirect_visible": e})
    good = pd.DataFrame([val(5, 3.0), val(10, 2.0), val(30, 1.0)])
    bad = pd.DataFrame([val(5, 1.0), val(10, 2.0), val(30, 1.0)])
    assert reproduction.val_fig10(good)[0]["status"] == "reproduced"
    failed = reproduction.val_fig10(bad)[0]
    assert failed["status"] == "not reproduced" and failed["run_value"] == pytest.approx(2.0)
    single = reproduction.val_fig10(pd.DataFrame([val(30, 1.0)]))[0]
    assert single["status"] == "not measured"


def test_gates_table2_ordering():
    table = pd.DataFrame([row("visibility_gates", 5, 1.0, default=True), row("ir_unshadowed", 5, 2.0, default=True),
                          row("direct", 1, 0.5, default=True)])
    out = reproduction.gates_table2(table)
    status = {r["claim"]: r["status"] for r in out}
    assert status["gates MSE / unshadowed VPLs MSE < 1"] == "reproduced"
    assert status["gates MSE / direct-only MSE <= 1"] == "not reproduced"
    assert np.isfinite([r["paper_value"] for r in out]).all()


def test_gates_claim_is_not_applicable_without_indirect_occlusion():
    table = pd.DataFrame([row("visibility_gates", 5, 1.0, default=True), row("ir_unshadowed", 5, 1.0, default=True),
                          row("ir_shadowed", 50, 1.0, default=True), row("direct", 1, 2.0, default=True)])
    status = {r["claim"]: r["status"] for r in reproduction.gates_table2(table)}
    assert status["gates MSE / unshadowed VPLs MSE < 1"] == "not applicable"
    table.loc[table["method"] == "ir_shadowed", "mse.combined"] = 0.5   # shadows matter: the claim is testable
    status = {r["claim"]: r["status"] for r in reproduction.gates_table2(table)}
    assert status["gates MSE / unshadowed VPLs MSE < 1"] == "not reproduced"


# ---------------------------------------------------------------------------- the error over frames (issue 24)
def test_error_over_frames_compares_with_its_interval_over_pixels():
    # variance.indirect: A's rungs e = 4 / t, B one point; B's value carries an interval of +-0.5
    def var_row(method, t, e, ci, **kw):
        return row(method, t, 1.0, **{"variance.indirect": e, "variance_ci.indirect": ci}, **kw)
    table = pd.DataFrame([var_row("A", 1, 4, 0.0), var_row("A", 2, 2, 0.0, default=True), var_row("A", 4, 1, 0.0),
                          var_row("B", 2, 1, 0.5, default=True),
                          var_row("C", 2, 0.0, 0.0, default=True)])   # deterministic: variance 0, off the log axes
    out = compare.comparison_table(table, errors=("variance.indirect",))
    assert set(out["error"]) == {"variance.indirect"} and set(out["method_b"]) == {"A", "B"}
    r = out.set_index(["method_a", "method_b", "kind"]).loc[("A", "B", "error_at_equal_time")]
    assert r["ratio"] == pytest.approx(2.0)
    # B's true variance in [0.5, 1.5]: A's 2 at B's time is 4/3 .. 4 times B's (no noise floor subtracted)
    assert r["lo"] == pytest.approx(2 / 1.5) and r["hi"] == pytest.approx(4.0)
    # the same numbers as an MSE column would get no interval without a noise floor
    table["mse.indirect"] = table["variance.indirect"]
    plain = compare.compare_view(table, "mse.indirect").set_index(["method_a", "method_b", "kind"])
    assert plain.loc[("A", "B", "error_at_equal_time"), "hi"] == pytest.approx(2.0)


def test_flc_bias_against_mitsuba_is_its_targets():
    def frames(method, bias2, ci, **kw):
        return row(method, 5, 1.0, **{"rel_bias2.indirect": bias2, "rel_bias2_ci.indirect": ci}, **kw)
    target = dict(default=False, params={"emission": "flc", "jitter_frames": 64})
    table = pd.DataFrame([frames("flc", 0.051, 0.002, default=True), frames("manylights", 0.30, 0.01, default=True),
                          frames("manylights", 0.049, 0.002, **target),
                          frames("manylights", 0.2, 0.002, default=False, params={"emission": "flc", "jitter_frames": 1})])
    [r] = reproduction.flc_unbiased(table)
    assert r["status"] == "reproduced" and r["run_value"] == pytest.approx(0.051 / 0.049)
    assert "jitter_frames=64" in r["note"]
    table.loc[table["method"] == "flc", "rel_bias2.indirect"] = 0.08   # FLC biased beyond its lobe
    assert reproduction.flc_unbiased(table)[0]["status"] == "not reproduced"
    in_table = reproduction.reproduction_table(table)
    assert (in_table["paper"] == "FLC eq. 8-9").sum() == 1
    # no target row: not measured; no error over frames (an old run): no row at all
    only_flc = table[table["method"] == "flc"]
    assert reproduction.flc_unbiased(only_flc)[0]["status"] == "not measured"
    # the centroid sum is not FLC's target (FLC jitters its VPLs): not measured either
    centroid = table[~table["params"].str.contains('"jitter_frames": 64')]
    assert reproduction.flc_unbiased(centroid)[0]["status"] == "not measured"
    # an flc row with eq. 5 as printed (near_field=paper_eps) is the one judged, not the default
    paper = pd.concat([table, pd.DataFrame([frames("flc", 0.049, 0.002, params={"near_field": "paper_eps"})])],
                      ignore_index=True)
    [r] = reproduction.flc_unbiased(paper)
    assert r["status"] == "reproduced" and "near_field: paper_eps" in r["note"]
    assert reproduction.flc_unbiased(only_flc.drop(columns=["rel_bias2.indirect"])) == []
    assert reproduction.flc_unbiased(only_flc.assign(**{"rel_bias2.indirect": np.nan})) == []
