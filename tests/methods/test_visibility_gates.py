"""visibility_gates: topology precomputation (voxels, skeleton, clusters, gates) and the GL
pipeline (geometry clusters, light assignment, gather), checked against ir_unshadowed (same VPLs),
a numpy brute force of the same visibility rule, and the analytic sphere."""
import numpy as np
import pytest
from scipy import sparse

from bench.corpus import load_scene
from bench.corpus.procedural import sphere_inside_indirect
from bench.gl import Frame, GpuScene, SharedPasses, StageProfiler, read_rgb
from bench.harness import run_method
from bench.method import ParamError, SkipRow, resolve_params
from bench.metrics import relmse
from methods.ir_shadowed.method import InstantRadiosityShadowed
from methods.ir_unshadowed.method import InstantRadiosityUnshadowed
from methods.visibility_gates.method import VisibilityGates, scene_topology
from methods.visibility_gates.topology import (KIND_COVERAGE, KIND_TOPOLOGY, KIND_UNCLASSIFIED, cluster,
                                               prune_spurs)
from tests.conftest import make_open_box

W, H = 64, 48
ROOMS_PARAMS = {"voxel_resolution": 64, "vpl_count": 128}


@pytest.fixture(scope="module")
def rooms():
    return load_scene("rooms")


def render_frame(ctx, scene, params, seed=0):
    """One frame by hand, keeping the VPLs and the GBuffer for the numpy brute force."""
    gpu = GpuScene(ctx, scene, seed=seed)
    view = gpu.view("main", W, H)
    passes = SharedPasses(gpu, view, VisibilityGates.needs)
    method = VisibilityGates()
    try:
        method.prepare(gpu, scene, gpu.facts, resolve_params(VisibilityGates, params), view)
        prof = StageProfiler(ctx)
        passes.render(prof)
        out = method.render(Frame(ctx=ctx, gpu=gpu, view=view, passes=passes, index=0, seed=seed), prof)
        vpls = method.sampler.read_vpls()
        vpls["position"] = vpls["position"].astype(np.float64) + gpu.origin
        return {"indirect": read_rgb(out.indirect), "vpls": vpls, "gbuffer": passes.gbuffer.read(),
                "topology": method.topology, "eps": method.eps}
    finally:
        method.release()
        passes.release()
        gpu.release()


def brute_force(frame, gate_scale=1.0):
    """The method's estimate in numpy: same-cluster VPLs always, other clusters' VPLs when the
    segment crosses a gate of the VPL's cluster (float64, no geometry clusters, no culling)."""
    topo, gb, v = frame["topology"], frame["gbuffer"], frame["vpls"]
    mask = gb["mask"].ravel()
    x = gb["position"].reshape(-1, 3)[mask].astype(np.float64)
    nx = gb["normal"].reshape(-1, 3)[mask].astype(np.float64)
    rho = gb["albedo"].reshape(-1, 3)[mask]
    lit = np.any(v["flux"] != 0, axis=1)
    y, ny, phi = v["position"][lit], v["normal"][lit].astype(np.float64), v["flux"][lit].astype(np.float64)
    cx = topo.cluster_of(x + nx * topo.pitch)
    cy = topo.cluster_of(y + ny * topo.pitch)
    d = y[None] - x[:, None]                                   # (P, K, 3) x -> y
    dist = np.linalg.norm(d, axis=2)
    w = d / np.maximum(dist, 1e-30)[..., None]
    cos_x = np.einsum("pkc,pc->pk", w, nx)
    cos_y = -np.einsum("pkc,kc->pk", w, ny)
    visible = cx[:, None] == cy[None]
    for c_, n_, r_, (a, b) in zip(topo.gate_centre, topo.gate_normal, topo.gate_radius, topo.gate_clusters):
        # the cone from a VPL of cluster a (b) through the gate lights pixels of any other cluster
        pair = ((cy[None] == a) & (cx[:, None] != a)) | ((cy[None] == b) & (cx[:, None] != b))
        sy = (y - c_) @ n_
        sx = (x - c_) @ n_
        opposite = sy[None] * sx[:, None] < 0
        t = sy[None] / np.where(opposite, sy[None] - sx[:, None], 1.0)
        q = y[None] + t[..., None] * (x[:, None] - y[None]) - c_
        visible |= pair & opposite & (np.linalg.norm(q, axis=2) <= r_ * gate_scale)
    term = np.where(visible & (cos_x > 0) & (cos_y > 0), cos_x * cos_y / np.maximum(frame["eps"], dist) ** 2, 0.0)
    out = np.zeros((H * W, 3))
    out[mask] = rho * (term @ phi) / np.pi ** 2
    return out.reshape(H, W, 3), cx


# --------------------------------------------------------------------------- precomputation
def test_rooms_topology_separates_rooms_with_gates(rooms):
    topo, _ = scene_topology(rooms, 64, 20.0)
    assert topo.cluster_count >= 3 and len(topo.gate_radius) >= 2
    assert np.all(topo.gate_clusters[:, 0] != topo.gate_clusters[:, 1])
    assert np.allclose(np.linalg.norm(topo.gate_normal, axis=1), 1.0)
    # the three room centres lie in three different visibility clusters
    centres = np.array([[2.0, 1.35, 0.0], [6.0, 1.35, 0.0], [10.0, 1.35, 0.0]])
    assert len(set(topo.cluster_of(centres).tolist())) == 3
    # segmentation: topology nodes are those of degree != 2 (or a loop's seed); the segmented
    # skeleton keeps only classified nodes and every node is associated with a classified one
    kept = topo.node_kind != KIND_UNCLASSIFIED
    assert np.all(kept[topo.segmented_edges.ravel()])
    assert np.all(kept[topo.node_segment])
    assert np.any(topo.node_kind == KIND_TOPOLOGY)
    # each gate's radius is the smaller maximal ball of its edge: it fits in the empty space
    assert np.all(topo.gate_radius > 0) and np.all(topo.gate_radius <= topo.node_radius.max())


def test_open_scene_is_skipped_with_reason(gl_ctx):
    with pytest.raises(SkipRow, match="encloses no empty space"):
        run_method(gl_ctx, VisibilityGates, make_open_box(), "main", W, H, {"voxel_resolution": 16}, frames=1)


def test_bad_parameters_are_one_line_errors():
    for bad in ({"vpl_count": 0}, {"voxel_resolution": 8}, {"gate_radius_scale": -1.0},
                {"use_gates": "yes"}, {"depth_slices": 1000}, {"alpha_percent": float("nan")}):
        with pytest.raises(ParamError) as err:
            resolve_params(VisibilityGates, bad)
        message = str(err.value)
        assert "\n" not in message and "visibility_gates" in message and next(iter(bad)) in message


# --------------------------------------------------------------------------- rendering
def test_single_cluster_sphere_equals_ir_unshadowed_and_analytic(gl_ctx):
    """Inside a sphere the empty space is one convex cluster: every VPL lights every pixel, the
    result is ir_unshadowed's (same VPLs, same code) and the analytic rho^2 I / (pi R^2)."""
    scene = load_scene("sphere_inside", subdivisions=3)
    params = {"voxel_resolution": 24, "vpl_count": 512}
    vg = run_method(gl_ctx, VisibilityGates, scene, "main", W, H, params, seed=3, frames=1)
    ir = run_method(gl_ctx, InstantRadiosityUnshadowed, scene, "main", W, H, {"vpl_count": 512}, seed=3, frames=1)
    assert vg.extra["visibility_clusters"] == 1 and vg.extra["gates"] == 0
    np.testing.assert_allclose(vg.indirect, ir.indirect, rtol=1e-6, atol=0)
    expected = sphere_inside_indirect()
    assert abs(vg.indirect.mean() / expected - 1) < 0.03


def test_gl_matches_numpy_visibility_rule_on_rooms(gl_ctx, rooms):
    """Geometry clusters + light assignment + gather == the brute-force rule in float64 (the
    cone/sphere culling is conservative, so no accepted VPL is lost). Pixels whose cluster lookup
    differs between float32 and float64 at a voxel boundary are excluded."""
    frame = render_frame(gl_ctx, rooms, ROOMS_PARAMS, seed=5)
    expected, clusters = brute_force(frame)
    got = frame["indirect"]
    assert expected.max() > 0
    err = np.abs(got - expected).max(axis=2)
    bad = err > 1e-4 * expected.max() + 1e-4 * np.abs(expected).max(axis=2)
    assert bad.mean() < 0.01, f"{bad.sum()} of {bad.size} pixels differ from the brute force"
    assert abs(got.sum() / expected.sum() - 1) < 0.01
    # the camera's room (2) sees light from room 1: some of it came through a gate
    seen = np.unique(clusters)
    assert len(seen) >= 2


def test_light_crosses_clusters_only_through_gates(gl_ctx, rooms):
    """Without gates (or with zero-radius disks) a pixel is lit only by VPLs of its own cluster;
    growing the disks only adds light (pixelwise monotone), never above ir_unshadowed with the
    same VPLs: the gates are what the method approximates visibility with."""
    runs = {}
    for key, extra in (("no_gates", {"use_gates": False}), ("zero", {"gate_radius_scale": 0.0}),
                       ("one", {}), ("three", {"gate_radius_scale": 3.0})):
        runs[key] = run_method(gl_ctx, VisibilityGates, rooms, "main", W, H, dict(ROOMS_PARAMS, **extra),
                               seed=2, frames=1).indirect
    unshadowed = run_method(gl_ctx, InstantRadiosityUnshadowed, rooms, "main", W, H, {"vpl_count": 128},
                            seed=2, frames=1).indirect
    np.testing.assert_array_equal(runs["no_gates"], runs["zero"])
    tol = 1e-6 * unshadowed.max()
    assert np.all(runs["zero"] <= runs["one"] + tol)
    assert np.all(runs["one"] <= runs["three"] + tol)
    assert np.all(runs["three"] <= unshadowed + tol)
    gain_one = (runs["one"] - runs["zero"]).sum()
    gain_three = (runs["three"] - runs["one"]).sum()
    assert gain_one > 0 and gain_three > 0          # the gates carry light into the camera's room
    assert ((runs["three"] - unshadowed) ** 2).mean() < ((runs["zero"] - unshadowed) ** 2).mean()


def test_deterministic_finite_and_timed(gl_ctx, rooms):
    a = run_method(gl_ctx, VisibilityGates, rooms, "main", W, H, ROOMS_PARAMS, seed=11, frames=2)
    b = run_method(gl_ctx, VisibilityGates, rooms, "main", W, H, ROOMS_PARAMS, seed=11, frames=1)
    c = run_method(gl_ctx, VisibilityGates, rooms, "main", W, H, ROOMS_PARAMS, seed=12, frames=1)
    np.testing.assert_array_equal(a.indirect, b.indirect)
    assert not np.array_equal(a.indirect, c.indirect)
    assert np.all(np.isfinite(a.indirect)) and a.indirect.max() > 0
    for stage in VisibilityGates.stages:
        assert len(a.stage_ms[stage]) == 2 and all(ms >= 0 for ms in a.stage_ms[stage])
    assert a.extra["precompute_s"] >= 0 and a.extra["gates"] >= 2


# --------------------------------------------------------------------------- regressions (vgfix)
def _chain(*corners):
    """Voxel coordinates of an axis-aligned polyline through the given corners (each voxel once)."""
    out = [np.asarray(corners[0])]
    for a, b in zip(corners[:-1], corners[1:]):
        a, b = np.asarray(a), np.asarray(b)
        step = np.sign(b - a)
        for i in range(1, int(np.abs(b - a).max()) + 1):
            out.append(a + i * step)
    return out


def test_spurs_the_junction_sees_are_pruned_hidden_branches_kept():
    """A junction with three branches in a room cut by a wall (x = 6 for y < 8): the two short
    branches it sees in a straight line are pruned, the one that turns around the wall is kept."""
    space = np.ones((12, 13, 5), bool)
    space[6, :8, :] = False
    junction = (3, 2, 2)
    left = _chain(junction, (1, 2, 2))[1:]
    right = _chain(junction, (5, 2, 2))[1:]
    around = _chain(junction, (3, 10, 2), (9, 10, 2), (9, 2, 2))[1:]
    coords = np.array([junction] + left + right + around)
    index = {tuple(c): i for i, c in enumerate(coords)}
    rows, cols = [], []
    for branch in (left, right, around):
        path = [junction] + [tuple(c) for c in branch]
        for a, b in zip(path[:-1], path[1:]):
            rows.append(index[tuple(a)]); cols.append(index[tuple(b)])
    n = len(coords)
    graph = sparse.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    graph = ((graph + graph.T) > 0).astype(np.int32).tocsr()
    kept, kept_graph = prune_spurs(coords, graph, space)
    expected = {tuple(junction)} | {tuple(c) for c in around}
    assert {tuple(c) for c in kept} == expected
    assert kept_graph.shape == (len(expected), len(expected))
    assert int(kept_graph.sum()) == 2 * (len(expected) - 1)  # still one path


def test_alpha_compares_the_two_neighbouring_balls():
    """Paper IV.B.2: a neighbour joins when its ball differs from the popped node's by at most
    alpha % of the cluster's largest radius, so a line whose radius shrinks gradually (10 % a
    step, alpha = 20) is one cluster; a jump of 30 % starts a new one."""
    pos = np.array([[3.0 * i, 0.0, 0.0] for i in range(6)])   # far apart: no ball holds a neighbour
    kind = np.array([KIND_TOPOLOGY] + [KIND_COVERAGE] * 4 + [KIND_TOPOLOGY])
    edges = np.array([[i, i + 1] for i in range(5)])
    gradual = np.array([1.0, 0.9, 0.8, 0.7, 0.6, 0.5])
    label, count = cluster(np.arange(6), edges, pos, gradual, kind, 20.0)
    assert count == 1 and set(label.values()) == {0}
    jump = np.array([1.0, 0.9, 0.8, 0.5, 0.45, 0.4])
    label, count = cluster(np.arange(6), edges, pos, jump, kind, 20.0)
    assert count == 2 and label[0] == label[2] != label[3] == label[5]


def test_cornell_spot_close_to_ir_shadowed(gl_ctx):
    """A box with two blocks: nearly every point sees nearly every other, so with the same VPLs
    the topological visibility must be close to the shadow-tested one (before the spur pruning
    and the alpha reading it was 0.74x as bright with 7 clusters at this resolution)."""
    scene = load_scene("cornell_spot")
    params = {"vpl_count": 128, "voxel_resolution": 32}
    vg = run_method(gl_ctx, VisibilityGates, scene, "main", W, H, params, seed=1, frames=1)
    shadowed = run_method(gl_ctx, InstantRadiosityShadowed, scene, "main", W, H, {"vpl_count": 128},
                          seed=1, frames=1).indirect
    ratio = vg.indirect.mean() / shadowed.mean()
    assert 0.9 < ratio < 1.1, f"mean indirect {ratio:.3f} x ir_shadowed's"
    assert relmse(vg.indirect, shadowed) < 0.02
    assert vg.extra["visibility_clusters"] <= 4  # the room and the blocks' closed interiors


def test_rooms_light_reaches_the_next_room_only_through_doors(gl_ctx, rooms):
    """The light cone of a room-1 VPL through a gate of its cluster lights whatever cluster lies
    beyond (paper V.C), not only the adjacent one: with the door's own cluster between the rooms,
    room 2 is lit from room 1 (one-cluster-hop cones gave 0.38x ir_shadowed here). Seen from
    room 3, two offset doors away from the light, nothing leaks through the walls: no brighter
    than ir_shadowed there."""
    main = run_method(gl_ctx, VisibilityGates, rooms, "main", W, H, ROOMS_PARAMS, seed=2, frames=1).indirect
    main_shadowed = run_method(gl_ctx, InstantRadiosityShadowed, rooms, "main", W, H, {"vpl_count": 128},
                               seed=2, frames=1).indirect
    ratio = main.mean() / main_shadowed.mean()
    assert 0.55 < ratio < 1.0, f"mean indirect {ratio:.3f} x ir_shadowed's"
    assert relmse(main, main_shadowed) < 0.05
    far = run_method(gl_ctx, VisibilityGates, rooms, "far", W, H, ROOMS_PARAMS, seed=2, frames=1).indirect
    far_shadowed = run_method(gl_ctx, InstantRadiosityShadowed, rooms, "far", W, H, {"vpl_count": 128},
                              seed=2, frames=1).indirect
    far_unshadowed = run_method(gl_ctx, InstantRadiosityUnshadowed, rooms, "far", W, H, {"vpl_count": 128},
                                seed=2, frames=1).indirect
    assert far_shadowed.mean() < 0.5 * far_unshadowed.mean()   # the view is a real occlusion test
    assert far.mean() <= far_shadowed.mean()
