"""CPU-side hot paths of a run: metrics of one image, error columns of one row, scene facts."""
from __future__ import annotations

import math

import numpy as np
import pytest

from bench.analysis import metrics as M

W, H = 128, 96


def image_pair(seed=0):
    """A reference with a black background band and a noisy, biased method image."""
    rng = np.random.default_rng(seed)
    ref = (rng.random((H, W, 3)) ** 2 * 2).astype(np.float32)
    ref[:, : W // 8] = 0.0
    img = np.clip(ref * 1.1 + rng.normal(0, 0.05, ref.shape), 0, None).astype(np.float32)
    img[:, : W // 8] = 0.0
    return img, ref


@pytest.mark.benchmark(group="metrics")
def test_compute_all_128x96(benchmark):
    img, ref = image_pair()
    mask = ref.max(axis=2) > 0
    exposure = M.flip_exposure_range(ref, mask)
    values = benchmark(M.compute_all, img, ref, mask, flip_exposure=exposure)
    assert list(values) == list(M.METRICS) and all(v > 0 and math.isfinite(v) for v in values.values())
    benchmark.extra_info["pixels"] = int(mask.sum())


@pytest.mark.benchmark(group="metrics")
def test_evaluate_row_128x96(benchmark):
    from bench.analysis.evaluation import evaluate_row
    img, ref = image_pair(1)
    ind_img, ind_ref = image_pair(2)
    images = {"direct": img, "indirect": 0.3 * ind_img}
    images["combined"] = images["direct"] + images["indirect"]
    refs = {"direct": ref, "indirect_unshadowed": 0.3 * ind_ref, "indirect_visible": 0.25 * ind_ref}
    out = benchmark(evaluate_row, images, refs)
    assert len(out) == 4 * (len(M.METRICS) + 1) and all(math.isfinite(v) for v in out.values())


@pytest.mark.benchmark(group="scene")
def test_compute_facts_cornell_tiled(benchmark):
    from bench.model.corpus import load_scene
    from bench.model.scene import compute_facts
    scene = load_scene("cornell_tiled")
    facts = benchmark(compute_facts, scene)
    assert facts.triangle_count == scene.triangle_count
    benchmark.extra_info["triangles"] = scene.triangle_count
