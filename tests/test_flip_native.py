"""HDR-FLIP compiled from FLIP.h (bench/analysis/flip_native) gives the pip wheel's map bit for bit.

Three ways to the map are held to `flip_evaluator.evaluate` (the wheel): FLIP.h's own
FLIP::evaluate compiled here, and the two halves (the reference's features, then the test image
against them) on the whole image and on crops. Pairs: odd sizes, images of one or a few pixels,
zero images, a large dynamic range, 2 to 12 exposures. Then the build: the fallback to the wheel
(forced, no compiler, a failing compiler) and two processes building at once.
"""
from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bench.analysis import flip_native
from bench.analysis import metrics as M

ROOT = Path(__file__).resolve().parent.parent
needs_native = pytest.mark.skipif(flip_native.library() is None, reason="no compiled FLIP (no C++ compiler)")


def wheel_map(ref, img, start, stop, exposures):
    import flip_evaluator
    params = {"ppd": M.FLIP_PPD, "startExposure": start, "stopExposure": stop, "numExposures": exposures,
              "tonemapper": "aces"}
    err, _, _ = flip_evaluator.evaluate(np.ascontiguousarray(ref, np.float32), np.ascontiguousarray(img, np.float32),
                                        "HDR", applyMagma=False, computeMeanError=False, parameters=params)
    return np.asarray(err, np.float32).reshape(ref.shape[:2])


def _pairs():
    rng = np.random.default_rng(3)

    def noisy(h, w, scale=1.0):
        ref = (rng.random((h, w, 3)) ** 3 * scale).astype(np.float32)
        img = np.clip(ref * rng.normal(1.0, 0.2, ref.shape) + rng.normal(0, 0.01 * scale, ref.shape), 0, None)
        return ref, img.astype(np.float32)
    yield "odd size 37x53", *noisy(37, 53), 2
    yield "one pixel", *noisy(1, 1), 3
    yield "one row", *noisy(1, 29), 4
    yield "one column", *noisy(23, 1), 5
    yield "3x4", *noisy(3, 4), 2
    yield "smaller than the filters 9x13", *noisy(9, 13), 6
    z = np.zeros((21, 30, 3), np.float32)
    yield "both zero", z, z.copy(), 2
    ref, img = noisy(21, 30)
    yield "zero reference", z, img, 3
    yield "zero image", ref, z, 4
    big = (10.0 ** rng.uniform(-4, 4, (31, 45, 1)) * rng.random((31, 45, 3))).astype(np.float32)
    yield "large dynamic range", big, np.clip(big * rng.normal(1, 0.3, big.shape), 0, None).astype(np.float32), 12
    for n in (7, 8, 9, 10, 11):
        yield f"{n} exposures", *noisy(40, 64, scale=5.0), n


PAIRS = list(_pairs())


def _range(ref, exposures):
    """An exposure range of `exposures` FLIP steps around the reference's own start."""
    start, _ = M.flip_exposure_range(ref)
    return start, start + exposures - 0.5


@needs_native
@pytest.mark.parametrize("name,ref,img,exposures", PAIRS, ids=[p[0] for p in PAIRS])
def test_compiled_flip_equals_the_wheel(name, ref, img, exposures):
    start, stop = _range(ref, exposures)
    assert M._flip_exposures(start, stop) == exposures
    wheel = wheel_map(ref, img, start, stop, exposures)
    whole = flip_native.flip_evaluate(ref, img, M.FLIP_PPD, start, stop, exposures)
    halves = flip_native.flip_map(ref, img, M.FLIP_PPD, start, stop, exposures)
    assert np.array_equal(whole, wheel, equal_nan=True), f"FLIP::evaluate: {np.sum(whole != wheel)} pixels differ"
    assert np.array_equal(halves, wheel, equal_nan=True), f"halves: {np.sum(halves != wheel)} pixels differ"


@needs_native
@pytest.mark.parametrize("name,ref,img,exposures", PAIRS[:1] + PAIRS[-2:], ids=[p[0] for p in PAIRS[:1] + PAIRS[-2:]])
def test_test_half_on_a_crop_is_the_whole_map_inside_it(name, ref, img, exposures):
    """On a crop, the pixels whose filter windows stay in it (or reach the image edge with it)."""
    start, stop = _range(ref, exposures)
    wheel = wheel_map(ref, img, start, stop, exposures)
    features = flip_native.reference_features(ref, M.FLIP_PPD, start, stop, exposures)
    h, w, r = ref.shape[0], ref.shape[1], M.FLIP_REACH
    for y0, y1, x0, x1 in ((0, h, 0, w), (0, h // 2 + r + 1, 3, w), (5, h, 0, min(w, 2 * r + 3))):
        crop = flip_native.map_against_reference(features, img[y0:y1, x0:x1], y0, x0, M.FLIP_PPD, start, stop)
        iy0, iy1 = (y0 if y0 == 0 else y0 + r), (y1 if y1 == h else y1 - r)
        ix0, ix1 = (x0 if x0 == 0 else x0 + r), (x1 if x1 == w else x1 - r)
        assert iy0 < iy1 and ix0 < ix1
        assert np.array_equal(crop[iy0 - y0:iy1 - y0, ix0 - x0:ix1 - x0], wheel[iy0:iy1, ix0:ix1])


@needs_native
def test_crop_outside_the_reference_is_refused():
    ref, img = PAIRS[0][1], PAIRS[0][2]
    features = flip_native.reference_features(ref, M.FLIP_PPD, -3.0, -1.5, 2)
    with pytest.raises(ValueError, match="outside"):
        flip_native.map_against_reference(features, img, 1, 0, M.FLIP_PPD, -3.0, -1.5)


# ---------------------------------------------------------------------------- the build and its fallback
@pytest.fixture
def fresh(monkeypatch, tmp_path):
    """flip_native deciding again, with its cache in tmp_path."""
    monkeypatch.setattr(flip_native, "_state", {})
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv(flip_native.FORCE_WHEEL_ENV, raising=False)
    return tmp_path


def test_forcing_the_wheel_gives_the_same_metrics(fresh, monkeypatch, capsys):
    rng = np.random.default_rng(5)
    ref = (rng.random((24, 31, 3)) * 2).astype(np.float32)
    img = np.clip(ref + rng.normal(0, 0.2, ref.shape), 0, None).astype(np.float32)
    monkeypatch.setenv(flip_native.FORCE_WHEEL_ENV, "1")
    assert flip_native.library() is None
    wheel = M.compute_all(img, ref)
    assert capsys.readouterr().err == ""      # asked for: no warning
    monkeypatch.setattr(flip_native, "_state", {})
    monkeypatch.delenv(flip_native.FORCE_WHEEL_ENV)
    native = M.compute_all(img, ref)
    assert wheel == native


@needs_native
def test_rows_judged_on_the_wheel_equal_rows_judged_on_threads(monkeypatch):
    """evaluate_row with the compiled FLIP (FLIP and CIEDE2000 on threads of their own) and with the
    wheel (everything on the caller's thread): the same columns, bit for bit."""
    from bench.analysis import evaluation
    from tests.test_metrics_speed import same, synthetic_row
    images, refs = synthetic_row(30, 44, seed=9)
    evaluation._PREPARED.clear()
    threaded = evaluation.evaluate_row(images, refs)
    monkeypatch.setattr(flip_native, "_state", {})
    monkeypatch.setenv(flip_native.FORCE_WHEEL_ENV, "1")
    evaluation._PREPARED.clear()
    assert same(evaluation.evaluate_row(images, refs), threaded)


def test_no_compiler_falls_back_to_the_wheel_with_one_line(fresh, monkeypatch, capsys):
    monkeypatch.setattr(flip_native, "_compiler", lambda: None)
    assert flip_native.library() is None
    assert flip_native.library() is None   # decided once
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no C++ compiler" in err and "slower" in err
    ref = np.full((12, 12, 3), 0.5, np.float32)
    assert M.compute_all(ref * 1.1, ref)["flip_mean"] > 0   # the wheel judges


def test_a_failing_build_falls_back_to_the_wheel_and_leaves_nothing(fresh, monkeypatch, capsys):
    monkeypatch.setattr(flip_native, "_compiler", lambda: ("/bin/false", "a compiler that always fails"))
    assert flip_native.library() is None
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "building FLIP.h failed" in err
    assert not any(p.is_file() for p in fresh.rglob("*"))   # no library, no temporary file


def test_the_library_is_keyed_by_sources_flags_and_compiler(fresh):
    a, b = flip_native.library_path("g++ 12.2"), flip_native.library_path("g++ 13.1")
    assert a != b and a.parent == b.parent == fresh / "flip_native"


@needs_native
def test_two_processes_building_at_once_both_load_a_whole_library(tmp_path):
    code = ("import numpy as np; from bench.analysis import flip_native as F; assert F.library() is not None; "
            "r = np.ones((8, 9, 3), np.float32); print(float(F.flip_map(r, r * 2, 67.0, -2.0, 1.0, 3).sum()))")
    env = dict(os.environ, GIBENCH_CACHE_DIR=str(tmp_path), PYTHONPATH=str(ROOT))
    env.pop(flip_native.FORCE_WHEEL_ENV, None)
    procs = [subprocess.Popen([sys.executable, "-c", code], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for _ in range(2)]
    outs = [p.communicate(timeout=600) for p in procs]
    assert all(p.returncode == 0 for p in procs), [o[1] for o in outs]
    assert outs[0][0] == outs[1][0] and math.isfinite(float(outs[0][0]))
    files = sorted(p.name for p in (tmp_path / "flip_native").iterdir())
    assert len(files) == 1 and files[0].endswith(".so"), files   # one library, no temporary file left
