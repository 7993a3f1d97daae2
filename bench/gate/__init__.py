"""The regression gate: `gibench gate BASELINE CANDIDATE` compares two sides row by row.

Each side is one run folder or several (comma-separated on the command line): repetitions of
the same command. Rows are matched on (scene name, view, method, params, seed, resolution):
bench.protocol.vocabulary.row_identity; a row found only at another resolution is listed as
not comparable. For each matched row:

* Status: a baseline row that is not ok/cached is skipped (nothing to compare against); a
  candidate row that no longer renders (failed or skipped) where the baseline rendered is a
  regression.
* Comparability: a different `method_version` (hash of the method's sources, shaders and the
  shared GL core), a different resolution, or different scene *content* (`scene_hash`: an
  edited scene file keeps its name) makes the row *not comparable*: it is listed with the
  reason, it is not a failure (asv's rule: results of edited code are never compared as if
  equal). Pass `compare_changed_versions=True` to compare rows whose method changed anyway
  (each finding is then marked "method changed"): that is the mode to gate a change *to* a
  method. Different frames, warm-up or stage clock make the row's *timing* not comparable.
* Timing, on repetitions: the unit of evidence is a run, not a frame. The K frames of one
  process share that run's load (a run slowed by background load separates completely from
  another at p ~ 0.004 on 5 vs 5 frames), so each run contributes one number per row: the
  median of its frame times, or, with `relative_to=METHOD`, that median divided by the
  median of METHOD's row on the same scene/view in the same run (load slows every method of
  a run alike). Only rows *rendered* in a run count (a cached row repeats old numbers). With
  at least `min_runs` (3) runs per side, a one-sided Welch t-test on the logarithms of those
  numbers gives a p-value per row; the p-values of all rows are adjusted for multiple testing
  (`correction`: "holm", family-wise error <= alpha, the default; or "bh", Benjamini-Hochberg
  false-discovery rate, `scipy.stats.false_discovery_control`). A regression needs the ratio of
  geometric means above 1 + time_threshold AND an adjusted p below alpha. Fewer runs: the row's
  timing is listed as not tested, never as a pass or fail. Interleave the runs of the two
  sides (A B A B A B) so that slow periods of the machine fall on both.
* Error: every `<metric>.<component>` column (metrics: bench.protocol.vocabulary.error_metric_names():
  the single-frame ERROR_METRICS and the error over frames, DECOMPOSITION_METRICS: bias2,
  variance, flicker, mse_accumulated and their relative forms) present in both runs, or only
  the columns `metrics` names (`--metric`: an unknown column is bad input, one a side lacks or
  no row has on both sides is an error of the gate, exit 2), judged only when both rows were
  scored against the same references (same `reference_key` and `reference_spp` of every
  reference the component uses, bench.protocol.vocabulary.REFERENCE_PARTS; otherwise the
  component is not comparable: refinement depends on which methods ran; `variance` and
  `flicker`, the spread of the method's own frames, do not depend on the reference). MSE is
  compared after subtracting the references' noise floor (E[(x - r)^2] = (x - mu)^2 + Var r),
  clamped at 0; the error over frames has the noise floor removed already, is clamped at 0 (an
  unbiased method's bias2 estimate scatters about 0) and is compared only between rows of the
  same error-frame count (`extra.error_frames`). A regression when candidate > baseline *
  (1 + error_threshold) and candidate - baseline exceeds the metric's absolute floor
  (ERROR_ABS_FLOOR, so 0 vs 1e-12 is not a regression) and, for an error over frames, the 95%
  interval of the difference (the two values' `<metric>_ci` intervals over pixels, in quadrature).
* Rows of the baseline missing from the candidate, and new rows, are listed, not failures (a
  candidate may run a subset).
* Runs: a side's runs must be distinct runs by content (the run id in each manifest, or for an
  older folder its creation time, or for a folder by hand the folder itself; and the rows): one
  run listed twice, by path, link or copy, would count as two repetitions, so it is bad input. A
  run that did not finish (`run_state.json`, read by bench.protocol.results.run_progress:
  interrupted, or still running) is bad input unless `allow_incomplete`, which names it in the
  notes and the verdict. A compared row whose method version or scene hash a side lacks (a
  hand-edited table) is compared as if unchanged, and the notes and the verdict say so.

Exit code: 0 pass, 1 at least one regression, 2 bad input or nothing compared (missing run
folder, a run listed twice, an unfinished run, no common row, every common row not comparable).

Modules, statistics then presentation: `load` (run folders, sides, row indexes, cells),
`statistics` (per-run times, the timing test and its correction, the error check), `compare`
(matching rows, comparability, findings: `compare_runs`, `GateResult`, `Finding`),
`presentation` (the Markdown report).
"""
from bench.gate.compare import Finding, GateResult, compare_runs

__all__ = ["Finding", "GateResult", "compare_runs"]
