"""The regression gate: synthetic run folders for the rules, and one end-to-end pair of real runs."""
import json
import shutil

import numpy as np
import pytest

from bench.gate import compare_runs, error_check, smallest_p, timing_check
from bench.results import load_results, params_json, save_results, summarize_samples

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
        if r["method"] == method:
            s = [v * factor for v in json.loads(r["samples.frame_ms"])]
            r["samples.frame_ms"] = json.dumps(s)
            r["frame_ms"] *= factor
            r["stage_ms.gather"] *= factor
        out.append(r)
    return out


# ---------------------------------------------------------------------------- pass / fail
def test_run_against_itself_passes(tmp_path):
    a = write_run(tmp_path / "a", two_rows())
    res = compare_runs(a, a)
    assert res.exit_code == 0 and res.compared == 2 and not res.regressions and not res.improvements
    md = res.markdown()
    assert md.startswith("## gibench gate: PASS") and "**Verdict: PASS** — 2 row(s) compared" in md


def test_injected_slowdown_fails(tmp_path):
    rows = two_rows()
    a, b = write_run(tmp_path / "a", rows), write_run(tmp_path / "b", slowed(rows, 1.5))
    res = compare_runs(a, b)
    assert res.exit_code == 1
    [f] = res.regressions
    assert f.row == "box/main/manylights" and f.check == "frame_ms (median)" and f.change == "x1.500"
    assert f.p_value < 0.05 and "gather" in f.note
    md = res.markdown()
    assert "### Regressions (1)" in md and "| box/main/manylights | frame_ms (median) |" in md
    assert "**Verdict: FAIL** — 1 regression(s) in 1 of 2 compared row(s)" in md
    # the mirror image is an improvement, not a failure
    back = compare_runs(b, a)
    assert back.exit_code == 0 and len(back.improvements) == 1


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


def test_error_floor_and_zero_baseline():
    assert error_check("mse", 0.0, 1e-12, 0.05) is None          # zero vs round-off
    assert error_check("mse", 0.0, 1e-3, 0.05) == "regression"   # zero vs a real error
    assert error_check("flip_mean", 0.1, 0.1 + 5e-7, 0.0) is None
    assert error_check("flip_mean", 0.1, 0.2, 0.05) == "regression"
    assert error_check("flip_mean", 0.2, 0.1, 0.05) == "improvement"


def test_noisy_but_equal_samples_do_not_flag(tmp_path):
    rng = np.random.default_rng(11)
    flagged = 0
    for trial in range(40):
        base = list(10 + rng.normal(0, 1.5, 8))
        cand = list(10 + rng.normal(0, 1.5, 8))
        flagged += timing_check(base, cand, 0.10, 0.05)["verdict"] == "regression"
    assert flagged <= 1  # same distribution: the two-part rule almost never fires
    # a ratio over the threshold that the test does not confirm: not flagged
    base = [10.0, 12.0, 9.0, 14.0, 8.0, 11.0]
    cand = [9.5, 13.5, 8.5, 15.5, 12.0, 12.6]
    t = timing_check(base, cand, 0.10, 0.05)
    assert t["ratio"] > 1.10 and t["p_slower"] >= 0.05 and t["verdict"] is None
    # a consistent shift below the threshold: confirmed by the test but too small
    steady = [10.0, 10.01, 9.99, 10.02, 9.98, 10.005]
    t = timing_check(steady, [v * 1.05 for v in steady], 0.10, 0.05)
    assert t["p_slower"] < 0.05 and t["verdict"] is None
    rows = [make_row(samples=base)]
    res = compare_runs(write_run(tmp_path / "a", rows), write_run(tmp_path / "b", [make_row(samples=cand)]))
    assert res.exit_code == 0 and not res.regressions


def test_too_few_frames_is_said(tmp_path):
    assert smallest_p(3, 3) == pytest.approx(0.05) and smallest_p(4, 4) < 0.05
    rows = [make_row(samples=(10.0, 10.2, 9.9))]
    res = compare_runs(write_run(tmp_path / "a", rows), write_run(tmp_path / "b", slowed(rows, 1.5)))
    assert res.exit_code == 0 and len(res.undecidable_timing) == 1
    md = res.markdown()
    assert "too few frames to test" in md and "--frames >= 4" in md and "x1.500" in md
    # said even when nothing is slower: the timing check is blind with 3 vs 3 frames
    res = compare_runs(tmp_path / "a", tmp_path / "a")
    assert res.exit_code == 0 and any("cannot be judged: with 3 vs 3 frames" in n for n in res.notes)
    assert "smallest Mann-Whitney p is 0.05" in res.markdown()


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
    res = compare_runs(a, b, compare_changed_versions=True)
    assert res.exit_code == 1 and res.regressions[0].note.startswith("method changed")


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
    res = compare_runs(write_run(tmp_path / "a", rows), write_run(tmp_path / "b", cand))
    assert res.exit_code == 1 and res.compared == 3 and not res.missing and not res.new
    assert sorted(f.baseline for f in res.regressions) == [pytest.approx(10.05), pytest.approx(20.05)]
    assert "box/main/manylights (seed 3)" in {f.row for f in res.regressions}


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
    # nothing in common: bad input, exit 2 with the reason in the summary
    other = write_run(tmp_path / "o", [make_row(scene="other")])
    res = compare_runs(a, other)
    assert res.exit_code == 2 and "no row of the candidate matches" in res.markdown()


def test_cli_gate_prints_markdown(tmp_path, capsys):
    from bench.cli import main
    rows = two_rows()
    a, b = write_run(tmp_path / "a", rows), write_run(tmp_path / "b", slowed(rows, 1.5))
    assert main(["gate", str(a), str(a)]) == 0
    assert "**Verdict: PASS**" in capsys.readouterr().out
    assert main(["gate", str(a), str(b), "--time-threshold", "0.6"]) == 0   # 50% slower, 60% allowed
    capsys.readouterr()
    assert main(["gate", str(a), str(b)]) == 1
    out = capsys.readouterr().out
    assert "## gibench gate: FAIL" in out and "**Verdict: FAIL**" in out


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
    from bench.evaluation import evaluate_row
    from bench.imageio import read_exr
    from bench.runner import RunConfig, run
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

    res = compare_runs(tmp_path / "base", tmp_path / "cand")
    assert res.exit_code == 1
    error_findings = {(f.row, f.check) for f in res.regressions if f.check != "frame_ms (median)"}
    assert ("open_box/main/manylights", "mse.indirect") in error_findings   # the bounce off the wall changed
    assert ("open_box/main/direct", "ciede2000.direct") in error_findings    # the wall itself changed colour
    assert "mse.indirect" in res.markdown()

    # an injected slowdown of a copy of the baseline fails on timing alone (10 frames: a few load spikes in
    # the real samples cannot hide a 1.5x shift from the Mann-Whitney test)
    shutil.copytree(tmp_path / "base", tmp_path / "slow")
    df = load_results(tmp_path / "slow")
    df["samples.frame_ms"] = [json.dumps([v * 1.5 for v in json.loads(s)]) for s in df["samples.frame_ms"]]
    df["frame_ms"] = df["frame_ms"] * 1.5
    save_results(tmp_path / "slow", df.to_dict("records"))
    assert main(["gate", str(tmp_path / "base"), str(tmp_path / "slow")]) == 1
    out = capsys.readouterr().out
    assert out.count("| frame_ms (median) |") == 2 and "x1.500" in out
