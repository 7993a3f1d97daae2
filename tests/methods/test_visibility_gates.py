"""visibility_gates: topology precomputation (voxels, skeleton, clusters, merging, gates) and the
GL pipeline (geometry clusters, light assignment, gather), checked against ir_unshadowed and
ir_shadowed (same VPLs), a numpy brute force of the same visibility rule, exact distances and the
analytic sphere; at the default parameters unless a test is about a parameter."""
import numpy as np
import pytest
import trimesh
from scipy import ndimage, sparse

from bench.model.corpus import load_scene
from bench.model.corpus.procedural import sphere_inside_indirect
from bench.gl import Frame, GpuScene, SharedPasses, StageProfiler, read_rgb
from bench.run.harness import run_method
from bench.protocol.method import ParamError, SkipRow, resolve_params
from methods.ir_shadowed.method import InstantRadiosityShadowed
from methods.ir_unshadowed.method import InstantRadiosityUnshadowed
from methods.visibility_gates.method import VisibilityGates, scene_topology, topology_seeds
from methods.visibility_gates.gates import MAX_GATE_EDGES, merge_wide_gates
from methods.visibility_gates.skeleton import KIND_COVERAGE, KIND_TOPOLOGY, KIND_UNCLASSIFIED, cluster, prune_spurs
from methods.visibility_gates.voxels import SurfaceIndex, voxelize
from tests.conftest import make_open_box

W, H = 64, 48
DEFAULTS = resolve_params(VisibilityGates, {})
ROOMS_PARAMS = {"vpl_count": 128}


def default_topology(scene, resolution=None):
    res = DEFAULTS["voxel_resolution"] if resolution is None else resolution
    return scene_topology(scene, res, DEFAULTS["alpha_percent"], DEFAULTS["merge_gate_fraction"])[0]


def indirect_ratio(ctx, scene, view="main", seed=0, **params):
    """(mean indirect / ir_shadowed's with the same VPLs, the visibility_gates result)."""
    vg = run_method(ctx, VisibilityGates, scene, view, W, H, params, seed=seed, frames=1)
    vpl = {"vpl_count": params.get("vpl_count", VisibilityGates.params["vpl_count"].default)}   # the defaults differ
    shadowed = run_method(ctx, InstantRadiosityShadowed, scene, view, W, H, vpl, seed=seed, frames=1).indirect
    return vg.indirect.mean() / shadowed.mean(), vg


@pytest.fixture(scope="module")
def rooms():
    return load_scene("rooms")


def render_frame(ctx, scene, params, seed=0, camera="main"):
    """One frame by hand, keeping the VPLs and the GBuffer for the numpy brute force."""
    gpu = GpuScene(ctx, scene, seed=seed)
    view = gpu.view(camera, W, H)
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
                "topology": method.topology, "eps": method.eps, "params": method.params,
                "draws": list(method.draws)}
    finally:
        method.release()
        passes.release()
        gpu.release()


def gate_crossings(topo, y, x, gate_scale=1.0):
    """(P, K, G) parameter t in (0, 1) where the segment y_k -> x_p crosses gate g's polygon, else -1."""
    gs = topo.gates
    out = -np.ones((len(x), len(y), len(gs.radius)))
    for g, (c_, n_, u_, v_) in enumerate(zip(gs.centre, gs.normal, gs.axis_u, gs.axis_v)):
        sy = (y - c_) @ n_
        sx = (x - c_) @ n_
        opposite = sy[None] * sx[:, None] < 0
        t = sy[None] / np.where(opposite, sy[None] - sx[:, None], 1.0)
        q = y[None] + t[..., None] * (x[:, None] - y[None]) - c_
        p = np.stack([q @ u_, q @ v_], axis=-1)
        hp = gs.halfplanes[g, :gs.count[g]]
        inside = (gate_scale > 0) & np.all(p @ hp[:, :2].T <= hp[:, 2] * gate_scale, axis=-1)
        out[..., g] = np.where(opposite & inside, t, -1.0)
    return out


def brute_force(frame, gate_scale=1.0, hops=1, chunk=256):
    """The method's estimate in numpy: same-cluster VPLs always, another cluster's VPL when the
    segment, leaving each cluster through the first of its gates it crosses, reaches the pixel's
    cluster within `hops` gates (float64, no geometry clusters, no culling; `chunk` pixels at a
    time, which bounds the memory of the (pixel, VPL, gate) arrays, not the result)."""
    topo, gb, v = frame["topology"], frame["gbuffer"], frame["vpls"]
    mask = gb["mask"].ravel()
    xs = gb["position"].reshape(-1, 3)[mask].astype(np.float64)
    nxs = gb["normal"].reshape(-1, 3)[mask].astype(np.float64)
    lit = np.any(v["flux"] != 0, axis=1)
    y, ny = v["position"][lit], v["normal"][lit].astype(np.float64)
    cy = topo.cluster_of(y + ny * topo.pitch)
    parts, clusters = [], []
    for first in range(0, len(xs), chunk):
        x, nx = xs[first:first + chunk], nxs[first:first + chunk]
        cx = topo.cluster_of(x + nx * topo.pitch)
        visible = cx[:, None] == cy[None]
        crossing = gate_crossings(topo, y, x, gate_scale)
        here = np.broadcast_to(cy[None], visible.shape).copy()
        t_prev = np.zeros(visible.shape)
        walking = ~visible
        for _ in range(hops):
            t_best, nxt = np.full(visible.shape, 2.0), -np.ones(visible.shape, np.int64)
            for g, (a, b) in enumerate(topo.gate_clusters):
                t = crossing[..., g]
                for src, dst in ((a, b), (b, a)):
                    better = walking & (here == src) & (t > t_prev) & (t < t_best)
                    t_best = np.where(better, t, t_best)
                    nxt = np.where(better, dst, nxt)
            arrived = walking & (nxt == cx[:, None])
            visible |= arrived
            walking &= (nxt >= 0) & ~arrived
            here, t_prev = np.where(walking, nxt, here), t_best
        parts.append(visible)
        clusters.append(cx)
    visible = np.concatenate(parts) if parts else np.zeros((0, len(y)), bool)
    return vpl_sum(frame, visible, chunk), np.concatenate(clusters) if clusters else np.zeros(0, np.int64)


def near_d2(frame, dist, area):
    """The squared distance of the method's near field (bench/gl/shaders/near_field.glsl)."""
    eps, p = frame["eps"], frame["params"]
    if p["near_field"] == "footprint":
        return np.maximum(eps ** 2, np.maximum(dist ** 2, p["near_field_scale"] * area / np.pi))
    if p["near_field"] == "disc_element":
        return np.maximum(eps ** 2, dist ** 2 + area / np.pi)
    return np.maximum(eps, dist) ** 2


def vpl_sum(frame, visible, chunk=256):
    """rho/pi sum_k Phi_k/pi cos_x cos_k / d2 over the VPLs with visible[p, k] (float64), d2 the
    method's near field of the distance d (near_d2); `chunk` pixels at a time."""
    gb, v = frame["gbuffer"], frame["vpls"]
    mask = gb["mask"].ravel()
    xs = gb["position"].reshape(-1, 3)[mask].astype(np.float64)
    nxs = gb["normal"].reshape(-1, 3)[mask].astype(np.float64)
    rho = gb["albedo"].reshape(-1, 3)[mask]
    lit = np.any(v["flux"] != 0, axis=1)
    y, ny, phi = v["position"][lit], v["normal"][lit].astype(np.float64), v["flux"][lit].astype(np.float64)
    area = v["area"][lit].astype(np.float64)[None]
    sums = np.zeros((len(xs), 3))
    for first in range(0, len(xs), chunk):
        x, nx, part = xs[first:first + chunk], nxs[first:first + chunk], slice(first, first + chunk)
        d = y[None] - x[:, None]
        dist = np.linalg.norm(d, axis=2)
        w = d / np.maximum(dist, 1e-30)[..., None]
        cos_x = np.einsum("pkc,pc->pk", w, nx)
        cos_y = -np.einsum("pkc,kc->pk", w, ny)
        term = np.where(visible[part] & (cos_x > 0) & (cos_y > 0), cos_x * cos_y / near_d2(frame, dist, area), 0.0)
        sums[part] = rho[part] * (term @ phi) / np.pi ** 2
    out = np.zeros((H * W, 3))
    out[mask] = sums
    return out.reshape(H, W, 3)


# --------------------------------------------------------------------------- precomputation
def test_rooms_topology_separates_rooms_with_gates(rooms):
    topo = default_topology(rooms)
    assert topo.cluster_count >= 3 and len(topo.gate_radius) >= 2
    assert np.all(topo.gate_clusters[:, 0] != topo.gate_clusters[:, 1])
    assert np.allclose(np.linalg.norm(topo.gates.normal, axis=1), 1.0)
    # the three room centres lie in three different visibility clusters
    centres = np.array([[2.0, 1.35, 0.0], [6.0, 1.35, 0.0], [10.0, 1.35, 0.0]])
    assert len(set(topo.cluster_of(centres).tolist())) == 3
    # segmentation: topology nodes are those of degree != 2 (or a loop's seed); the segmented
    # skeleton keeps only classified nodes and every node is associated with a classified one
    kept = topo.node_kind != KIND_UNCLASSIFIED
    assert np.all(kept[topo.segmented_edges.ravel()])
    assert np.all(kept[topo.node_segment])
    assert np.any(topo.node_kind == KIND_TOPOLOGY)
    # each gate is a convex polygon in its plane around its centre: unit half-plane normals,
    # positive offsets, its u axis in the plane, its bounding radius the farthest vertex
    gs = topo.gates
    assert np.allclose(np.einsum("gc,gc->g", gs.axis_u, gs.normal), 0.0, atol=1e-9)
    for g in range(len(gs.radius)):
        hp = gs.halfplanes[g, :gs.count[g]]
        assert 3 <= len(hp) <= MAX_GATE_EDGES and np.all(hp[:, 2] > 0)
        np.testing.assert_allclose(np.linalg.norm(hp[:, :2], axis=1), 1.0)
        assert np.isclose(np.linalg.norm(gs.vertices(g), axis=1).max(), gs.radius[g])


def test_scene_without_empty_space_to_light_is_skipped_with_reason(gl_ctx):
    """An open scene whose light and camera are both outside its (enlarged) bounding box has no
    space light travels in that the method could close: skipped, with the reason."""
    with pytest.raises(SkipRow, match="no empty space"):
        run_method(gl_ctx, VisibilityGates, make_open_box(light_position=(0.0, 1.0, 3.0)), "main", W, H, {},
                   frames=1)


def test_bad_parameters_are_one_line_errors():
    for bad in ({"vpl_count": 0}, {"voxel_resolution": 8}, {"gate_radius_scale": -1.0},
                {"use_gates": "yes"}, {"depth_slices": 1000}, {"alpha_percent": float("nan")},
                {"merge_gate_fraction": -0.1}, {"gate_hops": 0}):
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


@pytest.mark.parametrize("camera, hops", [("main", 1), ("far", 3)])
def test_gl_matches_numpy_visibility_rule_on_rooms(gl_ctx, rooms, camera, hops):
    """Geometry clusters + light assignment + gather == the brute-force rule in float64 (the
    cone/sphere culling is conservative, so no accepted VPL is lost), for the default single
    gate hop and for a walk through several gates. Pixels whose cluster lookup differs between
    float32 and float64 at a voxel boundary are excluded."""
    frame = render_frame(gl_ctx, rooms, dict(ROOMS_PARAMS, gate_hops=hops), seed=5, camera=camera)
    expected, clusters = brute_force(frame, hops=hops)
    got = frame["indirect"]
    assert expected.max() > 0
    err = np.abs(got - expected).max(axis=2)
    bad = err > 1e-4 * expected.max() + 1e-4 * np.abs(expected).max(axis=2)
    assert bad.mean() < 0.01, f"{bad.sum()} of {bad.size} pixels differ from the brute force"
    assert abs(got.sum() / expected.sum() - 1) < 0.01
    # the camera's room (2) sees light from room 1: some of it came through a gate
    seen = np.unique(clusters)
    assert len(seen) >= 2


@pytest.mark.parametrize("camera", ["main", "far"])
@pytest.mark.parametrize("rung", VisibilityGates.ladder,
                         ids=lambda r: f"vpl_count={resolve_params(VisibilityGates, dict(r))['vpl_count']}")
def test_gl_matches_numpy_visibility_rule_at_every_ladder_rung(gl_ctx, rooms, rung, camera):
    """Issue #23 (lost_empire's ladder): the visibility rule does not depend on the VPL count, so
    the GL parts that do (one light-mask word per 32 VPLs, the gather's draws over ranges of
    words under LOOP_CHUNK) must give the brute force at every rung, the walk through gates at
    its default length: the expected image then changes along the ladder only through the near
    field (NOTES.md, "The ladder on lost_empire"). Both views: 'main' sees the last words' VPLs,
    'far' light through two doors."""
    params = resolve_params(VisibilityGates, dict(rung))
    frame = render_frame(gl_ctx, rooms, dict(rung), seed=3, camera=camera)
    assert len(frame["draws"]) > 1                         # the chunking is exercised
    expected, clusters = brute_force(frame, hops=params["gate_hops"])
    got = frame["indirect"]
    assert expected.max() > 0 and len(np.unique(clusters)) >= 2
    err = np.abs(got - expected).max(axis=2)
    bad = err > 1e-4 * expected.max() + 1e-4 * np.abs(expected).max(axis=2)
    assert bad.mean() < 0.01, f"{bad.sum()} of {bad.size} pixels differ from the brute force"
    assert abs(got.sum() / expected.sum() - 1) < 0.01


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


def test_rooms_light_reaches_the_next_room_only_through_doors(gl_ctx, rooms):
    """Light from room 1 reaches the camera's room 2 through the door's gate, which is the door
    (the paper's disk of the door's maximal ball, 0.45 m for a 0.9 x 2.1 m door, let through a
    third of it: 0.59x ir_shadowed). Seen from room 3, two offset doors away from the light,
    the light walks through both doors' gates (default gate_hops); one hop (a VPL lights its
    neighbour cluster only, paper Fig. 11) only loses light there."""
    ratio, _ = indirect_ratio(gl_ctx, rooms, "main", seed=2)
    assert 0.85 <= ratio <= 1.15, f"mean indirect {ratio:.3f} x ir_shadowed's"
    far, far_run = indirect_ratio(gl_ctx, rooms, "far", seed=2)
    assert 0.7 <= far <= 1.15, f"far view: mean indirect {far:.3f} x ir_shadowed's"
    one = run_method(gl_ctx, VisibilityGates, rooms, "far", W, H, {"gate_hops": 1}, seed=2, frames=1).indirect
    assert np.all(one <= far_run.indirect + 1e-6 * one.max()) and one.mean() < far_run.indirect.mean()


# --------------------------------------------------------------------------- regressions (issue 11)
def test_tilted_walls_close_the_empty_space():
    """Voxels within sqrt(3)/2 voxel of a triangle are occupied, so a closed box turned about two
    axes separates its inside from its outside for the 26-connected thinning (sampling the
    triangles let the skeleton through tilted walls of cornell_spot's blocks: gates of 0.02 m)."""
    box = trimesh.creation.box(extents=(1.0, 0.8, 0.6))
    box.apply_transform(trimesh.transformations.euler_matrix(0.3, 0.5, 0.2))
    room = trimesh.creation.box(extents=(3.0, 3.0, 3.0))
    verts = np.concatenate([room.vertices, box.vertices])
    faces = np.concatenate([room.faces, box.faces + len(room.vertices)])
    for res in (24, 40, 64):
        _, empty, _, _, _, _ = voxelize(verts, faces, res)
        labels, count = ndimage.label(empty, structure=np.ones((3, 3, 3), bool))
        assert count == 2, f"voxel_resolution {res}: {count} components of the empty space"


def test_maximal_balls_are_exact_distances_to_the_triangles():
    """Ball radii are the exact point-triangle distance (k-d tree candidates, trimesh's exact
    distance), not a distance to voxel centres: checked against all triangles."""
    rng = np.random.default_rng(4)
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    mesh.vertices += rng.normal(0.0, 0.05, mesh.vertices.shape)
    query = rng.uniform(-0.7, 0.7, (200, 3))
    index = SurfaceIndex(mesh.vertices, mesh.faces, 0.3)
    tri = mesh.vertices[mesh.faces]
    full = np.array([np.linalg.norm(trimesh.triangles.closest_point(tri, np.repeat(q[None], len(tri), 0)) - q,
                                    axis=1).min() for q in query])
    np.testing.assert_allclose(index.distance(query), full, rtol=1e-9, atol=1e-12)
    assert np.array_equal(index.near(query, 0.5), full <= 0.5)


def test_wide_gates_merge_narrow_ones_separate():
    """A cluster joined by a gate nearly as wide as its largest ball is one space with its
    neighbour (0.9 >= 0.75); a door (a gate a third of both rooms' balls) keeps them apart;
    merges are re-evaluated with the merged clusters' balls and labels stay in order."""
    radius = np.array([1.3, 0.45, 1.3, 0.2])
    pairs = np.array([[0, 1], [1, 2], [2, 3]])
    gate_r = np.array([0.42, 0.42, 0.18])
    label, count = merge_wide_gates(4, radius, gate_r, pairs, 0.75)
    assert count == 2 and label[0] == label[1] == 0 and label[2] == label[3] == 1
    label, count = merge_wide_gates(4, radius, gate_r, pairs, 2.0)
    assert count == 4 and list(label) == [0, 1, 2, 3]


def test_cornell_spot_topology_is_stable_across_resolutions():
    """The box with its blocks is one room cluster (plus the blocks' closed interiors, apart from
    it) at voxel_resolution 32, 64 and 128 alike: before, 1, 19 and 26 clusters, from skeleton
    leaks through the blocks' tilted walls and radii measured to thickened voxels."""
    scene = load_scene("cornell_spot")
    room_points = np.array([[0.0, 1.6, 0.0], [0.7, 1.0, 0.7], [-0.7, 0.3, 0.7], [0.8, 0.3, -0.8], [0.0, 1.0, 0.95]])
    for res in (32, 64, 128):
        topo = default_topology(scene, res)
        rooms = set(topo.cluster_of(room_points).tolist())
        assert len(rooms) == 1, f"voxel_resolution {res}: room points in clusters {rooms}"
        assert topo.cluster_count <= 3 and len(topo.gate_radius) == 0, \
            f"voxel_resolution {res}: {topo.cluster_count} clusters, {len(topo.gate_radius)} gates"


def test_defaults_close_to_ir_shadowed_on_closed_scenes(gl_ctx):
    """At the defaults the indirect is within 15 % of ir_shadowed's with the same VPLs on the
    box with blocks and on hidden_bounce (0.65x and 0.63x before, at voxel_resolution 64)."""
    for name in ("cornell_spot", "hidden_bounce"):
        ratio, run = indirect_ratio(gl_ctx, load_scene(name), seed=1)
        assert 0.85 <= ratio <= 1.15, f"{name}: mean indirect {ratio:.3f} x ir_shadowed's"
        assert not run.extra["closed_by_box"]


def test_open_scene_is_closed_by_its_bounding_box(gl_ctx):
    """big_floor (floor and wall, no roof) was skipped: its camera and light are in the space
    around the geometry, which the enlarged bounding box closes; the balls stop at that box."""
    scene = load_scene("big_floor")
    topo = default_topology(scene)
    assert topo.closed_by_box
    lo = topo.origin + topo.pitch                                  # the closing box: the grid's outer layer
    hi = topo.origin + (np.asarray(topo.dims) - 1) * topo.pitch
    assert np.all(lo < scene.vertices.min(0)) and np.all(hi > scene.vertices.max(0))
    box_distance = np.minimum(topo.node_position - lo, hi - topo.node_position).min(axis=1)
    assert np.all(topo.node_radius <= box_distance + 1e-9)
    ratio, run = indirect_ratio(gl_ctx, scene, seed=1)
    assert run.extra["closed_by_box"] and 0.85 <= ratio <= 1.15, f"big_floor: {ratio:.3f} x ir_shadowed's"


def test_door_gate_is_the_door():
    """The gate between two rooms is the door: a polygon in the wall's plane (x = 4, not the plane
    through a skeleton voxel beside it) with the door's corners (0.9 x 2.1 m at z 0.6..1.5), where
    the ellipse of the opening's second moments (semi-axes 2.1 / sqrt(3), 0.9 / sqrt(3)) stuck
    out of the door's sides by 7 cm and above its lintel by 16 cm and missed its corners."""
    topo = default_topology(load_scene("rooms"))
    gs = topo.gates
    door = int(np.argmin(np.abs(gs.centre[:, 0] - 4.0)))
    assert abs(gs.centre[door, 0] - 4.0) < 1e-3 and abs(gs.normal[door, 0]) > 1 - 1e-6
    corners = gs.centre[door] + gs.vertices(door) @ np.stack([gs.axis_u[door], gs.axis_v[door]])
    expected = np.array([[4.0, y, z] for y in (0.0, 2.1) for z in (0.6, 1.5)])
    assert len(corners) == 4
    gaps = np.linalg.norm(corners[:, None] - expected[None], axis=2).min(axis=1)
    assert gaps.max() < 0.02, f"gate corners {corners.round(3).tolist()}"


def test_parameter_tables_match_the_params():
    """Every knob is in the manual's and the README's parameter tables with its default and range."""
    import sys
    from pathlib import Path
    module = sys.modules[VisibilityGates.__module__]
    readme = (Path(module.__file__).parent / "README.md").read_text()
    for text in (module.__doc__, readme):
        rows = {cells[0]: cells for cells in ([c.strip() for c in line.strip().strip("|").split("|")]
                                              for line in text.splitlines() if line.startswith("| "))}
        for name, p in VisibilityGates.params.items():
            assert name in rows, name
            default, span = rows[name][1], rows[name][2]
            if isinstance(p.default, bool):
                assert default == str(p.default).lower() and span == "bool", (name, rows[name])
            elif p.choices is not None:   # the shared near field: a choice, listed as such
                assert default == p.default and span == ", ".join(p.choices), (name, rows[name])
            else:
                assert float(default) == p.default, (name, rows[name])
                low, high = (float(x) for x in span.split(".."))
                assert (low, high) == (p.low, p.high), (name, rows[name])


def test_wide_gate_merge_keeps_the_union_quasi_convex():
    """merge_visible_fraction: two clusters joined by a wide gate are merged when the segments
    between their skeleton nodes stay in the empty space (a straight corridor cut by a break in
    the radii), not when the union bends round a corner (an L: its arms see little of each other)."""
    space = np.zeros((30, 30, 5), bool)
    space[:10, :, :] = True      # arm along y
    space[:, :10, :] = True      # arm along x
    straight = np.array([[5, y, 2] for y in range(12, 30)])
    corner = np.array([[x, 5, 2] for x in range(12, 30)])
    coords = np.concatenate([straight[:9], straight[9:], corner])
    node_cluster = np.repeat([0, 1, 2], [9, 9, 18])
    radius = np.array([2.0, 2.0, 2.0])
    pairs = np.array([[0, 1], [0, 2]])
    gate_r = np.array([1.8, 1.8])
    label, count = merge_wide_gates(3, radius, gate_r, pairs, 0.75)
    assert count == 1
    label, count = merge_wide_gates(3, radius, gate_r, pairs, 0.75, space, coords, node_cluster, 0.9)
    assert count == 2 and label[0] == label[1] != label[2]


def test_defaults_keep_sibeniks_nave_apart_from_its_aisles():
    """At the defaults a merge across a wide gate keeps the merged cluster quasi-convex (the paper's
    IV.B): sibenik's nave, its aisles behind the pillar rows and its galleries stay 22 clusters
    joined by gates; merging by gate width alone left 12, whose VPLs lit the aisles through the
    pillars (relMSE 1.13 against the visible reference, above no indirect light's 0.96; 0.50 now).
    A door's own cluster still joins its room (rooms keeps its three clusters)."""
    defaults = resolve_params(VisibilityGates, {})
    assert defaults["merge_visible_fraction"] == 0.5
    args = (defaults["voxel_resolution"], defaults["alpha_percent"], defaults["merge_gate_fraction"])
    sibenik = load_scene("sibenik")
    checked, _ = scene_topology(sibenik, *args, defaults["merge_visible_fraction"])
    width_only, _ = scene_topology(sibenik, *args, 0.0)
    assert checked.cluster_count >= width_only.cluster_count + 8, (checked.cluster_count, width_only.cluster_count)
    rooms_topology, _ = scene_topology(load_scene("rooms"), *args, defaults["merge_visible_fraction"])
    assert rooms_topology.cluster_count == 3


def uncovered_border_area(topo, empty) -> float:
    """m^2 of the voxel faces between two clusters' empty voxels that no gate of the two clusters
    holds (within a voxel of its plane, inside its polygon); in a gate's own voxels the side of
    its plane decides the cluster (Topology.cluster_of at the voxel centres)."""
    gs, pitch = topo.gates, topo.pitch
    idx = np.argwhere(empty)
    grid = -np.ones(empty.shape, np.int64)
    grid[tuple(idx.T)] = topo.cluster_of(topo.origin + (idx + 0.5) * pitch)
    uncovered = 0
    for axis in range(3):
        n = empty.shape[axis] - 1
        a, b = np.take(grid, np.arange(n), axis=axis), np.take(grid, np.arange(1, n + 1), axis=axis)
        faces = np.argwhere((a >= 0) & (b >= 0) & (a != b))
        centre = topo.origin + (faces + 0.5) * pitch
        centre[:, axis] += 0.5 * pitch
        ca, cb = a[tuple(faces.T)], b[tuple(faces.T)]
        held = np.zeros(len(faces), bool)
        for g, (p, q) in enumerate(gs.pairs):
            mine = ((ca == p) & (cb == q)) | ((ca == q) & (cb == p))
            rel = centre[mine] - gs.centre[g]
            uv = np.column_stack([rel @ gs.axis_u[g], rel @ gs.axis_v[g]])
            hp = gs.halfplanes[g, :gs.count[g]]
            inside = (np.abs(rel @ gs.normal[g]) <= pitch) & np.all(uv @ hp[:, :2].T <= hp[:, 2] + 1e-9, axis=1)
            held[np.flatnonzero(mine)[inside]] = True
        uncovered += int((~held).sum())
    return uncovered * pitch * pitch


def test_border_gates_give_every_border_between_clusters_a_gate():
    """Light crosses from cluster to cluster only through gates, so every border between two
    clusters needs one (paper VII, "perfect manifolds separating clusters"). A skeleton edge's gate
    is one opening of the border: with `border_gates` the rest of sibenik's borders (at the
    other parameters' defaults) get gates of their own, each within a voxel of its patch;
    without, 100+ m^2 of border (openings beside the skeleton's) block all light."""
    defaults = resolve_params(VisibilityGates, {})
    args = (defaults["voxel_resolution"], defaults["alpha_percent"], defaults["merge_gate_fraction"],
            defaults["merge_visible_fraction"])
    sibenik = load_scene("sibenik")
    _, empty, *_ = voxelize(np.asarray(sibenik.vertices, float), np.asarray(sibenik.faces), args[0],
                            topology_seeds(sibenik))
    covered, _ = scene_topology(sibenik, *args, True)
    assert uncovered_border_area(covered, empty) == 0.0
    skeleton_only, _ = scene_topology(sibenik, *args, defaults["border_gates"])
    assert uncovered_border_area(skeleton_only, empty) > 100.0
