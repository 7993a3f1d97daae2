"""Visibility Gates precomputation (paper section IV), on the CPU with numpy / scipy / scikit-image:

1. `voxelize`: binary surface voxelization of the scene (trimesh subdivides every triangle to
   edges below a quarter voxel; each vertex marks its voxel), then the *enclosed* empty space:
   the 6-connected components of the empty voxels that do not touch the (padded) grid border.
2. `skeletonize`: curvilinear skeleton of the enclosed empty space (scikit-image's 3-D thinning,
   Lee et al. 1994: topology preserving and centred, like the paper's cubical-complex thinning
   [20]); the radius of each node's maximal ball comes from the Euclidean distance transform.
   The skeleton voxels become a graph (26-adjacency, minus the long side of every voxel
   triangle, so a voxel staircase is a line and not a chain of spurious junctions), then
   `prune_spurs` removes the terminal branches their junction sees in a straight line (the
   spurs an end-point-preserving thinning grows towards convex corners and edges).
3. `segment`: topology nodes (degree != 2), then curvature nodes (curv = dist(n, L1 Lk) /
   maxball(n) > 1, the most curved node first, recursively), then coverage nodes (a node in no
   maximal ball of its line's extrema, recursively); unclassified nodes are dropped and each
   is associated with the nearest extremum (arc length) of its line.
4. `cluster`: the paper's greedy visibility clusters (largest ball first, neighbours that are
   not curvature nodes and whose radius differs from the popped node's by at most alpha % of the
   cluster's largest, plus every node reachable inside the popped node's maximal ball).
5. `gates`: one disk per segmented edge joining two clusters: centre at the middle of the edge,
   normal along it, radius min(maxball(n1), maxball(n2)).
6. `cluster_grid`: each enclosed empty voxel gets the cluster of its geodesically nearest
   skeleton node (multi-source shortest paths through the empty space, scipy.sparse.csgraph);
   every other voxel (surfaces, outside) the cluster of its nearest enclosed empty voxel, so a
   surface point looked up one voxel off its surface along its normal finds its room.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import trimesh
from scipy import ndimage, sparse
from scipy.sparse.csgraph import connected_components, dijkstra
from skimage.morphology import skeletonize

KIND_UNCLASSIFIED, KIND_TOPOLOGY, KIND_CURVATURE, KIND_COVERAGE = 0, 1, 2, 3

# 13 half-neighbourhood offsets of the 26-neighbourhood (each undirected voxel pair once).
_HALF_OFFSETS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)
                          if (i, j, k) > (0, 0, 0)])


class TopologyError(ValueError):
    """The scene has no enclosed empty space the method can build its topology in."""


@dataclass
class Topology:
    origin: np.ndarray          # world position of voxel (0, 0, 0)'s corner
    pitch: float                # voxel edge (m)
    dims: tuple                 # grid size (x, y, z)
    cluster_grid: np.ndarray    # int32 (x, y, z): visibility cluster of every voxel
    node_position: np.ndarray   # (S, 3) world positions of the skeleton nodes
    node_radius: np.ndarray     # (S,) maximal-ball radius (m)
    node_kind: np.ndarray       # (S,) KIND_* of each node after segmentation
    node_segment: np.ndarray    # (S,) segmented node (skeleton index) each node is associated with
    node_cluster: np.ndarray    # (S,) visibility cluster of each node
    segmented_edges: np.ndarray  # (E, 2) skeleton indices of the segmented skeleton's edges
    cluster_count: int
    gate_centre: np.ndarray     # (G, 3) world
    gate_normal: np.ndarray     # (G, 3) unit, from gate_clusters[:, 0]'s side to [:, 1]'s
    gate_radius: np.ndarray     # (G,)
    gate_clusters: np.ndarray   # (G, 2) the two clusters each gate separates
    enclosed_voxels: int
    timings_s: dict = field(default_factory=dict)

    def cluster_of(self, points: np.ndarray) -> np.ndarray:
        """Visibility cluster of world points (nearest voxel, clamped to the grid)."""
        idx = np.floor((np.asarray(points, float) - self.origin) / self.pitch).astype(np.int64)
        idx = np.clip(idx, 0, np.asarray(self.dims) - 1)
        return self.cluster_grid[idx[:, 0], idx[:, 1], idx[:, 2]]


# ----------------------------------------------------------------------------- 1. voxelization
def voxelize(vertices: np.ndarray, faces: np.ndarray, resolution: int):
    """(occupied bool grid, enclosed-empty bool grid, origin, pitch). Grid padded by 2 voxels."""
    lo, hi = vertices.min(0), vertices.max(0)
    extent = hi - lo
    pitch = float(extent.max()) / int(resolution)
    origin = lo - 2.0 * pitch
    dims = np.ceil((hi - origin) / pitch).astype(np.int64) + 2
    sub_v, _ = trimesh.remesh.subdivide_to_size(vertices, faces, max_edge=0.25 * pitch, max_iter=64)
    idx = np.clip(np.floor((sub_v - origin) / pitch).astype(np.int64), 0, dims - 1)
    occupied = np.zeros(tuple(dims), dtype=bool)
    occupied[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    labels, _ = ndimage.label(~occupied)  # 6-connectivity: a 26-connected surface layer blocks it
    border = np.unique(np.concatenate([labels[[0, -1]].ravel(), labels[:, [0, -1]].ravel(),
                                       labels[:, :, [0, -1]].ravel()]))
    enclosed = (labels > 0) & ~np.isin(labels, border)
    return occupied, enclosed, origin, pitch


# ----------------------------------------------------------------------------- 2. skeleton graph
def skeleton_graph(enclosed: np.ndarray):
    """Skeleton voxel coordinates (S, 3) and their adjacency (CSR, symmetric, 0/1)."""
    skel = skeletonize(enclosed) > 0
    labels, count = ndimage.label(enclosed)
    has = np.zeros(count + 1, bool)
    has[np.unique(labels[skel])] = True
    for comp in np.flatnonzero(~has[1:]) + 1:  # a component thinned to nothing keeps its deepest voxel
        dist = ndimage.distance_transform_edt(labels == comp)
        skel[np.unravel_index(int(np.argmax(dist)), dist.shape)] = True
    coords = np.argwhere(skel)
    index = -np.ones(enclosed.shape, np.int64)
    index[tuple(coords.T)] = np.arange(len(coords))
    rows, cols, lens = [], [], []
    for off in _HALF_OFFSETS:
        nb = coords + off
        ok = np.all((nb >= 0) & (nb < np.asarray(enclosed.shape)), axis=1)
        j = -np.ones(len(coords), np.int64)
        j[ok] = index[tuple(nb[ok].T)]
        m = j >= 0
        rows.append(np.flatnonzero(m)); cols.append(j[m]); lens.append(np.full(m.sum(), int(np.abs(off).sum())))
    r, c, l = np.concatenate(rows), np.concatenate(cols), np.concatenate(lens)
    n = len(coords)

    def adj(mask):
        a = sparse.coo_matrix((np.ones(mask.sum()), (r[mask], c[mask])), shape=(n, n)).tocsr()
        return ((a + a.T) > 0).astype(np.int32)

    # drop the longest side of each voxel triangle: a diagonal step beside two axis steps
    def has_path(two_step, mask):
        coo = sparse.coo_matrix(two_step)
        return np.isin(r[mask] * n + c[mask], coo.row.astype(np.int64) * n + coo.col)

    a1, a2 = adj(l == 1), adj(l == 2)
    keep = np.ones(len(r), bool)
    keep[l == 2] = ~has_path(a1 @ a1, l == 2)
    keep[l == 3] = ~has_path((a1 + a2) @ (a1 + a2), l == 3)
    graph = adj(keep)
    return coords, graph


def _segment_in_space(space: np.ndarray, a: np.ndarray, b: np.ndarray) -> bool:
    """Does the straight segment between voxel centres a and b stay inside `space` (sampled at
    a quarter voxel)?"""
    steps = max(int(np.ceil(4.0 * np.abs(b - a).max())), 1)
    t = np.linspace(0.0, 1.0, steps + 1)[:, None]
    v = np.floor(a + t * (b - a) + 0.5).astype(np.int64)
    return bool(space[tuple(v.T)].all())


def prune_spurs(coords: np.ndarray, graph, space: np.ndarray):
    """Skeleton simplification before segmentation: drop every terminal branch (an end node up
    to, excluding, the first node of degree >= 3) all of whose nodes the junction sees in a
    straight line through the empty space. Such a branch bounds no region hidden from the rest
    of the skeleton (a convex corner or edge of a room, a straight dead end): it is the spur a
    voxel thinning that preserves end points grows towards every convex corner, which a
    filtered curvilinear skeleton does not have. One pass over the original branches only, so a
    room behind a door (whose own skeleton has junctions) is never pruned away.
    Returns (coords, graph) of the kept nodes."""
    nbrs = _neighbours(graph)
    degree = np.diff(graph.indptr)
    keep = np.ones(len(coords), bool)
    for tip in np.flatnonzero(degree == 1):
        branch, prev, cur = [int(tip)], -1, int(tip)
        while True:
            nxt = [int(x) for x in nbrs[cur] if x != prev]
            if len(nxt) != 1:
                break
            prev, cur = cur, nxt[0]
            if degree[cur] != 2:
                break
            branch.append(cur)
        if degree[cur] < 3:  # an isolated path (two end nodes, no junction): nothing to prune into
            continue
        if all(_segment_in_space(space, coords[cur].astype(float), coords[b].astype(float)) for b in branch):
            keep[branch] = False
    sub = graph[keep][:, keep].tocsr()
    return coords[keep], sub


# ----------------------------------------------------------------------------- 3. segmentation
def _neighbours(graph) -> list:
    return [graph.indices[graph.indptr[i]:graph.indptr[i + 1]] for i in range(graph.shape[0])]


def trace_lines(nbrs: list, kind: np.ndarray) -> list:
    """Maximal lines between topology nodes: lists [L1, n2, .., Lk] (L1, Lk topology nodes)."""
    lines, seen = [], set()
    for start in np.flatnonzero(kind == KIND_TOPOLOGY):
        for first in nbrs[start]:
            if (start, first) in seen:
                continue
            line, prev, cur = [int(start)], int(start), int(first)
            while True:
                line.append(cur)
                if kind[cur] == KIND_TOPOLOGY:
                    break
                nxt = [x for x in nbrs[cur] if x != prev]
                prev, cur = cur, int(nxt[0])
            seen.add((line[0], line[1]))
            seen.add((line[-1], line[-2]))
            lines.append(line)
    return lines


def _point_line_distance(p, a, b):
    d = b - a
    dd = float(d @ d)
    if dd == 0.0:  # closed loop: L1 == Lk
        return np.linalg.norm(p - a, axis=-1)
    return np.linalg.norm(np.cross(p - a, d), axis=-1) / np.sqrt(dd)


def split_lines(lines: list, pos: np.ndarray, radius: np.ndarray, kind: np.ndarray) -> list:
    """Cut lines at curvature nodes, then at coverage nodes (paper IV.B.1), recursively."""
    def by_curvature(line):
        inner = np.asarray(line[1:-1])
        if len(inner) == 0:
            return [line]
        curv = _point_line_distance(pos[inner], pos[line[0]], pos[line[-1]]) / radius[inner]
        j = int(np.argmax(curv))
        if curv[j] <= 1.0:
            return [line]
        kind[inner[j]] = KIND_CURVATURE
        return by_curvature(line[:j + 2]) + by_curvature(line[j + 1:])

    def by_coverage(line):
        inner = np.asarray(line[1:-1])
        if len(inner) == 0:
            return [line]
        a, b = line[0], line[-1]
        covered = ((np.linalg.norm(pos[inner] - pos[a], axis=1) <= radius[a]) |
                   (np.linalg.norm(pos[inner] - pos[b], axis=1) <= radius[b]))
        if covered.all():
            return [line]
        j = int(np.argmin(covered))  # first uncovered node walking from L1
        kind[inner[j]] = KIND_COVERAGE
        return [line[:j + 2]] + by_coverage(line[j + 1:])

    out = []
    for line in lines:
        for part in by_curvature(line):
            out += by_coverage(part)
    return out


def segment(graph, pos: np.ndarray, radius: np.ndarray):
    """Node kinds, association of every node to a segmented node, segmented edges."""
    n = graph.shape[0]
    nbrs = _neighbours(graph)
    degree = np.diff(graph.indptr)
    kind = np.where(degree != 2, KIND_TOPOLOGY, KIND_UNCLASSIFIED).astype(np.int8)
    ncomp, comp = connected_components(graph, directed=False)
    for c in range(ncomp):  # a pure loop has no topology node: its first node becomes one
        members = np.flatnonzero(comp == c)
        if not np.any(kind[members] == KIND_TOPOLOGY):
            kind[members[0]] = KIND_TOPOLOGY
    lines = split_lines(trace_lines(nbrs, kind), pos, radius, kind)
    association = np.arange(n)
    edges = set()
    for line in lines:
        a, b = line[0], line[-1]
        if a != b:
            edges.add((min(a, b), max(a, b)))
        steps = np.linalg.norm(np.diff(pos[line], axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(steps)])
        for i, node in enumerate(line[1:-1], start=1):
            association[node] = a if arc[i] <= arc[-1] - arc[i] else b
    seg_edges = np.array(sorted(edges), dtype=np.int64).reshape(-1, 2)
    return kind, association, seg_edges


# ----------------------------------------------------------------------------- 4. visibility clusters
def cluster(seg_nodes: np.ndarray, seg_edges: np.ndarray, pos, radius, kind, alpha_percent: float):
    """Paper IV.B.2: greedy clusters over the segmented skeleton. Returns {skeleton node: cluster}."""
    nbrs: dict = {int(v): [] for v in seg_nodes}
    for a, b in seg_edges:
        nbrs[int(a)].append(int(b))
        nbrs[int(b)].append(int(a))
    order = sorted((int(v) for v in seg_nodes), key=lambda v: (-radius[v], v))
    label: dict = {}
    count = 0
    for n in order:
        if n in label:
            continue
        stack, r_max = [n], 0.0
        while stack:
            m = stack.pop()
            if m in label:
                continue
            label[m] = count
            r_max = max(r_max, float(radius[m]))
            for k in nbrs[m]:
                if k not in label and kind[k] != KIND_CURVATURE and \
                        abs(float(radius[k]) - float(radius[m])) <= alpha_percent / 100.0 * r_max:
                    stack.append(k)
            # every node inside m's maximal ball reachable from m (traversal kept inside the ball)
            seen, frontier = {m}, [m]
            while frontier:
                u = frontier.pop()
                for k in nbrs[u]:
                    if k not in seen and np.linalg.norm(pos[k] - pos[m]) <= radius[m]:
                        seen.add(k)
                        frontier.append(k)
                        if k not in label:
                            stack.append(k)
        count += 1
    return label, count


# ----------------------------------------------------------------------------- 6. voxel -> cluster
def cluster_grid(enclosed: np.ndarray, skel_coords: np.ndarray, node_cluster: np.ndarray) -> np.ndarray:
    shape = enclosed.shape
    flat = np.flatnonzero(enclosed.ravel())
    index = -np.ones(enclosed.size, np.int64)
    index[flat] = np.arange(len(flat))
    coords = np.array(np.unravel_index(flat, shape)).T
    rows, cols = [], []
    for axis in range(3):
        off = np.zeros(3, np.int64)
        off[axis] = 1
        nb = coords + off
        ok = nb[:, axis] < shape[axis]
        j = -np.ones(len(coords), np.int64)
        j[ok] = index[np.ravel_multi_index(tuple(nb[ok].T), shape)]
        m = j >= 0
        rows.append(np.flatnonzero(m)); cols.append(j[m])
    r, c = np.concatenate(rows), np.concatenate(cols)
    g = sparse.coo_matrix((np.ones(len(r)), (r, c)), shape=(len(flat), len(flat))).tocsr()
    sources = index[np.ravel_multi_index(tuple(skel_coords.T), shape)]
    _, _, nearest = dijkstra(g, directed=False, indices=sources, unweighted=True, min_only=True,
                             return_predecessors=True)
    source_node = -np.ones(len(flat), np.int64)
    source_node[sources] = np.arange(len(sources))
    grid = -np.ones(enclosed.size, np.int32)
    reached = nearest >= 0
    grid[flat[reached]] = node_cluster[source_node[nearest[reached]]]
    grid = grid.reshape(shape)
    # unreached enclosed voxels (none when every component holds a skeleton node) and every other
    # voxel: the cluster of the nearest labelled voxel
    _, nearest_idx = ndimage.distance_transform_edt(grid < 0, return_indices=True)
    return grid[tuple(nearest_idx)].astype(np.int32)


# ----------------------------------------------------------------------------- all steps
def build_topology(vertices: np.ndarray, faces: np.ndarray, resolution: int, alpha_percent: float,
                   scene_name: str = "scene") -> Topology:
    timings = {}
    t = time.perf_counter()
    _, enclosed, origin, pitch = voxelize(np.asarray(vertices, float), np.asarray(faces), resolution)
    timings["voxelize"] = time.perf_counter() - t
    if not enclosed.any():
        raise TopologyError(f"scene '{scene_name}' encloses no empty space at voxel_resolution={resolution} "
                            f"(open scene: visibility clusters need closed rooms)")
    t = time.perf_counter()
    coords, graph = skeleton_graph(enclosed)
    coords, graph = prune_spurs(coords, graph, enclosed)
    depth = ndimage.distance_transform_edt(enclosed)
    radius = np.maximum(depth[tuple(coords.T)] - 0.5, 0.5) * pitch  # centre to the voxelised surface
    pos = origin + (coords + 0.5) * pitch
    timings["skeleton"] = time.perf_counter() - t
    t = time.perf_counter()
    kind, association, seg_edges = segment(graph, pos, radius)
    seg_nodes = np.flatnonzero(kind != KIND_UNCLASSIFIED)
    label, count = cluster(seg_nodes, seg_edges, pos, radius, kind, alpha_percent)
    node_cluster = np.array([label[int(association[i])] for i in range(len(coords))], np.int32)
    centres, normals, radii, pairs = [], [], [], []
    for a, b in seg_edges:
        ca, cb = label[int(a)], label[int(b)]
        if ca == cb:
            continue
        d = pos[b] - pos[a]
        centres.append(0.5 * (pos[a] + pos[b]))
        normals.append(d / np.linalg.norm(d))
        radii.append(min(radius[a], radius[b]))
        pairs.append((ca, cb))
    timings["segment_cluster_gates"] = time.perf_counter() - t
    t = time.perf_counter()
    grid = cluster_grid(enclosed, coords, node_cluster)
    timings["cluster_grid"] = time.perf_counter() - t
    return Topology(origin=origin, pitch=pitch, dims=tuple(int(x) for x in enclosed.shape), cluster_grid=grid,
                    node_position=pos, node_radius=radius, node_kind=kind, node_segment=association,
                    node_cluster=node_cluster, segmented_edges=seg_edges, cluster_count=count,
                    gate_centre=np.array(centres, float).reshape(-1, 3),
                    gate_normal=np.array(normals, float).reshape(-1, 3),
                    gate_radius=np.array(radii, float), gate_clusters=np.array(pairs, np.int64).reshape(-1, 2),
                    enclosed_voxels=int(enclosed.sum()), timings_s=timings)
