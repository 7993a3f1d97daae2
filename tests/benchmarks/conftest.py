"""pytest-benchmark suite: CPU-side hot paths and the GL frame.

Cheap by default: in a plain `pytest` run (CI) every benchmarked call runs once, untimed, as
if `--benchmark-disable` were given, so the suite is a smoke test costing a few seconds.
Timing is on when asked for with any of --benchmark-enable, --benchmark-only, --benchmark-save,
--benchmark-autosave, --benchmark-json, --benchmark-compare(-fail), or GIBENCH_BENCHMARK=1:

    # measure and keep a baseline (.benchmarks/ in the working directory)
    pytest tests/benchmarks --benchmark-enable --benchmark-autosave
    # later: compare with it and fail on a 10% slower median
    pytest tests/benchmarks --benchmark-enable --benchmark-compare --benchmark-compare-fail=median:10%

GL frames are timed with `ctx.finish()` inside the timed call; the per-stage GPU times of the
timed rounds (medians, ms) are in each benchmark's `extra_info` as `stage_ms.<stage>`.
"""
from __future__ import annotations

import os

import pytest

_TIMING_OPTIONS = ("benchmark_enable", "benchmark_only", "benchmark_save", "benchmark_autosave", "benchmark_json",
                   "benchmark_compare", "benchmark_compare_fail")


def timing_requested(config) -> bool:
    if os.environ.get("GIBENCH_BENCHMARK", "").strip() not in ("", "0"):
        return True
    for name in _TIMING_OPTIONS:
        try:
            if config.getoption(name):
                return True
        except ValueError:  # pytest-benchmark missing: the benchmark fixture fails on its own
            return False
    return False


@pytest.fixture(scope="session", autouse=True)
def _cheap_benchmarks_by_default(request):
    session = getattr(request.config, "_benchmarksession", None)
    if session is not None and not timing_requested(request.config):
        session.disabled = True
    yield
