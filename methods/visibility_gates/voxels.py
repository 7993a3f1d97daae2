"""Visibility Gates precomputation, step 1 (topology.py runs every step): exact point-to-scene
distances and the binary voxelization of the empty space light travels in.

1. `voxelize`: by default ("sphere") a voxel is occupied when its centre is within sqrt(3)/2
   voxel of a triangle (exact distances, `SurfaceIndex`); with occupancy "touch" when its closed
   cube intersects a triangle (`touched_voxels`, Akenine-Moller's separating-axis test, a
   thinner shell). Under both the 26-connected empty space never passes through a surface. The empty space is every component of empty voxels not reaching the grid's border,
   plus, for open scenes, the component around the geometry holding a camera eye or positional
   light, closed by the bounding box enlarged by PAD voxels.
`SurfaceIndex` also measures the skeleton nodes' maximal balls and the gates' openings.
"""
from __future__ import annotations

import numpy as np
import trimesh
from scipy import ndimage
from scipy.spatial import cKDTree

OCCUPIED_DISTANCE = 0.5 * np.sqrt(3.0)  # voxels: centre-to-triangle distance of an occupied voxel (sphere)
PAD = 2  # voxels between the scene's bounding box and the grid border (the closing box)
OCCUPANCIES = ("touch", "sphere")  # voxelize's rules: the closed cube meets a triangle; its circumscribed ball does
DEFAULT_OCCUPANCY = "sphere"
SAT_TOLERANCE = 1e-9  # relative slack of the separating-axis test: a cube grazing a triangle counts as touching
PAIR_CHUNK = 2_000_000  # candidate (voxel, triangle) pairs tested at once


def triangle_box_overlap(tri: np.ndarray, centre: np.ndarray, half: float = 0.5) -> np.ndarray:
    """Does each closed axis-aligned cube (centre (N, 3), half edge `half`) intersect its triangle
    (N, 3, 3)? Akenine-Moller's separating-axis test, vectorised: the cube's three axes, the
    triangle's normal and the nine cross products of its edges with the cube's axes; the two are
    disjoint iff their projections on one of these 13 axes are disjoint. Touching counts as
    overlapping (closed sets, SAT_TOLERANCE of slack). A degenerate triangle (segment, point)
    is tested exactly too: its zero axes separate nothing, the remaining ones are a segment's
    or a point's own."""
    v = np.asarray(tri, float) - np.asarray(centre, float)[:, None, :]
    slack = 1.0 + SAT_TOLERANCE
    apart = np.any(v.min(axis=1) > half * slack, axis=1) | np.any(v.max(axis=1) < -half * slack, axis=1)
    e = np.stack([v[:, 1] - v[:, 0], v[:, 2] - v[:, 1], v[:, 0] - v[:, 2]], axis=1)  # (N, 3 edges, 3)
    n = np.cross(e[:, 0], e[:, 1])
    r = half * np.abs(n).sum(axis=1)
    apart |= np.abs(np.einsum("nc,nc->n", n, v[:, 0])) > r * slack
    for j in range(3):  # edge x cube axis j: (0, -e_z, e_y), (e_z, 0, -e_x), (-e_y, e_x, 0)
        a = np.zeros_like(e)
        k1, k2 = (j + 1) % 3, (j + 2) % 3
        a[..., k1] = e[..., k2]
        a[..., k2] = -e[..., k1]
        p = np.einsum("nec,nvc->nev", a, v)  # (N, 3 axes, 3 vertices)
        r = half * np.abs(a).sum(axis=2)
        apart |= np.any((p.min(axis=2) > r * slack) | (p.max(axis=2) < -r * slack), axis=1)
    return ~apart


def touched_voxels(vertices: np.ndarray, faces: np.ndarray, origin: np.ndarray, pitch: float, dims) -> np.ndarray:
    """Conservative voxelization: the voxels whose closed cube intersects a triangle (exact,
    `triangle_box_overlap`), as a bool grid of shape `dims`. Candidates: every voxel of each
    triangle's closed bounding box, tested in chunks of PAIR_CHUNK pairs."""
    dims = np.asarray(dims, np.int64)
    tri = (np.asarray(vertices, float)[np.asarray(faces)] - origin) / pitch  # voxel units
    # closed cube i spans [i, i + 1]: it meets [a, b] iff a - 1 <= i <= b (a hair wider: the test decides)
    lo = np.clip(np.ceil(tri.min(axis=1) - 1.0 - 1e-6).astype(np.int64), 0, dims - 1)
    hi = np.clip(np.floor(tri.max(axis=1) + 1e-6).astype(np.int64), 0, dims - 1)
    lo = np.minimum(lo, hi)
    extent = hi - lo + 1
    counts = extent.prod(axis=1)
    occupied = np.zeros(tuple(dims), dtype=bool)
    ends = np.cumsum(counts)
    start = 0
    while start < len(tri):
        # triangles [start, stop) hold at most PAIR_CHUNK pairs (at least one triangle)
        base = ends[start - 1] if start else 0
        stop = max(int(np.searchsorted(ends, base + PAIR_CHUNK, side="right")), start + 1)
        t = np.repeat(np.arange(start, stop), counts[start:stop])
        k = np.arange(len(t)) - np.repeat(ends[start:stop] - counts[start:stop] - base, counts[start:stop])
        ex = extent[t]
        idx = lo[t] + np.stack([k // (ex[:, 1] * ex[:, 2]), (k // ex[:, 2]) % ex[:, 1], k % ex[:, 2]], axis=1)
        hit = triangle_box_overlap(tri[t], idx + 0.5)
        occupied[tuple(idx[hit].T)] = True
        start = stop
    return occupied


def surface_samples(vertices: np.ndarray, faces: np.ndarray, spacing: float):
    """Points on every triangle: a barycentric lattice whose sub-triangles have edges <= spacing,
    so every point of a triangle is within `spacing` of one of its samples. (points (P, 3), the
    triangle of each point (P,))."""
    tri = vertices[faces]
    longest = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
    steps = np.maximum(np.ceil(longest / spacing), 1).astype(np.int64)
    points, owner = [], []
    for k in np.unique(steps):
        i, j = np.indices((k + 1, k + 1)).reshape(2, -1)
        keep = i + j <= k
        u, v = i[keep] / k, j[keep] / k
        sel = np.flatnonzero(steps == k)
        for part in np.array_split(sel, max(1, len(sel) * len(u) // 2_000_000)):
            t = tri[part]
            p = t[:, None, 0] + u[None, :, None] * (t[:, None, 1] - t[:, None, 0]) + \
                v[None, :, None] * (t[:, None, 2] - t[:, None, 0])
            points.append(p.reshape(-1, 3))
            owner.append(np.repeat(part, len(u)))
    return np.concatenate(points), np.concatenate(owner)


class SurfaceIndex:
    """Exact point-to-scene distances. Candidates come from a k-d tree of surface samples at most
    `spacing` from every point of their triangle: with d0 the distance to the nearest sample, the
    nearest triangle has a sample within d0 + spacing, so testing the triangles of every sample in
    that ball (trimesh's exact point-triangle distance) gives the true minimum."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, spacing: float):
        self.vertices, self.faces, self.spacing = vertices, faces, float(spacing)
        self.points, self.owner = surface_samples(vertices, faces, spacing)
        self.tree = cKDTree(self.points, balanced_tree=False, compact_nodes=False)

    def distance(self, query: np.ndarray) -> np.ndarray:
        """Exact distance of each query point to the nearest triangle."""
        query = np.asarray(query, float).reshape(-1, 3)
        d0, _ = self.tree.query(query)
        best = d0.copy()
        hits = self.tree.query_ball_point(query, d0 + self.spacing)
        counts = np.fromiter((len(h) for h in hits), np.int64, len(hits))
        q = np.repeat(np.arange(len(query)), counts)
        f = self.owner[np.concatenate(hits).astype(np.int64)]
        pairs = np.unique(q * len(self.faces) + f)
        q, f = pairs // len(self.faces), pairs % len(self.faces)
        for part in np.array_split(np.arange(len(q)), max(1, len(q) // 1_000_000)):
            closest = trimesh.triangles.closest_point(self.vertices[self.faces[f[part]]], query[q[part]])
            np.minimum.at(best, q[part], np.linalg.norm(closest - query[q[part]], axis=1))
        return best

    def near(self, query: np.ndarray, threshold: float) -> np.ndarray:
        """Is each query point within `threshold` of a triangle (exact)? The nearest sample
        decides unless it lies in (threshold, threshold + spacing]; only those get `distance`."""
        query = np.asarray(query, float).reshape(-1, 3)
        d0, _ = self.tree.query(query, distance_upper_bound=threshold + self.spacing)
        out = d0 <= threshold
        unsure = np.flatnonzero(~out & np.isfinite(d0))
        if len(unsure):
            out[unsure] = self.distance(query[unsure]) <= threshold
        return out


def voxelize(vertices: np.ndarray, faces: np.ndarray, resolution: int, seeds=(), occupancy: str = DEFAULT_OCCUPANCY):
    """Binary voxelization and the empty space light travels in.

    occupancy "touch": a voxel is occupied when its closed cube intersects a triangle
    (`touched_voxels`, the conservative voxelization: the paper's voxels touching a surface).
    The segment between the centres of two 26-adjacent voxels lies in the union of their two
    closed cubes (each coordinate moves by 0 or 1 voxel: up to its middle it stays in the
    first cube, from there in the second), so a triangle crossing it meets one of them, which is
    occupied: the 26-connected empty space never passes through a surface. A touched voxel's
    centre is within sqrt(3)/2 voxel of the triangle, so this shell is a subset of "sphere"'s.
    occupancy "sphere": a voxel is occupied when its centre is within sqrt(3)/2 voxel of a triangle (exact distance,
    OCCUPIED_DISTANCE), a ball circumscribing the cube: the segment between the centres of two 26-adjacent voxels that crosses a
    triangle has one end within sqrt(3)/2 voxel of the crossing, so the 26-connected empty space
    (the connectivity of scikit-image's thinning) never passes through a surface, however it is
    tilted. Sampling the triangles instead, as before, let the skeleton leak through tilted
    walls into the closed blocks of a Cornell box. The grid spans the scene's bounding box
    enlarged by PAD voxels on every side; its outermost voxel layer is a wall (the closing box).
    The empty space is every 26-connected component of empty voxels that does not reach that
    layer (enclosed rooms) plus, for open scenes, the component around the geometry when a seed
    (camera eye, positional light) lies in it: an open roof or an open floor is then closed by
    the enlarged bounding box. Returns (occupied, empty, origin, pitch, closed_by_box, the
    SurfaceIndex used: samples half a voxel apart)."""
    lo, hi = vertices.min(0), vertices.max(0)
    pitch = float((hi - lo).max()) / int(resolution)
    origin = lo - PAD * pitch
    dims = np.ceil((hi - origin) / pitch).astype(np.int64) + PAD
    if occupancy not in OCCUPANCIES:
        raise ValueError(f"voxelize: occupancy '{occupancy}' is not one of {', '.join(OCCUPANCIES)}")
    surface = SurfaceIndex(vertices, faces, 0.5 * pitch)
    if occupancy == "touch":
        occupied = touched_voxels(vertices, faces, origin, pitch, dims)
    else:
        occupied = sphere_voxels(surface, origin, pitch, dims)
    return empty_space(occupied, origin, pitch, seeds) + (surface,)


def sphere_voxels(surface: SurfaceIndex, origin: np.ndarray, pitch: float, dims) -> np.ndarray:
    """The voxels whose centre is within OCCUPIED_DISTANCE voxel of a triangle (exact distance)."""
    dims = np.asarray(dims, np.int64)
    idx = np.clip(np.floor((surface.points - origin) / pitch).astype(np.int64), 0, dims - 1)
    near = np.zeros(tuple(dims), dtype=bool)
    near[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    # a centre within OCCUPIED_DISTANCE + 0.5 (< 1.5) voxels of a sample is in a voxel next to the sample's
    band = np.argwhere(ndimage.binary_dilation(near, structure=np.ones((3, 3, 3), bool)))
    occupied = np.zeros(tuple(dims), dtype=bool)
    occupied[tuple(band[surface.near(origin + (band + 0.5) * pitch, OCCUPIED_DISTANCE * pitch)].T)] = True
    return occupied


def empty_space(occupied: np.ndarray, origin: np.ndarray, pitch: float, seeds=()):
    """The enclosed 26-connected components of ~occupied, plus the open one holding a seed
    (closed by the grid's outermost layer). Returns (occupied, empty, origin, pitch, closed_by_box)."""
    dims = np.asarray(occupied.shape)
    labels, _ = ndimage.label(~occupied, structure=np.ones((3, 3, 3), bool))
    border = np.unique(np.concatenate([labels[[0, -1]].ravel(), labels[:, [0, -1]].ravel(),
                                       labels[:, :, [0, -1]].ravel()]))
    border = border[border > 0]
    empty = (labels > 0) & ~np.isin(labels, border)
    seeds = np.asarray(seeds, float).reshape(-1, 3)
    seed_idx = np.floor((seeds - origin) / pitch).astype(np.int64)
    inside = np.all((seed_idx >= 1) & (seed_idx < dims - 1), axis=1)
    outside = np.intersect1d(border, labels[tuple(seed_idx[inside].T)])
    closed_by_box = len(outside) > 0
    if closed_by_box:
        empty |= np.isin(labels, outside)
        for axis in range(3):  # the closing box: the grid's outermost layer
            empty[(slice(None),) * axis + (0,)] = False
            empty[(slice(None),) * axis + (-1,)] = False
    return occupied, empty, origin, pitch, closed_by_box

