"""Tests of `pbgi` on scenes with many small charts (real scenes have thousands: sponza 7,000,
conference 18,000): the emitter hierarchy is one tree over every texel of the scene, so the
work of a receiver tile grows far slower than the number of charts, and the result still
matches the all-pairs sum; small charts cost a texel each in the lightmap."""
from __future__ import annotations

import numpy as np
import pytest

from bench.model.scene import Camera, PointLight
from methods.pbgi.hierarchy import build_tree
from methods.pbgi.method import TILE_TEXELS
from tests.conftest import grid_quad, scene_from_parts
from tests.methods.test_pbgi import _Live


def make_tiled_box(n: int):
    """The open box of make_grid_box whose floor is n x n separate square tiles (gaps of a
    fifth of the pitch between them): n^2 charts of a texel or two at the default density,
    like the thousands of small pieces of a real scene (sponza 7,000, conference 18,000)."""
    pitch = 2.0 / n
    side = 0.8 * pitch
    i, j = (a.ravel() for a in np.meshgrid(np.arange(n), np.arange(n)))
    x0, z0 = -1.0 + pitch * i + 0.1 * pitch, -1.0 + pitch * j + 0.1 * pitch
    corners = np.stack([np.column_stack([x0, np.zeros_like(x0), z0]),
                        np.column_stack([x0, np.zeros_like(x0), z0 + side]),
                        np.column_stack([x0 + side, np.zeros_like(x0), z0 + side]),
                        np.column_stack([x0 + side, np.zeros_like(x0), z0])], axis=1)
    quad = np.array([[0, 1, 2], [0, 2, 3]])   # normal +y
    floor = (corners.reshape(-1, 3), (4 * np.arange(n * n)[:, None, None] + quad).reshape(-1, 3))
    parts = [floor, grid_quad([-1, 0, -1], [2, 0, 0], [0, 2, 0], 4), grid_quad([-1, 0, -1], [0, 2, 0], [0, 0, 2], 4)]
    colours = [[0.8, 0.8, 0.8], [0.2, 0.8, 0.2], [0.8, 0.2, 0.2]]
    return scene_from_parts(f"tiled_box_{n}", parts, colours, [PointLight([0.2, 1.2, 0.1], [2.0] * 3)],
                            {"main": Camera([0, 1, 3.5], [0, 0.5, 0], fov_y_deg=50)})


def _run(gl_ctx, scene, params):
    live = _Live(gl_ctx, scene, params, 32, 24)
    try:
        m = live.method
        visits = m.read_visits() if m.hierarchical else None
        return {"lightmap": live.displayed(), "visits": visits, "charts": m.unwrap.chart_count,
                "texels": m.texel_count, "window": m.window, "tiles": m.tile_count, "chart_of_texel": m.texel_chart,
                "xy": m.texel_xy}
    finally:
        live.close()


def test_many_small_charts_bounded_work_and_all_pairs_sum(gl_ctx):
    """On a box whose floor is 400 and then 1,600 separate tiles (charts) of a texel or two: a
    receiver tile holds texels of several charts, visits far fewer nodes than there are charts
    (a tree per chart visits at least one node per chart, and a receiver tile per chart), and
    that work stays about the same when the charts are four times as many; the converged
    lightmap is the all-pairs sum within 3% per texel in total and 1% in the mean. The density
    is 35 texels per scene radius (20 per metre on this box): at the default 144 the tiles are
    ~20 texels each (a real scene's thousands of charts are a texel or two at the cap)."""
    sparse = {"texel_density": 35.0}
    runs = {n: _run(gl_ctx, make_tiled_box(n), sparse) for n in (20, 40)}
    few, many = runs[20], runs[40]
    assert few["charts"] > 400 and many["charts"] > 1600
    assert many["texels"] > 8 * many["tiles"] and many["tiles"] < 0.6 * many["charts"]
    per_tile = {n: r["visits"].mean() for n, r in runs.items()}   # nodes per tile over the whole window
    assert per_tile[40] < 0.25 * many["charts"]
    assert per_tile[40] < 1.5 * per_tile[20]
    full = _run(gl_ctx, make_tiled_box(40), dict(sparse, gather="all_pairs", emitter_budget=0))
    assert np.array_equal(full["xy"], many["xy"])
    ref, got = full["lightmap"], many["lightmap"]
    assert ref.max() > 0
    assert np.abs(got - ref).sum() / ref.sum() < 0.03
    assert abs(got.sum() / ref.sum() - 1.0) < 0.01


def test_tree_over_charts_and_receiver_tiles():
    """The tree is over all texels whatever their chart: pre-order ranges with skip links,
    leaves exactly the texels, and receiver tiles of at most TILE_TEXELS leaves that partition
    the texels and stay compact in space."""
    rng = np.random.default_rng(3)
    # 400 small patches (charts) of 1..6 texels with random orientations in a 10 m cube
    centres = rng.uniform(0, 10, (400, 3))
    counts = rng.integers(1, 7, 400)
    position = np.repeat(centres, counts, axis=0) + rng.normal(0, 0.05, (counts.sum(), 3))
    normal = rng.normal(size=(400, 3))
    normal = np.repeat(normal / np.linalg.norm(normal, axis=1)[:, None], counts, axis=0)
    tree = build_tree(position, normal)
    n = tree.node_count
    assert np.array_equal(np.sort(tree.leaf_order), np.arange(len(position)))
    assert np.array_equal(tree.skip == np.arange(n) + 1, tree.hi - tree.lo == 1)   # leaf <=> one texel
    assert tree.level[tree.skip == np.arange(n) + 1].max() == 0
    for i in np.flatnonzero(tree.hi - tree.lo > 1):
        kids = tree.children(int(i))
        assert len(kids) >= 2 and tree.lo[kids[0]] == tree.lo[i] and tree.hi[kids[-1]] == tree.hi[i]
        assert all(tree.hi[a] == tree.lo[b] for a, b in zip(kids[:-1], kids[1:]))
        assert all(tree.level[k] < tree.level[i] for k in kids)   # the build goes level by level
    assert len(tree.roots) <= 6 and tree.hi[tree.roots].sum() - tree.lo[tree.roots].sum() == len(position)
    tiles = tree.receiver_tiles(TILE_TEXELS)
    assert tiles[0, 0] == 0 and np.all(tiles[1:, 0] == tiles[:-1].sum(axis=1)) and tiles[-1].sum() == len(position)
    assert tiles[:, 1].max() <= TILE_TEXELS and tiles[:, 1].mean() > 0.4 * TILE_TEXELS
    p = position[tree.leaf_order]
    shuffled = p[rng.permutation(len(p))]
    spread = [np.ptp(p[a:a + c], axis=0).max() for a, c in tiles if c > 1]
    random_spread = [np.ptp(shuffled[a:a + c], axis=0).max() for a, c in tiles if c > 1]
    assert np.median(spread) < 0.5 * np.median(random_spread)   # a tile holds nearby texels
    # any leaf range is a node range whose walk covers exactly those leaves
    first, end = tree.node_range(100, 700)
    i, covered = first, []
    while i < end:
        if tree.skip[i] <= end:
            covered.append((int(tree.lo[i]), int(tree.hi[i])))
            i = int(tree.skip[i])
        else:
            i += 1
    assert covered[0][0] == 100 and covered[-1][1] == 700
    assert all(a[1] == b[0] for a, b in zip(covered[:-1], covered[1:]))


def test_bad_tree_input():
    with pytest.raises(ValueError, match="no covered lightmap texel"):
        build_tree(np.zeros((0, 3)), np.zeros((0, 3)))
    with pytest.raises(ValueError, match="non-finite"):
        build_tree(np.array([[0.0, np.nan, 0.0]]), np.array([[0.0, 1.0, 0.0]]))


def test_tiles_dispatched_in_batches(gl_ctx, monkeypatch):
    """More receiver tiles than one dispatch may hold (GL guarantees 65,535 work groups; a
    1024^2 lightmap has ~65,000 tiles of 16 texels) are gathered in batches: the same sums."""
    import methods.pbgi.method as pbgi
    scene = make_tiled_box(20)
    whole = _run(gl_ctx, scene, {})
    monkeypatch.setattr(pbgi, "MAX_WORK_GROUPS", 100)
    batched = _run(gl_ctx, scene, {})
    assert whole["tiles"] > 300
    assert np.array_equal(batched["lightmap"], whole["lightmap"])
    assert np.array_equal(batched["visits"], whole["visits"])
