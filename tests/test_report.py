"""The HTML report: built from a tiny real run, with and without (synthesized) references, and
driven in headless Chromium (Playwright): images and plots render, the wipe slider and the
exposure change the canvas, no console errors; a screenshot goes to test-output/report.png."""
from __future__ import annotations

import json
from contextlib import contextmanager
import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bench.protocol import results as store
from bench.model.imageio import read_exr, write_exr
from reports import build_report
from reports.render import fmt
from reports.viewdata import error_scales

CHROMIUM = Path("/usr/bin/chromium")
SCREENSHOT = Path(__file__).resolve().parents[1] / "test-output" / "report.png"
REF_COMPONENTS = ("direct", "indirect_unshadowed", "indirect_visible")


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A real run: cornell_spot, direct + manylights, 48x36, no references."""
    from bench.run.serial import RunConfig, run
    out = tmp_path_factory.mktemp("run")
    run(RunConfig(scenes=["cornell_spot"], methods=["direct", "manylights"], width=48, height=36, frames=2,
                  warmup=1, references=False, progress=False, out=out), log=lambda m: None)
    return out


def _mse(a, b):
    return float(np.mean((a - b) ** 2))


@pytest.fixture(scope="module")
def run_with_refs(tiny_run, tmp_path_factory):
    """A copy of the tiny run with synthesized references, error columns and convergence curves
    (the references are the manylights images, rescaled, so every method has a non-zero error)."""
    out = tmp_path_factory.mktemp("run_refs")
    shutil.copytree(tiny_run, out, dirs_exist_ok=True)
    shutil.rmtree(out / "report", ignore_errors=True)
    df = store.load_results(out)
    ml = out / df.loc[df["method"] == "manylights", "image_dir"].iloc[0]
    direct, indirect = read_exr(ml / "direct.exr"), read_exr(ml / "indirect.exr")
    refs = {"direct": direct, "indirect_unshadowed": indirect * 1.2, "indirect_visible": indirect * 0.8}
    ref_dir = out / "references" / "cornell_spot" / "main"
    for comp, img in refs.items():
        write_exr(ref_dir / f"{comp}.exr", img)
        write_exr(ref_dir / f"{comp}_variance.exr", np.full_like(img, 1e-4))
    rows = []
    for rec in df.to_dict("records"):
        img_dir = out / rec["image_dir"]
        imgs = {c: read_exr(img_dir / f"{c}.exr") for c in ("direct", "indirect", "combined")}
        rec["mse.indirect"] = _mse(imgs["indirect"], refs["indirect_unshadowed"])
        rec["mse.indirect_visible"] = _mse(imgs["indirect"], refs["indirect_visible"])
        rec["mse.combined"] = _mse(imgs["combined"], refs["direct"] + refs["indirect_visible"])
        rec["relmse.indirect"] = rec["mse.indirect"] / (float(np.mean(refs["indirect_unshadowed"] ** 2)) + 1e-2)
        for comp in REF_COMPONENTS:
            rec[f"reference_noise_floor.{comp}"] = 1e-4 / 64
            rec[f"reference_spp.{comp}"] = 64
            rec[f"reference_key.{comp}"] = f"synthetic-{comp}"
        rows.append(rec)
    rows.append({"scene": "cornell_spot", "view": "main", "method": "flc", "params": "{}", "seed": 0,
                 "width": 48, "height": 36, "status": "failed: method 'flc' failed to load"})
    store.save_results(out, rows)
    base = max(r.get("mse.indirect", 0.0) for r in rows)
    curve = [{"spp": s, "seconds": 0.05 * s, "mse_estimate": base * 4.0 / s} for s in (1, 4, 16, 64)]
    (out / "reference_curves.json").write_text(json.dumps(
        {f"cornell_spot/main/{c}": curve for c in REF_COMPONENTS}))
    return out


def test_report_without_references(tiny_run, tmp_path):
    index = build_report(tiny_run, tmp_path / "rep")
    page = index.read_text()
    assert index.name == "index.html" and (tmp_path / "rep" / "assets" / "viewer.js").is_file()
    assert "manylights" in page and "cornell_spot" in page
    assert "llvmpipe" in page  # machine info from the manifest
    assert re.search(r"<(link|script)[^>]+(https?:)?//", page) is None  # offline: nothing from the network
    # no reference: errors are missing, never zero, and no speed-up is claimed
    assert "speed-ups unavailable" in page and "No Mitsuba references" in page
    data = (tmp_path / "rep" / "data" / "view_0.js").read_text()
    view = json.loads(data.split("] = ", 1)[1].rstrip(";\n"))
    assert view["width"] == 48 and view["height"] == 36
    assert all(c["reference"] is None for c in view["components"].values())
    assert list((tmp_path / "rep" / "plots").glob("stages_*.svg"))


def test_report_with_references(run_with_refs):
    index = build_report(run_with_refs)
    assert index == run_with_refs / "report" / "index.html"
    page = index.read_text()
    assert "Equal-error speed-up" in page and "Pareto front" in page
    assert "<option value='relmse.indirect' selected>" in page
    assert "Rows not rendered" in page and "failed: method &#x27;flc&#x27; failed to load" in page
    assert (run_with_refs / "report" / "plots" / "time_error_0.svg").is_file()
    # between-method matrices (direct vs manylights) and the paper table are on the page and as CSV
    assert "Between methods: equal time, equal error" in page and "Time at equal error" in page
    comp = pd.read_csv(run_with_refs / "report" / "data" / "comparisons.csv")
    assert set(comp["method_a"]) == {"direct", "manylights"} and comp["ratio"].notna().any()
    assert "Paper reproduction" in page
    view = json.loads((run_with_refs / "report" / "data" / "view_0.js").read_text().split("] = ", 1)[1].rstrip(";\n"))
    ind = view["components"]["indirect"]
    assert ind["reference"] == "ref_unshadowed" and ind["scale"]["abs"] > 0
    assert [s["kind"] for s in ind["sources"]].count("method") == 2
    # both methods share the direct pass: their direct image (= the synthetic direct reference) is stored once
    direct_blobs = {s["blob"] for s in view["components"]["direct"]["sources"]}
    assert len(direct_blobs) == 1 and len(view["components"]["direct"]["sources"]) == 3
    # float16 payload round-trips the linear image
    import base64
    src = next(s for s in ind["sources"] if s["id"] == "ref_unshadowed")
    got = np.frombuffer(base64.b64decode(view["blobs"][src["blob"]]), "<f2").astype(np.float32).reshape(36, 48, 3)
    want = read_exr(run_with_refs / "references" / "cornell_spot" / "main" / "indirect_unshadowed.exr")
    np.testing.assert_allclose(got, want, rtol=2e-3, atol=1e-6)


def test_error_scale_is_shared_and_fmt_marks_missing():
    ref = np.ones((4, 4, 3), np.float32)
    a, b = ref * 1.5, ref * 3.0
    scales, eps = error_scales(ref, [a, b])
    assert scales["abs"] == pytest.approx(2.0, rel=1e-5)  # the worse method sets the shared scale
    assert scales["rel"] == pytest.approx(2.0 / (1 + eps), rel=1e-5)
    zero_scales, _ = error_scales(ref, [a, np.zeros_like(ref)])  # an all-zero image does not set the scale
    assert zero_scales["abs"] == pytest.approx(0.5, rel=1e-5)
    assert fmt(float("nan")) == "\u2014" and fmt(None) == "\u2014" and fmt(0.0) == "0"


def test_report_rejects_a_missing_run(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope"):
        build_report(tmp_path / "nope")


def test_cli_report(tiny_run, tmp_path, capsys):
    from bench.cli import main
    assert main(["report", str(tiny_run), "--out", str(tmp_path / "r")]) == 0
    assert (tmp_path / "r" / "index.html").is_file()
    assert "report:" in capsys.readouterr().out


CANVAS_STATS = """(sel) => {
  const c = document.querySelector(sel);
  const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
  let sum = 0, lit = 0;
  for (let i = 0; i < d.length; i += 4) { const v = d[i] + d[i+1] + d[i+2]; sum += v; if (v > 30) lit++; }
  return {w: c.width, h: c.height, sum: sum, lit: lit, hash: Array.from(d.filter((_, i) => i % 97 == 0)).join(',')};
}"""


def _set_range(page, selector, value):
    page.eval_on_selector(selector, "(e, v) => { e.value = v; e.dispatchEvent(new Event('input', {bubbles: true})); }",
                          str(value))


@contextmanager
def report_page(index):
    """(page, console errors) of the report at `index`, opened in headless chromium once its
    script says it is ready; skips when chromium is not installed."""
    if not CHROMIUM.is_file():
        pytest.skip("chromium not installed (/usr/bin/chromium)")
    from playwright.sync_api import sync_playwright
    errors = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=[
            "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking",
            "--disable-component-update", "--disable-sync"])
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 1500})
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(index.as_uri())
            page.wait_for_function("window.GIBENCH && window.GIBENCH.ready === true", timeout=20000)
            yield page, errors
        finally:
            browser.close()


@pytest.mark.browser
def test_report_in_browser(run_with_refs):
    index = build_report(run_with_refs)
    with report_page(index) as (page, errors):
        assert page.evaluate("GIBENCH.viewers.length") == 1

        before = page.evaluate(CANVAS_STATS, "canvas.view-canvas")
        assert before["w"] >= 48 and before["lit"] > 0.05 * before["w"] * before["h"]  # not blank
        thumbs = page.eval_on_selector_all("figure.thumb canvas", "cs => cs.length")
        assert thumbs == 2

        # every plot image loaded
        sizes = page.eval_on_selector_all("img.plot", "imgs => imgs.map(i => i.complete ? i.naturalWidth : 0)")
        assert len(sizes) >= 2 and all(s > 0 for s in sizes)

        # the wipe slider changes the displayed image (A = reference, B = a method)
        page.select_option(".viewer select.sel-b", label="direct")
        _set_range(page, ".viewer input.wipe", 1000)
        only_a = page.evaluate(CANVAS_STATS, "canvas.view-canvas")
        _set_range(page, ".viewer input.wipe", 0)
        only_b = page.evaluate(CANVAS_STATS, "canvas.view-canvas")
        assert only_a["hash"] != only_b["hash"] and only_a["sum"] != only_b["sum"]

        # exposure: one stop up brightens
        ev = float(page.eval_on_selector(".viewer input.exposure", "e => e.value"))
        _set_range(page, ".viewer input.exposure", ev + 1)
        brighter = page.evaluate(CANVAS_STATS, "canvas.view-canvas")
        assert brighter["sum"] > only_b["sum"]

        # wheel zooms about the cursor, drag pans, double-click resets
        box = page.locator("canvas.view-canvas").bounding_box()
        cx, cy = box["x"] + box["width"] * 0.3, box["y"] + box["height"] * 0.4
        page.mouse.move(cx, cy)
        page.mouse.wheel(0, -400)
        page.wait_for_function("GIBENCH.viewers[0].zoom > 1")
        zoomed = page.evaluate(CANVAS_STATS, "canvas.view-canvas")
        assert zoomed["hash"] != brighter["hash"]
        page.mouse.down()
        page.mouse.move(cx + 60, cy + 40, steps=4)
        page.mouse.up()
        panned = page.evaluate(CANVAS_STATS, "canvas.view-canvas")
        assert panned["hash"] != zoomed["hash"]
        page.dblclick("canvas.view-canvas")
        assert page.evaluate(CANVAS_STATS, "canvas.view-canvas")["hash"] == brighter["hash"]

        # the error map view of the indirect component
        page.click(".viewer button[data-component='indirect']")
        page.select_option(".viewer select.sel-mode", "abs")
        _set_range(page, ".viewer input.wipe", 500)
        err = page.evaluate(CANVAS_STATS, "canvas.view-canvas")
        assert err["hash"] != brighter["hash"]
        assert page.eval_on_selector(".legend", "e => getComputedStyle(e).visibility") == "visible"

        # the metric select switches the overview table
        page.select_option("select.metric-select", "mse.combined")
        assert page.eval_on_selector("[data-metric='mse.combined']", "e => !e.hidden")
        assert page.eval_on_selector("[data-metric='relmse.indirect']", "e => e.hidden")

        # back to the combined image for the screenshot
        page.click(".viewer button[data-component='combined']")
        page.select_option(".viewer select.sel-mode", "image")
        page.select_option(".viewer select.sel-b", label="manylights")
        SCREENSHOT.parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(SCREENSHOT), full_page=True)
    assert not errors, errors
    assert SCREENSHOT.stat().st_size > 10000


def test_report_of_a_run_where_nothing_rendered(tmp_path):
    store.save_results(tmp_path, [{"scene": "cornell_spot", "view": "main", "method": "flc", "params": "{}", "seed": 0,
                                   "status": "failed: method 'flc' failed to load"}])
    page = build_report(tmp_path).read_text()
    assert "No rendered rows" in page and "Rows not rendered" in page


def test_scaling_fit_recovers_the_slope(tmp_path):
    import pandas as pd
    from reports import plots
    # t = 2 n^0.5 (ms) over three series scenes, plus a scene outside the series
    n = {"highpoly_10k": 1e4, "highpoly_1m": 1e6, "highpoly_10m": 1e7, "cornell_spot": 1e3}
    rows = [{"scene": s, "view": "main", "method": "m", "frame_ms": 2 * v ** 0.5, "image_dir": f"images/{s}/main/m"}
            for s, v in n.items()]
    fits = plots.scaling_fits(pd.DataFrame(rows), n)
    counts, times, slope = fits["m"]
    assert slope == pytest.approx(0.5) and list(counts) == [1e4, 1e6, 1e7]
    assert plots.scaling_plot(fits, tmp_path / "s.svg").is_file()


def test_fmt_keeps_the_report_number_format():
    assert fmt(28800.4) == "28,800" and fmt(12345678.9) == "12,345,679" and fmt(1e9) == "1e+09"
    assert fmt(0.000123456) == "0.000123" and fmt(999.5) == "1e+03" and fmt(1.5, 2) == "1.5"
    assert fmt(1234) == "1,234" and fmt(np.int64(7)) == "7" and fmt(True) == "yes" and fmt(np.bool_(False)) == "no"
    assert fmt(float("inf")) == "\u2014" and fmt("n/a") == "n/a"


def test_hand_edited_table_is_one_line_or_a_report(tiny_run, tmp_path, capsys):
    """Issue #27: a non-numeric frame_ms, parquet and checksums removed, ended in two tracebacks."""
    from bench.cli import main
    for name, edit, code in (("text", lambda df: df.assign(frame_ms=["fast"] + list(df["frame_ms"][1:])), 2),
                             ("params", lambda df: df.assign(params=["{bad"] + list(df["params"][1:])), 2),
                             ("no_version", lambda df: df.drop(columns=["method_version"]), 0)):
        run_dir = tmp_path / name
        shutil.copytree(tiny_run, run_dir)
        shutil.rmtree(run_dir / "report", ignore_errors=True)
        (run_dir / "results.parquet").unlink()
        (run_dir / "results.checksums.json").unlink()
        edit(pd.read_csv(run_dir / "results.csv")).to_csv(run_dir / "results.csv", index=False)
        assert main(["report", str(run_dir), "--out", str(tmp_path / f"rep_{name}")]) == code, name
        err = capsys.readouterr().err.strip()
        if code:
            assert "\n" not in err and "Traceback" not in err and "results.csv: column" in err, err


# ---------------------------------------------------------------------------- the error over frames (issue 24)
SPLIT_COMPONENTS = ("indirect", "indirect_visible", "combined")


@pytest.fixture(scope="module")
def run_with_frames(run_with_refs, tmp_path_factory):
    """The run with references, plus the error over frames of K = 8 frames as the runner writes it:
    `direct` deterministic (variance and flicker 0, all its error bias), `manylights` a noisy method
    (a third of its error variance, flicker below it, as a method reusing earlier frames)."""
    out = tmp_path_factory.mktemp("run_frames")
    shutil.copytree(run_with_refs, out, dirs_exist_ok=True)
    shutil.rmtree(out / "report", ignore_errors=True)
    rows = store.load_results(out).to_dict("records")
    for rec in rows:
        if rec["method"] not in ("direct", "manylights"):
            continue   # the failed row has none
        rec["extra.error_frames"] = 8
        share = 0.0 if rec["method"] == "direct" else 1 / 3
        for comp in SPLIT_COMPONENTS:
            rel = comp == "indirect" and rec.get("relmse.indirect") or 0.4
            for prefix, total in (("", rec[f"mse.{comp}"]), ("rel_", rel)):
                values = {"variance": share * total, "bias2": (1 - share) * total, "flicker": 0.5 * share * total,
                          "mse_accumulated": (1 - share) * total + share * total / 8}
                for metric, value in values.items():
                    rec[f"{prefix}{metric}.{comp}"] = value
                    rec[f"{prefix}{metric}_ci.{comp}"] = 0.05 * value
    store.save_results(out, rows)
    return out


def _svg_ids(path: Path) -> set:
    return set(re.findall(r'id="([^"]+)"', path.read_text()))


def test_report_shows_the_error_over_frames(run_with_frames, run_with_refs):
    index = build_report(run_with_frames)
    page = index.read_text()
    assert "<h2 id='decomposition'>Bias, variance and flicker</h2>" in page and "href='#decomposition'" in page
    assert "accumulation cannot remove" in page and "emission=flc" in page   # the note, and FLC's
    # per view: the bias/variance bars and their numbers, the default rung of each method
    ids = _svg_ids(run_with_frames / "report" / "plots" / "bias_variance_0.svg")
    assert {"bias2-direct", "bias2-manylights", "variance-direct", "variance-manylights"} <= ids
    table = page.split("class='data decomposition'", 1)[1].split("</table>", 1)[0]
    assert table.count("<tr data-method=") == 2 and ">100%<" in table and ">67%<" in table   # direct: all bias
    assert "&plusmn;" in table
    # both curves of every method on the time-vs-error plot
    ids = _svg_ids(run_with_frames / "report" / "plots" / "time_error_0.svg")
    for comp in ("indirect", "combined"):
        assert {f"single-{comp}-manylights", f"accumulated-{comp}-manylights", f"accumulated-{comp}-direct"} <= ids
    # the flicker column of the overview tables, and the new metrics in its select
    assert page.count("<th class='flicker'") >= len(re.findall(r"<div data-metric=", page))
    assert "<option value='rel_bias2.indirect'>" in page and "<option value='rel_variance.combined'>" in page
    assert "<option value='variance.combined'>" not in page and "<dt>variance</dt>" in page
    # a run without the columns (an old run): nothing new, no error
    old = build_report(run_with_refs, run_with_refs / "old_report").read_text()
    assert "id='decomposition'" not in old and "class='flicker'" not in old and "decomposition" not in old
    assert not list((run_with_refs / "old_report" / "plots").glob("bias_variance_*"))
    assert not {i for i in _svg_ids(run_with_refs / "old_report" / "plots" / "time_error_0.svg")
                if i.startswith("accumulated-")}


def test_bias_variance_split_without_some_columns():
    from reports import tables
    rows = pd.DataFrame([{"scene": "s", "view": "v", "method": "a", "label": "a", "image_dir": "images/s/v/a",
                          "frame_ms": 1.0, "rel_bias2.indirect": -1e-4, "rel_variance.indirect": 0.2},
                         {"scene": "s", "view": "v", "method": "b", "label": "b", "image_dir": "images/s/v/b",
                          "frame_ms": 2.0, "rel_bias2.indirect": np.nan, "rel_variance.indirect": np.nan}])
    [a] = tables.bias_variance(rows)   # b has no split (an old row beside a new one): left out
    assert a["bias_share"] == 0.0 and a["rel_bias2_ci"] is None and a["error_frames"] is None
    assert tables.bias_variance(rows.drop(columns=["rel_variance.indirect"])) == []


@pytest.mark.browser
def test_error_over_frames_in_browser(run_with_frames):
    """The bias/variance split and both curves of each method, as a browser shows them."""
    index = build_report(run_with_frames)
    plots_dir = run_with_frames / "report" / "plots"
    with report_page(index) as (page, errors):
        # the split: its figure loaded and visible, its table with one row per method
        bars = page.locator("img.plot.bias-variance")
        assert bars.count() == 1 and bars.is_visible()
        assert bars.evaluate("i => i.complete && i.naturalWidth > 0")
        methods = page.eval_on_selector_all("table.decomposition tr[data-method]", "rs => rs.map(r => r.dataset.method)")
        assert sorted(methods) == ["direct", "manylights"]
        assert page.locator("#decomposition").is_visible()
        # the flicker column of the shown overview table
        assert page.locator("#overview-tables div:not([hidden]) th.flicker").first.is_visible()
        # both curves drawn, per method and panel, and the split's bars, in the figures the page shows
        drawn = "es => es.filter(e => e.getBBox().width > 0).map(e => e.id).sort()"
        page.goto((plots_dir / "time_error_0.svg").as_uri())
        for comp in ("indirect", "combined"):
            for curve in ("single", "accumulated"):
                assert page.eval_on_selector_all(f"[id^='{curve}-{comp}-']", drawn) == [
                    f"{curve}-{comp}-direct", f"{curve}-{comp}-manylights"]
        page.goto((plots_dir / "bias_variance_0.svg").as_uri())
        assert page.eval_on_selector_all("[id^='bias2-']", drawn) == ["bias2-direct", "bias2-manylights"]
        # direct is deterministic: its variance bar is empty
        assert page.eval_on_selector_all("[id^='variance-']", drawn) == ["variance-manylights"]
        assert page.eval_on_selector_all("[id^='variance-']", "es => es.length") == 2
    assert not errors, errors


def test_run_summary_shows_the_split(tmp_path):
    from bench.analysis.summary import summary_table, write_summary
    rows = [{"scene": "s", "view": "v", "method": "flc", "params": "{}", "seed": 0, "status": "ok", "frame_ms": 3.0,
             "width": 8, "height": 6, "image_dir": "images/s/v/flc", "relmse.indirect": 0.3, "rel_bias2.indirect": 0.2, "rel_variance.indirect": 0.1,
             "rel_flicker.indirect": 0.1, "rel_bias2_ci.indirect": 0.01}]
    table = summary_table(pd.DataFrame(rows))
    assert list(table.columns)[-4:] == ["relmse.indirect", "rel_bias2.indirect", "rel_variance.indirect",
                                        "rel_flicker.indirect"]
    store.save_results(tmp_path, rows)
    md, _ = write_summary(tmp_path)
    assert "| rel_bias2.indirect |" in md.read_text()
    assert "rel_bias2" not in summary_table(pd.DataFrame(rows).drop(columns=["rel_bias2.indirect"])).columns


def test_between_method_tables_on_an_error_over_frames(run_with_frames, tmp_path):
    from bench.analysis.curves import declared_defaults, load_curves, sweep_table
    from bench.protocol.results import load_manifest
    from reports import comparisons
    table = sweep_table(store.load_results(run_with_frames), load_curves(run_with_frames),
                        declared_defaults(load_manifest(run_with_frames)), keep=("image_dir",))
    (tmp_path / "data").mkdir()
    out = comparisons.between_methods(table, tmp_path, errors=("rel_bias2.indirect",), matrix_error="bias2.combined")
    assert out["error"] == "bias2.combined" and [sorted(v["methods"]) for v in out["views"]] == [["direct", "manylights"]]
    csv = pd.read_csv(tmp_path / "data" / "comparisons.csv")
    assert set(csv["error"]) == {"rel_bias2.indirect", "bias2.combined"}
    # variance: direct's is 0, off the log-log curves: no ratio against it, none of it (shown as —)
    var = pd.read_csv(tmp_path / "data" / "comparisons.csv") if comparisons.between_methods(
        table, tmp_path, errors=(), matrix_error="variance.indirect") else None
    assert set(var["method_b"]) == {"manylights"} and var["ratio"].isna().all()
