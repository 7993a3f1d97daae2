"""visibility_gates: gates that are the openings (convex polygons in the plane of the opening's
frame), visibility clusters split at the gates, light walking through several gates, checked
at the default parameters against the same VPLs summed with exact visibility (the rooms scene's
walls rasterised independently of the topology), and the quality ladder."""
import numpy as np
import pytest
import trimesh

from bench.model.corpus import load_scene
from bench.protocol.method import resolve_params
from methods.visibility_gates.method import VisibilityGates
from methods.visibility_gates.gates import _halfplane_polygon, _polygon_area, opening_polygon
from methods.visibility_gates.voxels import SurfaceIndex
from tests.methods.test_visibility_gates import default_topology, render_frame, vpl_sum


@pytest.fixture(scope="module")
def rooms():
    return load_scene("rooms")


def test_opening_of_a_thick_tilted_wall_is_its_hole():
    """A square hole (0.8 m) in a 0.3 m thick slab turned 25 degrees about the vertical: the
    opening measured in a plane through the slab normal to it is the hole (exact distances: the
    occluder's nearest approach beyond the free region places each edge), whatever the raster."""
    hole, thick, size = 0.8, 0.3, 4.0
    blocks = []
    for (z0, z1, y0, y1) in ((-size, -hole / 2, -size, size), (hole / 2, size, -size, size),
                             (-hole / 2, hole / 2, -size, -hole / 2), (-hole / 2, hole / 2, hole / 2, size)):
        box = trimesh.creation.box(extents=(thick, y1 - y0, z1 - z0))
        box.apply_translation((0.0, 0.5 * (y0 + y1), 0.5 * (z0 + z1)))
        blocks.append(box)
    slab = trimesh.util.concatenate(blocks)
    turn = trimesh.transformations.rotation_matrix(np.radians(25.0), (0, 1, 0))
    slab.apply_transform(turn)
    normal = turn[:3, :3] @ np.array([1.0, 0.0, 0.0])
    surface = SurfaceIndex(slab.vertices, slab.faces, 0.02)
    centre, axis_u, halfplanes = opening_polygon(surface, np.array([0.0, 0.1, -0.05]), normal, 1.6, 0.1)
    area = _polygon_area(_halfplane_polygon(halfplanes))
    assert abs(area / hole ** 2 - 1) < 0.02, f"opening area {area:.4f} m^2, hole {hole ** 2:.4f}"
    assert np.linalg.norm(centre - (np.array([0.0, 0.1, -0.05]) @ normal) * normal) < 0.02


def test_rooms_clusters_are_split_at_the_walls():
    """The gates separate the clusters: every point within a voxel of the walls between rooms
    (beside the doors, in the rooms' corners) is in its own room's cluster. Before, the voxel
    grid took each voxel's nearest skeleton node, so a door's cluster reached into the next room
    (94 of 3805 VPLs of room 1 lit room 2 unshadowed) and the walls' voxels split arbitrarily."""
    topo = default_topology(load_scene("rooms"))
    rooms = topo.cluster_of(np.array([[2.0, 1.35, 0.0], [6.0, 1.35, 0.0], [10.0, 1.35, 0.0]]))
    assert len(set(rooms.tolist())) == 3
    ys, zs = np.meshgrid(np.linspace(0.05, 2.6, 12), np.linspace(-1.97, 1.97, 24))
    for wall in (4.0, 8.0):
        for offset, room in ((-0.02, int(wall // 4) - 1), (0.02, int(wall // 4))):
            for shift in (offset, 2.5 * offset, 6.0 * offset):
                points = np.column_stack([np.full(ys.size, wall + shift), ys.ravel(), zs.ravel()])
                got = topo.cluster_of(points)
                assert np.all(got == rooms[room]), \
                    f"{np.sum(got != rooms[room])} points at x = {wall + shift:.2f} outside room {room + 1}'s cluster"


def rooms_exact_visibility(scene, y, x):
    """(P, K) exact visibility between the rooms scene's points: every room is a convex box, so
    only the walls between rooms (the triangles in the planes x = 4 and x = 8) occlude; each
    wall's triangles are rasterised at 5 mm in (y, z) and a segment is blocked where it crosses
    a covered cell."""
    from skimage.draw import polygon as raster_polygon
    tri = scene.vertices[scene.faces]
    visible = np.ones((len(x), len(y)), bool)
    cell = 0.005
    lo = scene.vertices.min(0)
    shape = (int(np.ceil((scene.vertices[:, 1].max() - lo[1]) / cell)) + 2,
             int(np.ceil((scene.vertices[:, 2].max() - lo[2]) / cell)) + 2)
    for plane in (4.0, 8.0):
        on = np.all(np.abs(tri[:, :, 0] - plane) < 1e-9, axis=1)
        assert on.any()
        covered = np.zeros(shape, bool)
        for t in tri[on]:
            rr, cc = raster_polygon((t[:, 1] - lo[1]) / cell, (t[:, 2] - lo[2]) / cell, shape)
            covered[rr, cc] = True
        sx, sy = x[:, 0, None] - plane, y[None, :, 0] - plane
        cross = sx * sy < 0
        t = sy / np.where(cross, sy - sx, 1.0)
        q = y[None] + t[..., None] * (x[:, None] - y[None])
        iy = np.clip(np.round((q[..., 1] - lo[1]) / cell).astype(int), 0, shape[0] - 1)
        iz = np.clip(np.round((q[..., 2] - lo[2]) / cell).astype(int), 0, shape[1] - 1)
        visible &= ~(cross & covered[iy, iz])
    return visible


@pytest.mark.parametrize("camera, seed", [("far", 0), ("main", 3)])
def test_defaults_match_exact_visibility_on_rooms(gl_ctx, rooms, camera, seed):
    """At the defaults, on the three rooms, the method's indirect equals the same VPLs summed with
    exact visibility (walls rasterised independently of the topology), in the camera's room and
    in the room seen through the door. Before, room 3 seen from 'far' got 0.69x the exact light
    and room 2 through its door 1.32x (4096 VPLs): VPLs beside a door in the next room's cluster
    lit it unshadowed, and one gate hop lost the light crossing both doors; the gates' ellipses
    lit hard elliptical patches where the reference's are door-shaped."""
    frame = render_frame(gl_ctx, rooms, {}, seed=seed, camera=camera)
    gb, v = frame["gbuffer"], frame["vpls"]
    x = gb["position"].reshape(-1, 3)[gb["mask"].ravel()].astype(np.float64)
    lit = np.any(v["flux"] != 0, axis=1)
    expected = vpl_sum(frame, rooms_exact_visibility(rooms, v["position"][lit], x))
    got = frame["indirect"]
    px = gb["position"][..., 0]
    for name, region in (("x < 4", px < 4.0), ("4 < x < 8", (px > 4.0) & (px < 8.0)), ("x > 8", px > 8.0)):
        region &= gb["mask"]
        if expected[region].sum() > 0.02 * expected.sum():
            ratio = got[region].sum() / expected[region].sum()
            assert abs(ratio - 1) < 0.03, f"{camera}, {name}: {ratio:.3f} x the exact visibility's light"
    bad = np.abs(got - expected).max(axis=2) > 0.05 * expected.max()
    assert bad.mean() < 0.02, f"{camera}: {bad.sum()} of {bad.size} pixels off the exact visibility"


def test_quality_ladder():
    """3-5 rungs, valid parameters, fast -> accurate by VPL count, the defaults among them."""
    ladder = VisibilityGates.ladder
    assert 3 <= len(ladder) <= 5 and {} in [dict(r) for r in ladder]
    counts = [resolve_params(VisibilityGates, dict(r))["vpl_count"] for r in ladder]
    assert counts == sorted(counts) and len(set(counts)) == len(counts)


def test_a_word_of_vpls_split_over_draws_sums_the_same(gl_ctx, rooms):
    """llvmpipe's loop limit: with many gate hops (16: 561 loop iterations per VPL on rooms) a
    word of 32 VPLs is summed over several draws, each a range of its bits; on rooms (at most two
    gates on any path) that gives the image of 4 hops, whose draws take whole words."""
    from bench.run.harness import run_method
    params = {"vpl_count": 96}
    split = run_method(gl_ctx, VisibilityGates, rooms, "far", 64, 48, dict(params, gate_hops=16), seed=4, frames=1)
    whole = run_method(gl_ctx, VisibilityGates, rooms, "far", 64, 48, dict(params, gate_hops=4), seed=4, frames=1)
    assert whole.indirect.max() > 0
    np.testing.assert_allclose(split.indirect, whole.indirect, rtol=1e-5, atol=1e-6 * whole.indirect.max())


def _square_gate_set(centre, half, pairs):
    """GateSet of axis-aligned squares in planes x = const (normal +x), `half` their half-side."""
    from methods.visibility_gates.gates import MAX_GATE_EDGES, GateSet
    g = len(centre)
    hp = np.zeros((g, MAX_GATE_EDGES, 3))
    hp[:, :4] = [(1, 0, half), (-1, 0, half), (0, 1, half), (0, -1, half)]
    return GateSet(centre=np.asarray(centre, float), normal=np.tile([1.0, 0, 0], (g, 1)),
                   axis_u=np.tile([0, 1.0, 0], (g, 1)), halfplanes=hp, count=np.full(g, 4),
                   radius=np.full(g, half * np.sqrt(2)), area=np.full(g, 4 * half * half),
                   pairs=np.asarray(pairs, np.int64), sides=np.asarray(pairs, np.int64))


def test_border_gates_cover_the_openings_no_skeleton_gate_covers():
    """Two clusters meet through two holes in a wall (a row of arches); the skeleton's gate is
    one hole's. The light through the other hole needs a gate of its own (border_gates), in the
    wall's plane over that hole, and none is added when the gates cover both holes."""
    from methods.visibility_gates.gates import border_gates
    empty = np.ones((12, 10, 8), bool)
    empty[6] = False
    empty[6, 1:3, 2:6] = True   # hole 1: y 1..2, z 2..5
    empty[6, 6:9, 2:6] = True   # hole 2: y 6..8
    grid = np.where(np.arange(12)[:, None, None] < 6, 0, 1) * np.ones((1, 10, 8), np.int32)
    origin, pitch = np.zeros(3), 1.0
    one = _square_gate_set([(6.0, 2.0, 4.0)], 2.0, [(0, 1)])
    out = border_gates(grid, empty, origin, pitch, one)
    assert len(out.radius) == 2 and tuple(out.pairs[1]) == (0, 1) and tuple(out.sides[1]) == (0, 1)
    assert abs(abs(out.normal[1] @ [1.0, 0, 0]) - 1) < 1e-9 and abs(out.centre[1, 0] - 6.0) < 1e-9
    # a segment through hole 2 crosses the new gate's polygon, one through the wall beside it does not
    c, u, v = out.centre[1], out.axis_u[1], out.axis_v[1]
    hp = out.halfplanes[1, :out.count[1]]
    inside = lambda p: bool(np.all(hp[:, :2] @ [(p - c) @ u, (p - c) @ v] <= hp[:, 2] + 1e-9))
    assert inside(np.array([6.0, 7.5, 4.0])) and not inside(np.array([6.0, 4.5, 4.0]))
    assert abs(out.area[1] / (3 * 4) - 1) < 1e-6  # the hole's 3 x 4 voxel faces
    both = _square_gate_set([(6.0, 2.0, 4.0), (6.0, 7.5, 4.0)], 2.0, [(0, 1), (0, 1)])
    assert len(border_gates(grid, empty, origin, pitch, both).radius) == 2

