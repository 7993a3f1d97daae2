"""visibility_gates voxelization: the exact cube-triangle overlap of occupancy=touch (checked against
linear programming), its shell inside sphere's, the 26-connected empty space never crossing a
tilted thin wall under either rule, and the parameter's plumbing."""
import numpy as np
import pytest
import trimesh
from scipy import ndimage
from scipy.optimize import linprog

from bench.model.corpus import load_scene
from bench.protocol.method import ParamError, resolve_params
from bench.run.harness import run_method
from methods.visibility_gates.method import VisibilityGates, scene_topology
from methods.visibility_gates.voxels import (OCCUPANCIES, OCCUPIED_DISTANCE, SurfaceIndex, triangle_box_overlap,
                                             voxelize)

CUBE26 = np.ones((3, 3, 3), bool)


def lp_overlap(tri: np.ndarray, centre: np.ndarray, half: float = 0.5) -> bool:
    """Exact reference: barycentric weights w >= 0, sum 1, with |sum_k w_k v_k - centre| <= half."""
    v = tri - centre
    res = linprog(np.zeros(3), A_ub=np.vstack([v.T, -v.T]), b_ub=np.full(6, half),
                  A_eq=np.ones((1, 3)), b_eq=[1.0], bounds=[(0, None)] * 3, method="highs")
    return res.status == 0


def test_triangle_box_overlap_matches_linear_programming():
    rng = np.random.default_rng(7)
    n = 700
    tri = rng.uniform(-1.5, 1.5, (n, 3, 3)) * rng.uniform(0.05, 1.0, (n, 1, 1)) + rng.uniform(-1.0, 1.0, (n, 1, 3))
    tri[:100, 2] = tri[:100, 1]                                       # segments
    tri[100:150, 1:] = tri[100:150, :1]                               # points
    centre = np.zeros((n, 3))
    got = triangle_box_overlap(tri, centre)
    ref = np.array([lp_overlap(t, c) for t, c in zip(tri, centre)])
    assert 0.2 < ref.mean() < 0.8
    assert np.array_equal(got, ref), f"{(got != ref).sum()} of {n} disagree with the LP"


def test_triangle_box_overlap_is_closed():
    """A triangle in the plane of a face touches the cube; a hair beyond it does not."""
    flat = np.array([[[-3.0, -3.0, 0.0], [3.0, -3.0, 0.0], [0.0, 3.0, 0.0]]])
    for z, expected in ((0.5, True), (-0.5, True), (0.5 + 1e-6, False), (-0.5 - 1e-6, False)):
        assert triangle_box_overlap(flat + [0, 0, z], np.zeros((1, 3)))[0] == expected, z
    # an edge grazing the cube's edge (x + y = 1 through the corner (0.5, 0.5))
    graze = np.array([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [2.0, 2.0, 0.0]]])
    assert triangle_box_overlap(graze, np.zeros((1, 3)))[0]
    assert not triangle_box_overlap(graze + [1e-6, 1e-6, 0.0], np.zeros((1, 3)))[0]


def tilted_box_scene(seed: int):
    rng = np.random.default_rng(seed)
    block = trimesh.creation.box(extents=rng.uniform(0.4, 1.2, 3))
    block.apply_transform(trimesh.transformations.euler_matrix(*rng.uniform(0, np.pi, 3)))
    room = trimesh.creation.box(extents=(3.0, 3.0, 3.0))
    return (np.concatenate([room.vertices, block.vertices]),
            np.concatenate([room.faces, block.faces + len(room.vertices)]))


def test_touch_shell_is_the_cubes_meeting_a_triangle_inside_sphere_shell():
    """Every touched voxel's centre is within sqrt(3)/2 voxel of a triangle (touch within sphere);
    every voxel holding a surface point is touched; the voxels of sphere's shell that touch
    leaves empty meet no triangle (LP, all triangles)."""
    verts, faces = tilted_box_scene(3)
    occ_touch, _, origin, pitch, _, surface = voxelize(verts, faces, 20, occupancy="touch")
    occ_sphere, *_ = voxelize(verts, faces, 20, occupancy="sphere")
    # within sphere's shell but for cubes touching only at a corner (centre exactly sqrt(3)/2 away)
    centres = origin + (np.argwhere(occ_touch) + 0.5) * pitch
    assert surface.distance(centres).max() <= OCCUPIED_DISTANCE * pitch * (1 + 1e-9)
    corner = origin + (np.argwhere(occ_touch & ~occ_sphere) + 0.5) * pitch
    assert np.allclose(surface.distance(corner), OCCUPIED_DISTANCE * pitch, rtol=1e-9)
    assert occ_touch.sum() < occ_sphere.sum()
    fine = SurfaceIndex(verts, faces, 0.1 * pitch).points
    idx = np.floor((fine - origin) / pitch).astype(int)
    inside_cell = np.all(np.abs((fine - origin) / pitch - idx - 0.5) < 0.5 - 1e-6, axis=1)  # not on a cube's face
    assert occ_touch[tuple(idx[inside_cell].T)].all()
    thinner = np.argwhere(occ_sphere & ~occ_touch)
    assert len(thinner) > 20
    tri = (verts[faces] - origin) / pitch
    for v in np.random.default_rng(0).permutation(thinner)[:60]:
        assert not any(lp_overlap(t, v + 0.5) for t in tri), f"voxel {v} meets a triangle"


@pytest.mark.parametrize("occupancy", OCCUPANCIES)
def test_tilted_walls_and_blocks_never_leak(occupancy):
    """Property: a closed block at random orientations, and a zero-thickness tilted wall
    splitting a room, keep their sides 26-disconnected at several resolutions."""
    for seed in range(4):
        verts, faces = tilted_box_scene(seed)
        for res in (17, 31):
            _, empty, *_ = voxelize(verts, faces, res, occupancy=occupancy)
            count = ndimage.label(empty, structure=CUBE26)[1]
            assert count == 2, f"seed {seed} res {res}: {count} components"
    rng = np.random.default_rng(11)
    room = trimesh.creation.box(extents=(3.0, 3.0, 3.0))
    for trial in range(6):
        wall = trimesh.creation.box(extents=(6.0, 6.0, 0.0))   # zero thickness: two coincident faces
        angles = rng.uniform(-0.6, 0.6, 3)
        wall.apply_transform(trimesh.transformations.euler_matrix(*angles))
        wall.apply_translation(rng.uniform(-0.3, 0.3, 3))
        # the wall's square is clipped to the room by the room's own walls: it reaches past them
        verts = np.concatenate([room.vertices, wall.vertices])
        faces = np.concatenate([room.faces, wall.faces + len(room.vertices)])
        for res in (19, 29):
            _, empty, origin, pitch, _, _ = voxelize(verts, faces, res, occupancy=occupancy)
            labels, _ = ndimage.label(empty, structure=CUBE26)
            centres = origin + (np.argwhere(empty) + 0.5) * pitch
            n = trimesh.transformations.euler_matrix(*angles)[:3, 2]
            side = (centres - wall.centroid) @ n > 0
            lab = labels[empty]
            assert not np.intersect1d(lab[side], lab[~side]).size, f"trial {trial} res {res}: leak through the wall"


def test_touch_leaves_a_voxel_beside_a_thin_wall_empty():
    """A voxel whose centre is 0.7 voxel from a thin wall: inside sphere's ball (0.866), its cube
    (half edge 0.5) does not meet the wall: occupied by sphere only."""
    room = trimesh.creation.box(extents=(10.0, 10.0, 10.0))
    room.apply_translation((5.0, 5.0, 5.0))                      # [0, 10]^3, pitch 1 at resolution 10
    wall = trimesh.creation.box(extents=(0.0, 6.0, 6.0))
    wall.apply_translation((4.2, 5.0, 5.0))
    verts = np.concatenate([room.vertices, wall.vertices])
    faces = np.concatenate([room.faces, wall.faces + len(room.vertices)])
    grids = {occ: voxelize(verts, faces, 10, occupancy=occ) for occ in OCCUPANCIES}
    origin, pitch = grids["touch"][2], grids["touch"][3]
    assert np.isclose(pitch, 1.0)
    beside = tuple(np.floor((np.array([3.5, 5.5, 5.5]) - origin) / pitch).astype(int))   # centre x 3.5: 0.7 off
    on = tuple(np.floor((np.array([4.5, 5.5, 5.5]) - origin) / pitch).astype(int))       # centre x 4.5: cube meets it
    assert grids["sphere"][0][beside] and not grids["touch"][0][beside]
    assert grids["touch"][1][beside]
    assert grids["touch"][0][on] and grids["sphere"][0][on]


def test_occupancy_parameter():
    with pytest.raises(ValueError, match="occupancy 'cube'"):
        voxelize(np.eye(3), np.array([[0, 1, 2]]), 8, occupancy="cube")
    with pytest.raises(ParamError):
        resolve_params(VisibilityGates, {"occupancy": "cube"})
    assert resolve_params(VisibilityGates, {})["occupancy"] in OCCUPANCIES


def test_touch_topology_renders(gl_ctx):
    """Both rules build rooms' topology (cached apart) and render finite, non-negative light."""
    rooms = load_scene("rooms")
    d = resolve_params(VisibilityGates, {})
    args = (d["voxel_resolution"], d["alpha_percent"], d["merge_gate_fraction"], d["merge_visible_fraction"], False)
    touch, _ = scene_topology(rooms, *args, occupancy="touch")
    sphere, _ = scene_topology(rooms, *args, occupancy="sphere")
    assert touch is not sphere and touch.empty_voxels > sphere.empty_voxels
    res = run_method(gl_ctx, VisibilityGates, rooms, "main", 64, 48, {"vpl_count": 128, "occupancy": "touch"},
                     seed=0, frames=1)
    assert np.isfinite(res.indirect).all() and res.indirect.min() >= 0 and res.indirect.mean() > 0
