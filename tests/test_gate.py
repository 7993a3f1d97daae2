"""The regression gate: synthetic run folders for the rules, and one end-to-end pair of real runs."""
import json
import shutil

import numpy as np
import pytest

from bench.gate import compare_runs
from bench.gate.statistics import adjust_p_values, error_check, timing_check
from bench.protocol.results import load_results, params_json, save_results, summarize_samples

MACHINE = {"gl_renderer": "llvmpipe (LLVM 19.1.7, 256 bits)", "cpu": "test cpu"}


def make_row(scene="box", view="main", method="manylights", samples=(10.0, 10.4, 9.8, 10.1, 10.2, 9.9),
             errors=None, version="v1", status="ok", params=None, seed=0, width=64, height=48):
    med, iqr = summarize_samples(list(samples))
    row = {"scene": scene, "view": view, "method": method, "params": params_json(params or {}), "seed": seed,
           "width": width, "height": height, "frames": len(samples), "warmup": 1, "frame_ms": med,
           "frame_ms_iqr": iqr, "status": status, "method_version": version,
           "samples.frame_ms": json.dumps(list(samples)), "stage_ms.gather": med * 0.6,
           "image_dir": f"images/{scene}/{view}/{method}"}
    default_errors = {"mse.indirect": 0.02, "relmse.indirect": 0.3, "flip_mean.indirect": 0.2,
                      "dssim.combined": 0.05, "ciede2000.combined": 3.0}
    row.update(default_errors if errors is None else errors)
    return row


def write_run(path, rows, machine=MACHINE):
    path.mkdir(parents=True, exist_ok=True)
    save_results(path, rows)
    (path / "manifest.json").write_text(json.dumps({"schema_version": 1, "git_commit": "abc123", "machine": machine}))
    return path


def two_rows(**kw):
    return [make_row(**kw), make_row(method="direct", samples=(4.0, 4.1, 3.9, 4.05, 3.95, 4.0), **kw)]


def slowed(rows, factor, method="manylights"):
    out = []
    for r in rows:
        r = dict(r)
        if method is None or r["method"] == method:
            s = [v * factor for v in json.loads(r["samples.frame_ms"])]
            r["samples.frame_ms"] = json.dumps(s)
            r["frame_ms"] *= factor
            r["stage_ms.gather"] *= factor
        out.append(r)
    return out


RUN_JITTER = (1.0, 1.03, 0.98, 1.01, 0.995)  # run-to-run variation of a machine: a few percent


def write_runs(path, rows, n=3, factor=1.0, method="manylights", offset=0):
    """n run folders of the same rows, each run's times scaled by its own run-to-run jitter (and
    `factor` for `method`, every method when None); returns the folders as one comma-separated side."""
    folders = []
    for i in range(n):
        jitter = RUN_JITTER[(i + offset) % len(RUN_JITTER)]
        run_rows = slowed(slowed(rows, jitter, method=None), factor, method=method)
        folders.append(str(write_run(path / f"r{i}", run_rows)))
    return ",".join(folders)


# ---------------------------------------------------------------------------- pass / fail
def test_run_against_itself_passes(tmp_path):
    a = write_run(tmp_path / "a", two_rows())
    res = compare_runs(a, a)
    assert res.exit_code == 0 and res.compared == 2 and not res.regressions and not res.improvements
    md = res.markdown()
    assert md.startswith("## gibench gate: PASS") and "**Verdict: PASS** — 2 row(s) compared" in md
    runs = write_runs(tmp_path / "rep", two_rows())
    res = compare_runs(runs, runs)
    assert res.exit_code == 0 and res.timing_tested == 2 and not res.regressions


def test_injected_slowdown_fails_on_repetitions(tmp_path):
    rows = two_rows()
    a, b = write_runs(tmp_path / "a", rows), write_runs(tmp_path / "b", rows, factor=1.5, offset=1)
    res = compare_runs(a, b)
    assert res.exit_code == 1
    [f] = res.regressions
    assert f.row == "box/main/manylights" and f.check == "frame_ms (median)" and f.change.startswith("x1.5")
    assert f.p_value < 0.05 and "gather" in f.note and "3 vs 3 runs" in f.note
    md = res.markdown()
    assert "### Regressions (1)" in md and "| box/main/manylights | frame_ms (median) |" in md
    assert "**Verdict: FAIL** — 1 regression(s) in 1 of 2 compared row(s)" in md and "Holm" in md
    # the mirror image is an improvement, not a failure
    back = compare_runs(b, a)
    assert back.exit_code == 0 and len(back.improvements) == 1


def test_one_loaded_run_is_not_a_regression(tmp_path):
    """Issue #15: frames of one process share its load; a candidate run slowed by background load
    separated completely from the baseline on 6 vs 6 frames (FAIL in every row). One run per side
    gives no timing verdict: it is listed as not tested."""
    rows = two_rows()
    a, b = write_run(tmp_path / "a", rows), write_run(tmp_path / "b", slowed(rows, 1.4, method=None))
    res = compare_runs(a, b)
    assert res.exit_code == 0 and not res.regressions and res.timing_tested == 0
    assert len(res.undecidable_timing) == 2
    md = res.markdown()
    assert "### Timing not tested (2)" in md and "x1.400" in md and "gibench gate A1,A2,A3 B1,B2,B3" in md
    assert any("timing is gated on >= 3 runs per side" in n for n in res.notes)


def test_relative_timing_cancels_load(tmp_path):
    """Load slows every method of a run alike: gated relative to `direct` in the same run, a
    uniformly slowed candidate passes, and a slowdown of one method still fails."""
    rows = two_rows()
    a = write_runs(tmp_path / "a", rows)
    loaded = write_runs(tmp_path / "b", rows, factor=1.5, method=None, offset=1)
    assert compare_runs(a, loaded).exit_code == 1              # absolute times: the load looks like a regression
    res = compare_runs(a, loaded, relative_to="direct")
    assert res.exit_code == 0 and res.timing_tested == 1 and not res.regressions
    worse = write_runs(tmp_path / "c", slowed(rows, 1.5, method=None), factor=1.4, offset=2)
    res = compare_runs(a, worse, relative_to="direct")
    assert res.exit_code == 1 and [f.row for f in res.regressions] == ["box/main/manylights"]
    assert res.regressions[0].check == "frame_ms (relative)" and "relative to `direct`" in res.markdown()
    with pytest.raises(ValueError, match="no row of method 'ssdo'"):
        compare_runs(a, a, relative_to="ssdo")


def test_p_values_are_adjusted_across_rows(tmp_path):
    from scipy.stats import false_discovery_control
    p = [0.01, 0.04, 0.03, 0.2]
    assert list(adjust_p_values(p, "holm")) == pytest.approx([0.04, 0.09, 0.09, 0.2])
    assert list(adjust_p_values(p, "bh")) == pytest.approx(list(false_discovery_control(p)))
    # a marginal slowdown: significant for one row alone, not once twelve rows are tested together
    base, cand = [10.0, 10.9, 10.3], [11.5, 12.5, 11.6]
    t = timing_check(base, cand, 0.10, 0.05)
    assert t["verdict"] == "regression" and 0.05 / 12 < t["p_slower"] < 0.05

    def rows_with(times, scenes):
        return [make_row(scene=sc, samples=(v,) * 5) for sc in scenes for v in [times]]

    def side(path, times, scenes):
        return ",".join(str(write_run(path / f"r{i}", rows_with(v, scenes))) for i, v in enumerate(times))

    one = ["s0"]
    assert compare_runs(side(tmp_path / "a1", base, one), side(tmp_path / "b1", cand, one)).exit_code == 1
    many = [f"s{i}" for i in range(12)]
    res = compare_runs(side(tmp_path / "a", base, many), side(tmp_path / "b", cand, many))
    assert res.exit_code == 0 and res.timing_tested == 12 and not res.regressions
    assert compare_runs(tmp_path / "a" / "r0", tmp_path / "a" / "r0", correction="bh").exit_code == 0
    with pytest.raises(ValueError, match="correction"):
        compare_runs(tmp_path / "a" / "r0", tmp_path / "a" / "r0", correction="none")


def test_cached_rows_do_not_count_as_runs(tmp_path):
    rows = two_rows()
    a = write_runs(tmp_path / "a", rows)
    cached = [dict(r, status="cached") for r in slowed(rows, 1.5)]
    b = ",".join(str(write_run(tmp_path / f"b{i}", cached)) for i in range(3))
    res = compare_runs(a, b)
    assert res.exit_code == 0 and res.timing_tested == 0
    assert all("cached rows repeat old timings" in why for *_, why in res.undecidable_timing)


def test_changed_error_fails(tmp_path):
    rows = two_rows()
    worse = [dict(r) for r in rows]
    worse[0]["mse.indirect"] = 0.02 * 1.08        # +8% > 5%
    worse[0]["ciede2000.combined"] = 3.0 * 1.04   # +4% < 5%: not a regression
    worse[1]["dssim.combined"] = 0.05 * 0.5       # better: an improvement
    res = compare_runs(write_run(tmp_path / "a", rows), write_run(tmp_path / "b", worse))
    assert res.exit_code == 1
    assert [(f.row, f.check, f.change) for f in res.regressions] == [("box/main/manylights", "mse.indirect", "+8.0%")]
    assert [(f.row, f.check) for f in res.improvements] == [("box/main/direct", "dssim.combined")]
    # a looser threshold lets it through
    assert compare_runs(tmp_path / "a", tmp_path / "b", error_threshold=0.10).exit_code == 0


def test_errors_net_of_noise_floor_and_only_against_the_same_references(tmp_path):
    refs = {"reference_key.indirect_unshadowed": "k" * 32, "reference_spp.indirect_unshadowed": 256,
            "reference_noise_floor.indirect_unshadowed": 0.0009}
    base = make_row(errors={"mse.indirect": 0.00100, "relmse.indirect": 0.5}) | refs
    # +3% in raw MSE, but +30% in the method's own error (MSE minus the reference's noise floor 0.0009)
    cand = dict(base, **{"mse.indirect": 0.00103})
    res = compare_runs(write_run(tmp_path / "a", [base]), write_run(tmp_path / "b", [cand]))
    [f] = res.regressions
    assert f.check == "mse.indirect" and f.change == "+30.0%" and "noise floor" in f.note
    # a better-converged reference for the candidate (refinement depends on which methods ran):
    # its errors are not comparable, not a regression
    other = dict(base, **{"mse.indirect": 0.0015, "relmse.indirect": 0.9, "reference_spp.indirect_unshadowed": 1024})
    res = compare_runs(tmp_path / "a", write_run(tmp_path / "c", [other]))
    assert res.exit_code == 0 and not res.regressions
    assert res.not_comparable == [("box/main/manylights",
                                   "errors of indirect (reference indirect_unshadowed spp 256 -> 1024) not comparable")]
    assert any("references differ" in n for n in res.notes)


def test_error_floor_and_zero_baseline():
    assert error_check("mse", 0.0, 1e-12, 0.05) is None          # zero vs round-off
    assert error_check("mse", 0.0, 1e-3, 0.05) == "regression"   # zero vs a real error
    assert error_check("flip_mean", 0.1, 0.1 + 5e-7, 0.0) is None
    assert error_check("flip_mean", 0.1, 0.2, 0.05) == "regression"
    assert error_check("flip_mean", 0.2, 0.1, 0.05) == "improvement"


def test_noisy_but_equal_runs_do_not_flag():
    rng = np.random.default_rng(11)
    flagged = 0
    for trial in range(200):
        base = list(10 * np.exp(rng.normal(0, 0.1, 3)))
        cand = list(10 * np.exp(rng.normal(0, 0.1, 3)))
        flagged += timing_check(base, cand, 0.10, 0.05)["verdict"] == "regression"
    assert flagged <= 10  # same distribution: at most alpha of single-row tests fire
    # a ratio over the threshold that the test does not confirm: not flagged
    t = timing_check([10.0, 14.0, 8.0], [9.5, 15.5, 12.0], 0.10, 0.05)
    assert t["ratio"] > 1.10 and t["p_slower"] >= 0.05 and t["verdict"] is None
    # a consistent shift below the threshold: confirmed by the test but too small
    steady = [10.0, 10.01, 9.99]
    t = timing_check(steady, [v * 1.05 for v in steady], 0.10, 0.05)
    assert t["p_slower"] < 0.05 and t["verdict"] is None


# ---------------------------------------------------------------------------- comparability and coverage
def test_changed_method_version_is_not_comparable(tmp_path):
    rows = two_rows()
    changed = slowed(rows, 2.0)
    changed[0]["method_version"] = "v2"
    a, b = write_run(tmp_path / "a", rows), write_run(tmp_path / "b", changed)
    res = compare_runs(a, b)
    assert res.exit_code == 0 and res.compared == 1
    assert res.not_comparable == [("box/main/manylights", "method version changed (v1 -> v2)")]
    assert "### Not comparable (1)" in res.markdown()
    changed[0]["mse.indirect"] = 0.04
    res = compare_runs(a, write_run(tmp_path / "c", changed), compare_changed_versions=True)
    assert res.exit_code == 1 and res.regressions[0].note.startswith("method changed")


def test_nothing_compared_is_an_error_with_the_right_reason(tmp_path):
    rows = two_rows()
    res = compare_runs(write_run(tmp_path / "a", rows), write_run(tmp_path / "b", two_rows(width=128, height=96)))
    assert res.exit_code == 2 and res.compared == 0
    assert "nothing was compared" in res.error and "2 resolution changed" in res.error
    assert not any("method version" in n for n in res.notes)


def test_edited_scene_is_not_comparable(tmp_path):
    rows = [dict(r, scene_hash="a" * 64) for r in two_rows()]
    edited = [dict(rows[0], scene_hash="b" * 64, **{"mse.indirect": 0.5}), rows[1]]
    res = compare_runs(write_run(tmp_path / "a", rows), write_run(tmp_path / "b", edited))
    assert res.exit_code == 0 and res.compared == 1 and not res.regressions
    assert res.not_comparable == [("box/main/manylights", "scene content changed (aaaaaaaa -> bbbbbbbb)")]


def test_frames_warmup_and_stage_clock_are_checked(tmp_path):
    rows = [dict(r, stage_clock="finish_wall") for r in two_rows()]
    a = write_runs(tmp_path / "a", rows)
    for i, change in enumerate(({"warmup": 3}, {"frames": 9}, {"stage_clock": "gl_query"})):
        other = [dict(r, **change) for r in rows]
        res = compare_runs(a, write_runs(tmp_path / f"b{i}", other, factor=1.5))
        assert res.exit_code == 0 and not res.regressions, change
        name = next(iter(change))
        assert sum(f"timing not comparable ({name}" in why for _, why in res.not_comparable) == 2, change


def test_missing_new_failed_and_skipped_rows(tmp_path):
    rows = two_rows() + [make_row(method="ir_shadowed", status="failed: shader error")]
    cand = [dict(rows[0], status="failed: method 'manylights' frame 0: GL error"),
            make_row(method="ssdo"), dict(rows[2], status="ok")]
    res = compare_runs(write_run(tmp_path / "a", rows), write_run(tmp_path / "b", cand))
    assert res.exit_code == 1
    [f] = res.regressions
    assert f.check == "status" and f.baseline == "ok" and f.candidate.startswith("failed:")
    assert res.missing == ["box/main/direct"] and res.new == ["box/main/ssdo"]
    assert res.skipped_baseline == [("box/main/ir_shadowed", "failed: shader error")]
    md = res.markdown()
    assert "### Missing in candidate (1)" in md and "### New in candidate (1)" in md
    # a missing row alone is reported, not a failure
    res = compare_runs(tmp_path / "a", write_run(tmp_path / "c", rows[:1]))
    assert res.exit_code == 0 and res.missing == ["box/main/direct"]


def test_rows_match_on_params_and_seed(tmp_path):
    rows = [make_row(params={"n": 1}), make_row(params={"n": 2}, samples=(20.0, 20.5, 19.5, 20.2, 20.1, 19.9)),
            make_row(seed=3)]
    # same rows in another order, the n=2 row and the seed-3 row slowed: only those regress
    cand = [slowed([rows[2]], 1.4)[0], rows[0], slowed([rows[1]], 1.4)[0]]
    res = compare_runs(write_runs(tmp_path / "a", rows), write_runs(tmp_path / "b", cand, offset=1))
    assert res.exit_code == 1 and res.compared == 3 and not res.missing and not res.new
    assert sorted(f.row for f in res.regressions) == ["box/main/manylights", "box/main/manylights (seed 3)"]
    assert sorted(round(f.candidate / f.baseline, 1) for f in res.regressions) == [1.4, 1.4]


def test_bad_input(tmp_path, capsys):
    from bench.cli import main
    a = write_run(tmp_path / "a", two_rows())
    with pytest.raises(FileNotFoundError, match="baseline run folder not found"):
        compare_runs(tmp_path / "nope", a)
    assert main(["gate", str(a), str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("gibench: candidate run folder not found") and "\n" not in err
    (tmp_path / "empty").mkdir()
    assert main(["gate", str(a), str(tmp_path / "empty")]) == 2
    assert "no results.csv" in capsys.readouterr().err
    with pytest.raises(ValueError, match="alpha"):
        compare_runs(a, a, alpha=1.5)
    with pytest.raises(ValueError, match="min_runs"):
        compare_runs(a, a, min_runs=1)
    # nothing in common: bad input, exit 2 with the reason in the summary
    other = write_run(tmp_path / "o", [make_row(scene="other")])
    res = compare_runs(a, other)
    assert res.exit_code == 2 and "no row of the candidate matches" in res.markdown()


def test_cli_gate_prints_markdown(tmp_path, capsys):
    from bench.cli import main
    rows = two_rows()
    a, b = write_runs(tmp_path / "a", rows), write_runs(tmp_path / "b", rows, factor=1.5, offset=1)
    assert main(["gate", a, a]) == 0
    assert "**Verdict: PASS**" in capsys.readouterr().out
    assert main(["gate", a, b, "--time-threshold", "0.6"]) == 0   # 50% slower, 60% allowed
    capsys.readouterr()
    assert main(["gate", a, b]) == 1
    out = capsys.readouterr().out
    assert "## gibench gate: FAIL" in out and "**Verdict: FAIL**" in out
    assert main(["gate", a, b, "--relative-to", "direct", "--correction", "bh"]) == 1
    assert "Benjamini-Hochberg" in capsys.readouterr().out
    # nothing compared: exit 2, not a pass
    assert main(["gate", a, str(write_run(tmp_path / "c", two_rows(width=32, height=24)))]) == 2


def test_machine_difference_is_noted(tmp_path):
    rows = two_rows()
    res = compare_runs(write_run(tmp_path / "a", rows),
                       write_run(tmp_path / "b", rows, machine=dict(MACHINE, gl_renderer="NVIDIA RTX")))
    assert res.exit_code == 0 and any("machines differ" in n for n in res.notes)


# ---------------------------------------------------------------------------- end to end: two real runs
@pytest.mark.gl
def test_end_to_end_real_runs(tmp_path, monkeypatch, capsys):
    """Two tiny real runs (no Mitsuba): the baseline's own images stand in for the reference, so the
    baseline's errors are 0 and an albedo change in the candidate shows up as error regressions."""
    from bench.cli import main
    from bench.analysis.evaluation import evaluate_row
    from bench.model.imageio import read_exr
    from bench.run.serial import RunConfig, run
    from tests.conftest import make_open_box

    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))
    scene = make_open_box()
    albedo = scene.albedo.copy()
    albedo[4:6] = [0.2, 0.2, 0.8]  # the red wall turns blue
    common = dict(methods=["direct", "manylights"], width=64, height=48, frames=10, warmup=1, references=False,
                  progress=False)
    run(RunConfig(scenes=[scene], out=tmp_path / "base", **common), log=lambda m: None)
    run(RunConfig(scenes=[scene.with_albedo(albedo)], out=tmp_path / "cand", **common), log=lambda m: None)

    base_df = load_results(tmp_path / "base")
    refs = {}
    for rec in base_df.to_dict("records"):
        d = tmp_path / "base" / rec["image_dir"]
        indirect = read_exr(d / "indirect.exr")
        refs[rec["method"]] = {"direct": read_exr(d / "direct.exr"), "indirect_unshadowed": indirect,
                               "indirect_visible": indirect}
    for name in ("base", "cand"):
        df = load_results(tmp_path / name)
        rows = []
        for rec in df.to_dict("records"):
            d = tmp_path / name / rec["image_dir"]
            images = {c: read_exr(d / f"{c}.exr") for c in ("direct", "indirect", "combined")}
            rec.update(evaluate_row(images, refs[rec["method"]]))
            rows.append(rec)
        save_results(tmp_path / name, rows)

    assert main(["gate", str(tmp_path / "base"), str(tmp_path / "base")]) == 0
    assert "**Verdict: PASS** — 2 row(s) compared" in capsys.readouterr().out

    # the edited scene is not compared as if unchanged (rows carry the scene's content hash)...
    res = compare_runs(tmp_path / "base", tmp_path / "cand")
    assert res.exit_code == 2 and "scene content changed" in res.error
    # ...so to stand in for a method change that alters the images, the candidate claims the baseline's scene
    df = load_results(tmp_path / "cand")
    df["scene_hash"] = base_df["scene_hash"].iloc[0]
    save_results(tmp_path / "cand", df.to_dict("records"))
    res = compare_runs(tmp_path / "base", tmp_path / "cand")
    assert res.exit_code == 1
    error_findings = {(f.row, f.check) for f in res.regressions if f.check != "frame_ms (median)"}
    assert ("open_box/main/manylights", "mse.indirect") in error_findings   # the bounce off the wall changed
    assert ("open_box/main/direct", "ciede2000.direct") in error_findings    # the wall itself changed colour
    assert "mse.indirect" in res.markdown()

    # an injected slowdown of copies of the baseline fails on timing alone, on three runs per side
    sides = {}
    for name, factor in (("same", 1.0), ("slow", 1.5)):
        folders = []
        for i, jitter in enumerate((1.0, 1.02, 0.99)):
            folder = tmp_path / f"{name}{i}"
            shutil.copytree(tmp_path / "base", folder)
            df = load_results(folder)
            f = factor * jitter
            df["samples.frame_ms"] = [json.dumps([v * f for v in json.loads(s)]) for s in df["samples.frame_ms"]]
            df["frame_ms"] = df["frame_ms"] * f
            save_results(folder, df.to_dict("records"))
            folders.append(str(folder))
        sides[name] = ",".join(folders)
    assert main(["gate", sides["same"], sides["slow"]]) == 1
    out = capsys.readouterr().out
    assert out.count("| frame_ms (median) |") == 2 and "x1.5" in out


def test_folder_with_two_resolutions_matches_each(tmp_path):
    """A run folder keeps rows of earlier resolutions (merge): each is matched at its own size."""
    rows = two_rows() + slowed(two_rows(width=128, height=96), 3.0, method=None)
    cand = rows[:2] + [dict(rows[2], **{"mse.indirect": 0.03}), rows[3]]
    res = compare_runs(write_run(tmp_path / "a", rows), write_run(tmp_path / "b", cand))
    assert res.compared == 4 and not res.not_comparable and not any("duplicate" in n for n in res.notes)
    assert [(f.row, f.check) for f in res.regressions] == [("box/main/manylights", "mse.indirect")]
    assert res.regressions[0].baseline == pytest.approx(0.02)


# ---------------------------------------------------------------------------- issue #27: runs, tables
def _hand_edit(folder, edit):
    """The results of `folder` as a hand-edited CSV: parquet and checksums removed, `edit` applied."""
    import pandas as pd
    (folder / "results.parquet").unlink()
    (folder / "results.checksums.json").unlink()
    df = pd.read_csv(folder / "results.csv")
    edit(df).to_csv(folder / "results.csv", index=False)
    return folder


def test_one_run_listed_twice_is_bad_input(tmp_path, capsys):
    """A,A,A is one run, not three repetitions (it gave p = 0 and FAIL); so is a copied folder."""
    from bench.cli import main
    rows = two_rows()
    a = write_run(tmp_path / "a", rows)
    b = write_runs(tmp_path / "b", rows, factor=1.5)
    assert main(["gate", f"{a},{a},{a}", b]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and f"the baseline lists one run twice: {a} and {a} are the same run" in err
    real = tmp_path / "real"
    write_run(real, rows)
    manifest = json.loads((real / "manifest.json").read_text())
    (real / "manifest.json").write_text(json.dumps(dict(manifest, run_id="0f" * 16, created="2026-01-01T00:00:00")))
    shutil.copytree(real, tmp_path / "copy")
    with pytest.raises(ValueError, match="the candidate lists one run twice: .*run id 0f0f"):
        compare_runs(a, f"{real},{tmp_path / 'copy'}")
    # a copy whose rows differ (another measurement) is another run; one folder on both sides is a self-check
    assert compare_runs(b, b).exit_code == 0


def test_hand_edited_tables(tmp_path, capsys):
    """A non-numeric frame_ms is one line naming the cell (exit 2); a dropped method_version column is
    named in the notes and the verdict instead of a silent pass."""
    from bench.cli import main
    rows = two_rows()
    a = write_run(tmp_path / "a", rows)
    no_versions = _hand_edit(write_run(tmp_path / "nv", rows), lambda df: df.drop(columns=["method_version"]))
    res = compare_runs(a, no_versions)
    assert res.exit_code == 0 and "not checked: method versions of 2 row(s)" in res.verdict()
    assert any("method versions of 2 compared row(s) could not be checked" in n for n in res.notes)

    def text_in_frame_ms(df):
        df["frame_ms"] = df["frame_ms"].astype(object)
        df.loc[1, "frame_ms"] = "fast"
        return df
    bad = _hand_edit(write_run(tmp_path / "bad", rows), text_in_frame_ms)
    assert main(["gate", str(a), str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "column frame_ms holds 'fast' in row 3" in err


# ---------------------------------------------------------------------------- the error over frames (issue 24)
REFS = {"reference_key.indirect_unshadowed": "k" * 32, "reference_spp.indirect_unshadowed": 256,
        "reference_noise_floor.indirect_unshadowed": 1e-6}


def frames_row(bias2=0.004, variance=0.01, k=8, **kw):
    """A row with the error over frames of `indirect` (and its intervals over pixels), as the runner writes them."""
    cols = {"mse.indirect": 0.02, "relmse.indirect": 0.3, "bias2.indirect": bias2, "bias2_ci.indirect": 1e-4,
            "variance.indirect": variance, "variance_ci.indirect": 1e-4, "flicker.indirect": variance,
            "flicker_ci.indirect": 1e-4, "mse_accumulated.indirect": bias2 + variance / k,
            "mse_accumulated_ci.indirect": 1e-4, "rel_variance.indirect": 0.2, "rel_variance_ci.indirect": 1e-3}
    return make_row(errors=cols, **kw) | REFS | {"extra.error_frames": k}


def test_error_over_frames_is_gated_like_the_other_errors(tmp_path):
    a = write_run(tmp_path / "a", [frames_row()])
    noisier = write_run(tmp_path / "b", [frames_row(variance=0.02) | {"mse.indirect": 0.03}])
    res = compare_runs(a, noisier)
    assert res.exit_code == 1
    assert {f.check for f in res.regressions} == {"variance.indirect", "flicker.indirect", "mse.indirect",
                                                  "mse_accumulated.indirect"}
    # --metric: that column only (timing is gated as before)
    res = compare_runs(a, noisier, metrics=["variance.indirect"])
    assert [f.check for f in res.regressions] == ["variance.indirect"] and res.metrics == ("variance.indirect",)
    assert "`variance.indirect` only" in res.markdown()
    res = compare_runs(a, noisier, metrics="relmse.indirect")
    assert res.exit_code == 0 and not res.regressions
    # less bias: an improvement of bias2 and of the accumulated error
    res = compare_runs(a, write_run(tmp_path / "c", [frames_row(bias2=0.001)]), metrics=["bias2.indirect"])
    assert res.exit_code == 0 and [f.check for f in res.improvements] == ["bias2.indirect"]


def test_bias2_within_its_interval_is_no_change(tmp_path):
    # an unbiased method: its bias2 estimate scatters about 0 within its interval over pixels
    base = frames_row(bias2=-2e-5) | {"bias2_ci.indirect": 3e-5}
    same = frames_row(bias2=3e-5) | {"bias2_ci.indirect": 3e-5}
    a = write_run(tmp_path / "a", [base])
    assert compare_runs(a, write_run(tmp_path / "b", [same]), metrics=["bias2.indirect"]).exit_code == 0
    res = compare_runs(a, write_run(tmp_path / "c", [frames_row(bias2=2e-3)]), metrics=["bias2.indirect"])
    [f] = res.regressions
    assert f.baseline == 0.0 and f.candidate == 2e-3 and "95% interval" in f.note   # clamped at 0
    assert error_check("bias2", 0.0, 4e-5, 0.05, spread=5e-5) is None
    assert error_check("bias2", 0.0, 4e-5, 0.05) == "regression"


def test_error_over_frames_needs_the_same_frame_count_not_the_same_reference_spp(tmp_path):
    a = write_run(tmp_path / "a", [frames_row()])
    res = compare_runs(a, write_run(tmp_path / "b", [frames_row(variance=0.05, k=4)]))
    assert res.exit_code == 0 and not res.regressions
    assert ("box/main/manylights", "errors over frames not comparable (error frames 8 -> 4)") in res.not_comparable
    # a better-converged candidate reference: variance and flicker (the method's own spread) are still judged
    refined = frames_row(variance=0.05) | {"reference_spp.indirect_unshadowed": 1024}
    res = compare_runs(a, write_run(tmp_path / "c", [refined]))
    assert {f.check for f in res.regressions} == {"variance.indirect", "flicker.indirect"}
    assert any("not comparable" in why for _, why in res.not_comparable)


def test_metric_option(tmp_path, capsys):
    from bench.cli import main
    a = write_run(tmp_path / "a", [frames_row()])
    b = write_run(tmp_path / "b", [frames_row(variance=0.02)])
    assert main(["gate", str(a), str(b), "--metric", "variance.indirect"]) == 1
    assert "| variance.indirect |" in capsys.readouterr().out
    assert main(["gate", str(a), str(b), "--metric", "mse.indirect,relmse.indirect"]) == 0
    capsys.readouterr()
    for bad in ("variance.foo", "noise.indirect", "variance.direct", "bias2_ci.indirect", ""):
        with pytest.raises(SystemExit) as exc:
            main(["gate", str(a), str(b), "--metric", bad])
        assert exc.value.code == 2
        err = capsys.readouterr().err.strip()
        assert "--metric" in err and "\n" not in err
    with pytest.raises(ValueError, match="unknown error column 'noise.indirect'"):
        compare_runs(a, b, metrics=["noise.indirect"])
    # a column a side lacks (an old run, or --error-frames 1): exit 2, saying so
    old = write_run(tmp_path / "old", [make_row() | REFS])
    assert main(["gate", str(old), str(b), "--metric", "variance.indirect"]) == 2
    assert "has no column variance.indirect" in capsys.readouterr().out
    # the column exists but no row has it on both sides: nothing judged, exit 2
    empty = write_run(tmp_path / "e", [frames_row() | {"variance.indirect": float("nan")}])
    res = compare_runs(empty, b, metrics=["variance.indirect"])
    assert res.exit_code == 2 and "nothing was judged" in res.error
    # without --metric an old baseline still gates its own columns
    assert compare_runs(old, b).exit_code == 0
