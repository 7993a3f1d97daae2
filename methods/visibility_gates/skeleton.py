"""Visibility Gates precomputation, steps 2 to 4 (topology.py runs every step): the
curvilinear skeleton of the empty space, its segmentation and the greedy visibility clusters.

2. `skeleton_graph`: curvilinear skeleton of the empty space (scikit-image's 3-D thinning,
   Lee et al. 1994: topology preserving and centred, like the paper's cubical-complex thinning
   [20]). The skeleton voxels become a graph (26-adjacency, minus the long side of every voxel
   triangle, so a voxel staircase is a line and not a chain of spurious junctions), then
   `prune_spurs` removes the terminal branches their junction sees in a straight line (the
   spurs an end-point-preserving thinning grows towards convex corners and edges). The radius
   of each node's maximal ball is its exact distance to the nearest triangle (and to the
   closing box's walls).
3. `segment`: topology nodes (degree != 2), then curvature nodes (curv = dist(n, L1 Lk) /
   maxball(n) > 1, the most curved node first, recursively), then coverage nodes (a node in no
   maximal ball of its line's extrema, recursively); unclassified nodes are dropped and each
   is associated with the nearest extremum (arc length) of its line.
4. `cluster`: the paper's greedy visibility clusters (largest ball first, neighbours that are
   not curvature nodes and whose radius differs from the popped node's by at most alpha % of the
   cluster's largest, plus every node reachable inside the popped node's maximal ball).
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse.csgraph import connected_components
from skimage.morphology import skeletonize

KIND_UNCLASSIFIED, KIND_TOPOLOGY, KIND_CURVATURE, KIND_COVERAGE = 0, 1, 2, 3

# 13 half-neighbourhood offsets of the 26-neighbourhood (each undirected voxel pair once).
_HALF_OFFSETS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)
                          if (i, j, k) > (0, 0, 0)])


# ----------------------------------------------------------------------------- 2. skeleton graph
def skeleton_graph(empty: np.ndarray):
    """Skeleton voxel coordinates (S, 3) and their adjacency (CSR, symmetric, 0/1)."""
    skel = skeletonize(empty) > 0
    labels, count = ndimage.label(empty, structure=np.ones((3, 3, 3), bool))
    has = np.zeros(count + 1, bool)
    has[np.unique(labels[skel])] = True
    for comp in np.flatnonzero(~has[1:]) + 1:  # a component thinned to nothing keeps its deepest voxel
        dist = ndimage.distance_transform_edt(labels == comp)
        skel[np.unravel_index(int(np.argmax(dist)), dist.shape)] = True
    coords = np.argwhere(skel)
    index = -np.ones(empty.shape, np.int64)
    index[tuple(coords.T)] = np.arange(len(coords))
    rows, cols, lens = [], [], []
    for off in _HALF_OFFSETS:
        nb = coords + off
        ok = np.all((nb >= 0) & (nb < np.asarray(empty.shape)), axis=1)
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
    """Node kinds, association of every node to a segmented node, segmented edges and, per
    segmented edge (a, b) with a < b, the skeleton line it replaces (nodes from a to b)."""
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
    edges = {}
    for line in lines:
        a, b = line[0], line[-1]
        if a != b:
            edges.setdefault((min(a, b), max(a, b)), list(line) if a < b else list(line[::-1]))
        steps = np.linalg.norm(np.diff(pos[line], axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(steps)])
        for i, node in enumerate(line[1:-1], start=1):
            association[node] = a if arc[i] <= arc[-1] - arc[i] else b
    seg_edges = np.array(sorted(edges), dtype=np.int64).reshape(-1, 2)
    return kind, association, seg_edges, edges


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

