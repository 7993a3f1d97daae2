"""Visibility Gates precomputation (paper section IV), on the CPU with numpy / scipy / scikit-image / trimesh:

1. `voxelize`: a voxel is occupied when its centre is within sqrt(3)/2 voxel of a triangle
   (exact distances, `SurfaceIndex`), so the 26-connected empty space never passes through a
   surface. The empty space is every component of empty voxels not reaching the grid's border,
   plus, for open scenes, the component around the geometry holding a camera eye or positional
   light, closed by the bounding box enlarged by PAD voxels.
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
5. `merge_wide_gates`: clusters joined by a paper gate (radius min(maxball(n1), maxball(n2)))
   at least `merge_fraction` x the smaller cluster's largest ball are merged. `gates_between`:
   one gate per segmented edge joining two clusters, the convex polygon of the opening of the
   empty space at the narrowest node of the skeleton line the edge replaces, in the plane of
   the opening's frame when there is one (`occluder_normal`, `opening_polygon`), or that
   node's maximal-ball disk (a regular 16-gon) where the opening is not bounded nearby.
6. `cluster_grid`: each empty voxel gets the cluster of its geodesically nearest skeleton node
   (breadth-first flooding through the empty space cut along the gates, `gate_barrier`;
   scikit-image's watershed); every other voxel (surfaces, outside) the cluster of its nearest
   empty voxel, so a surface point looked up one voxel off its surface along its normal finds
   its room; in the voxels a gate's plane cuts (the gate's and its wall's) the side of the
   plane decides.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import trimesh
from scipy import ndimage, sparse
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, HalfspaceIntersection, cKDTree
from skimage.morphology import skeletonize
from skimage.segmentation import watershed

KIND_UNCLASSIFIED, KIND_TOPOLOGY, KIND_CURVATURE, KIND_COVERAGE = 0, 1, 2, 3
OCCUPIED_DISTANCE = 0.5 * np.sqrt(3.0)  # voxels: centre-to-triangle distance of an occupied voxel
PAD = 2  # voxels between the scene's bounding box and the grid border (the closing box)

# 13 half-neighbourhood offsets of the 26-neighbourhood (each undirected voxel pair once).
_HALF_OFFSETS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)
                          if (i, j, k) > (0, 0, 0)])


class TopologyError(ValueError):
    """The scene has no empty space the method can build its topology in."""


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
    greedy_cluster_count: int   # clusters of the paper's greedy step, before merge_wide_gates
    gates: "GateSet"            # convex polygon gates (centre, plane, half-planes, the clusters they join)
    empty_voxels: int
    closed_by_box: bool         # open scene: the empty space is closed by the enlarged bounding box
    timings_s: dict = field(default_factory=dict)

    @property
    def gate_radius(self) -> np.ndarray:
        """(G,) radius of the ball around each gate's centre holding its polygon."""
        return self.gates.radius

    @property
    def gate_clusters(self) -> np.ndarray:
        return self.gates.pairs

    def cluster_of(self, points: np.ndarray) -> np.ndarray:
        """Visibility cluster of world points (nearest voxel, clamped to the grid; in a gate's own
        voxel, the side of the gate's plane the point is on)."""
        points = np.asarray(points, float).reshape(-1, 3)
        idx = np.floor((points - self.origin) / self.pitch).astype(np.int64)
        idx = np.clip(idx, 0, np.asarray(self.dims) - 1)
        out = self.cluster_grid[idx[:, 0], idx[:, 1], idx[:, 2]].astype(np.int64)
        at_gate = out < -1
        if at_gate.any():
            g = -out[at_gate] - 2
            plus = np.einsum("pc,pc->p", points[at_gate] - self.gates.centre[g], self.gates.normal[g]) >= 0
            out[at_gate] = self.gates.sides[g, plus.astype(int)]
        return out


# ----------------------------------------------------------------------------- 1. voxelization
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


def voxelize(vertices: np.ndarray, faces: np.ndarray, resolution: int, seeds=()):
    """Binary voxelization and the empty space light travels in.

    A voxel is occupied when its centre is within sqrt(3)/2 voxel of a triangle (exact distance,
    OCCUPIED_DISTANCE): the segment between the centres of two 26-adjacent voxels that crosses a
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
    surface = SurfaceIndex(vertices, faces, 0.5 * pitch)
    idx = np.clip(np.floor((surface.points - origin) / pitch).astype(np.int64), 0, dims - 1)
    near = np.zeros(tuple(dims), dtype=bool)
    near[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    # a centre within OCCUPIED_DISTANCE + 0.5 (< 1.5) voxels of a sample is in a voxel next to the sample's
    band = np.argwhere(ndimage.binary_dilation(near, structure=np.ones((3, 3, 3), bool)))
    occupied = np.zeros(tuple(dims), dtype=bool)
    occupied[tuple(band[surface.near(origin + (band + 0.5) * pitch, OCCUPIED_DISTANCE * pitch)].T)] = True
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
    return occupied, empty, origin, pitch, closed_by_box, surface


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


# ----------------------------------------------------------------------------- 5. gates, merging
GATE_RASTER = 16     # half-width of the gate's cross-section raster, in raster cells
GATE_REACH = 4.0     # the raster's half-width, in maximal-ball radii of the narrowest node
TANGENT_STEPS = (1, 2, 3, 5, 8)  # skeleton nodes either side of the narrowest node: candidate normals
MAX_GATE_EDGES = 16  # edges of a gate polygon (the GPU's Gate record holds this many half-planes)
EDGE_SAMPLES = (0.3, 0.5, 0.7)   # where along a polygon edge its exact offset is measured
EDGE_MARCH = 32      # distance samples along each outward march
FRAME_ANGLE = 30.0   # degrees: triangles facing within this of the skeleton line frame an opening
SIDE_REACH = 3.0     # gate radii: how far along its wall a gate's plane decides the side of a point
AREA_TOLERANCE = 0.05  # candidate planes whose openings are this close in area count as equal


@dataclass
class GateSet:
    """Convex polygon gates. Gate g lies in the plane through centre[g] normal to normal[g]; with
    axis_u[g] and axis_v = normal x axis_u its points q (relative to the centre) satisfy
    m_i . (q.u, q.v) <= offset_i for every half-plane (m_x, m_y, offset) of halfplanes[g, :count[g]]
    (the centre is inside: offsets > 0, so scaling the offsets scales the polygon about it)."""
    centre: np.ndarray       # (G, 3)
    normal: np.ndarray       # (G, 3) unit, along the skeleton (sign free)
    axis_u: np.ndarray       # (G, 3) unit, in the gate's plane
    halfplanes: np.ndarray   # (G, MAX_GATE_EDGES, 3)
    count: np.ndarray        # (G,) half-planes used
    radius: np.ndarray       # (G,) largest distance of a vertex from the centre (bounding ball)
    area: np.ndarray         # (G,) polygon area (m^2)
    pairs: np.ndarray        # (G, 2) the two clusters each gate separates
    sides: np.ndarray | None = None  # (G, 2) cluster on the -normal and +normal side (-1: the gate separates nothing)

    @property
    def axis_v(self) -> np.ndarray:
        return np.cross(self.normal, self.axis_u)

    def vertices(self, g: int) -> np.ndarray:
        """(V, 2) vertices of gate g's polygon in its (u, v) frame, counter-clockwise."""
        return _halfplane_polygon(self.halfplanes[g, :self.count[g]])


def _plane_axes(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    u = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    return u, np.cross(normal, u)


def _halfplane_polygon(halfplanes: np.ndarray) -> np.ndarray:
    """Vertices (counter-clockwise) of {q : m_i . q <= o_i}, which holds the origin strictly."""
    hs = np.column_stack([halfplanes[:, :2], -halfplanes[:, 2]])  # scipy: A q + b <= 0
    pts = HalfspaceIntersection(hs, np.zeros(2)).intersections
    hull = ConvexHull(pts)
    return pts[hull.vertices]


def _polygon_area(pts: np.ndarray) -> float:
    x, y = pts[:, 0], pts[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def _simplify_convex(pts: np.ndarray, max_vertices: int) -> np.ndarray:
    """Drop the vertex whose removal loses the least area (Visvalingam) until max_vertices remain."""
    pts = list(map(tuple, pts))
    while len(pts) > max_vertices:
        a = np.array(pts)
        prev, nxt = np.roll(a, 1, axis=0), np.roll(a, -1, axis=0)
        tri = 0.5 * np.abs((a[:, 0] - prev[:, 0]) * (nxt[:, 1] - prev[:, 1]) -
                           (nxt[:, 0] - prev[:, 0]) * (a[:, 1] - prev[:, 1]))
        pts.pop(int(np.argmin(tri)))
    return np.array(pts)


def regular_polygon_gate(radius: float, edges: int = MAX_GATE_EDGES) -> np.ndarray:
    """Half-planes of the regular polygon with the area of the disk of `radius` (the paper's disk)."""
    apothem = radius * np.sqrt(np.pi / (edges * np.tan(np.pi / edges)))
    ang = 2.0 * np.pi * np.arange(edges) / edges
    return np.column_stack([np.cos(ang), np.sin(ang), np.full(edges, apothem)])


def opening_polygon(surface: "SurfaceIndex", centre: np.ndarray, normal: np.ndarray, reach: float, wall: float):
    """The opening of the empty space in the plane (centre, normal), as a convex polygon.

    The region of the plane around `centre` farther than `wall` from every triangle (exact
    distance; the voxels' own OCCUPIED_DISTANCE, so a zero-thickness wall still bounds the plane
    through a skeleton node, which lies beside it) is rasterised at reach / GATE_RASTER (at most
    `wall`, so the 4-connected region never crosses a surface); its convex hull, simplified to
    MAX_GATE_EDGES edges, gives the edges' directions, and each edge is then placed where the
    opening really ends: marching outward from the edge (normal m), the region ends at s_f
    (distance = wall) and the occluder's nearest approach beyond is d_min, so the opening's
    border lies sqrt(wall^2 - d_min^2) beyond s_f (exact for an occluder's edge parallel to the
    gate's edge: a thin wall d_min = its offset from the plane, a thick one 0; the median of
    EDGE_SAMPLES along the edge). A rectangular door gives its rectangle. Returns (the
    region's centroid (the gate's centre), unit u axis, half-planes (E, 3) relative to the
    centroid), or None when the region reaches the raster's border (no bounded opening there)."""
    u, v = _plane_axes(normal)
    h = min(reach / GATE_RASTER, wall)
    n = int(np.ceil(reach / h))
    t = (np.arange(2 * n + 1) - n) * h
    su, sv = np.meshgrid(t, t, indexing="ij")
    points = centre + su[..., None] * u + sv[..., None] * v
    free = ~surface.near(points.reshape(-1, 3), wall).reshape(su.shape)
    labels, _ = ndimage.label(free)  # 4-connectivity
    own = labels[n, n]
    if own == 0:
        return None
    region = labels == own
    if region[[0, -1]].any() or region[:, [0, -1]].any():
        return None
    uv = np.stack([su[region], sv[region]], axis=1)
    mean = uv.mean(axis=0)
    uv = uv - mean
    if len(uv) >= 3 and np.linalg.matrix_rank(uv - uv[0], tol=1e-9 * h) == 2:
        hull = _simplify_convex(uv[ConvexHull(uv).vertices], MAX_GATE_EDGES)
    else:  # a region one cell wide: its cells' own squares
        hull = np.concatenate([uv + 0.5 * h * np.array(c) for c in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
        hull = _simplify_convex(hull[ConvexHull(hull).vertices], MAX_GATE_EDGES)
    nxt = np.roll(hull, -1, axis=0)
    edge = nxt - hull
    m = np.column_stack([edge[:, 1], -edge[:, 0]])  # outward for a counter-clockwise hull
    m /= np.linalg.norm(m, axis=1, keepdims=True)
    base = np.einsum("ec,ec->e", m, hull)
    # exact placement of every edge: march outward from EDGE_SAMPLES points of it
    frac = np.asarray(EDGE_SAMPLES)
    starts = hull[:, None] + frac[None, :, None] * edge[:, None]                   # (E, S, 2)
    span = h + 3.0 * wall
    s = np.linspace(0.0, span, EDGE_MARCH)
    q = starts[:, :, None] + s[None, None, :, None] * m[:, None, None]            # (E, S, K, 2)
    world = centre + (mean[0] + q[..., 0:1]) * u + (mean[1] + q[..., 1:2]) * v
    d = surface.distance(world.reshape(-1, 3)).reshape(q.shape[:3])
    inside = d > wall
    first = np.argmin(inside, axis=2)                                             # first sample at or below wall
    ends = np.where(inside.all(axis=2), EDGE_MARCH - 1, first)
    i0 = np.maximum(ends - 1, 0)
    d0 = np.take_along_axis(d, i0[..., None], 2)[..., 0]
    d1 = np.take_along_axis(d, ends[..., None], 2)[..., 0]
    w = np.clip((d0 - wall) / np.maximum(d0 - d1, 1e-30), 0.0, 1.0)
    s_f = s[i0] + w * (s[ends] - s[i0])
    beyond = s[None, None, :] >= s_f[..., None] - 1e-12
    beyond &= s[None, None, :] <= s_f[..., None] + 2.0 * wall
    d_min = np.where(beyond, d, np.inf).min(axis=2)
    d_min = np.where(np.isfinite(d_min), d_min, wall)
    offset = np.median(s_f + np.sqrt(np.maximum(wall * wall - d_min * d_min, 0.0)), axis=1)
    halfplanes = np.column_stack([m, base + offset])
    return centre + mean[0] * u + mean[1] * v, u, halfplanes


def occluder_normal(surface: "SurfaceIndex", centre: np.ndarray, tangent: np.ndarray, reach: float):
    """The area-weighted mean normal of the triangles within `reach` of `centre` that face along
    the skeleton (within FRAME_ANGLE of `tangent`): the plane of the wall an opening is cut in,
    or None when no such triangle is near."""
    t = tangent / np.linalg.norm(tangent)
    near = surface.tree.query_ball_point(centre, reach)
    if not near:
        return None
    tris = np.unique(surface.owner[np.asarray(near, np.int64)])
    v = surface.vertices[surface.faces[tris]]
    cross = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])  # |cross| = 2 area
    length = np.linalg.norm(cross, axis=1)
    ok = length > 0
    normals = cross[ok] / length[ok, None]
    along = normals @ t
    keep = np.abs(along) >= np.cos(np.radians(FRAME_ANGLE))
    if not keep.any():
        return None
    weight = length[ok][keep]
    mean = (normals[keep] * (np.sign(along[keep]) * weight)[:, None]).sum(axis=0)
    mean /= np.linalg.norm(mean)
    offset = float(np.average((v[ok][keep].mean(axis=1) - centre) @ mean, weights=weight))
    return mean, offset


def gates_between(seg_edges: np.ndarray, edge_lines: dict, seg_cluster: dict, pos: np.ndarray,
                  radius: np.ndarray, surface: "SurfaceIndex | None" = None, wall: float = 0.0) -> GateSet:
    """One gate per segmented edge joining two clusters. Without `surface`, the paper's disk
    (middle of the edge, orthogonal to it, radius min(maxball(n1), maxball(n2))), as the regular
    MAX_GATE_EDGES-gon of its area. With it, the polygon of the opening at the narrowest node of
    the skeleton line the edge replaces: of the planes through that node normal to the line
    there (tangents over TANGENT_STEPS nodes either side) or to the edge, the one whose bounded
    opening is smallest; or the disk of the node's maximal ball, normal to the line, when no
    such plane has a bounded opening nearby."""
    centres, normals, axes, planes, pairs = [], [], [], [], []
    for a, b in seg_edges:
        ca, cb = seg_cluster[int(a)], seg_cluster[int(b)]
        if ca == cb:
            continue
        pairs.append((ca, cb))
        found = None
        if surface is None:
            d = pos[b] - pos[a]
            centre, normal, r = 0.5 * (pos[a] + pos[b]), d / np.linalg.norm(d), min(radius[a], radius[b])
        else:
            line = edge_lines[(int(a), int(b))]
            k = int(np.argmin(radius[line]))
            centre, r = pos[line[k]], radius[line[k]]
            candidates = [pos[line[min(k + j, len(line) - 1)]] - pos[line[max(k - j, 0)]]
                          for j in TANGENT_STEPS[::-1]]  # the widest tangent first
            trial = []  # (point, unit normal): distinct directions only (within ~3 degrees)
            frame = occluder_normal(surface, centre, candidates[0], GATE_REACH * r)
            if frame is not None:  # the plane of the opening's frame (a door's wall) comes first
                trial.append((centre + np.clip(frame[1], -r, r) * frame[0], frame[0]))
            for d in candidates + [pos[b] - pos[a]]:
                if np.linalg.norm(d) > 0 and all(abs(d @ e) < 0.9986 * np.linalg.norm(d) for _, e in trial):
                    trial.append((centre, d / np.linalg.norm(d)))
            openings = [(cand, opening_polygon(surface, point, cand, GATE_REACH * r, wall)) for point, cand in trial]
            openings = [(cand, o, _polygon_area(_halfplane_polygon(o[2]))) for cand, o in openings if o is not None]
            normal = trial[0][1]
            if openings:
                smallest = min(area for _, _, area in openings)
                # the first (the frame's plane, then the widest tangent) within the measurement's
                # accuracy of the smallest: a plane tilted against a thin wall measures a few %
                # small (its edges are not parallel to the wall's), the frame's plane exact
                normal, found, _ = next(o for o in openings if o[2] <= (1.0 + AREA_TOLERANCE) * smallest)
        if found is None:
            found = (centre, _plane_axes(normal)[0], regular_polygon_gate(r))
        centres.append(found[0])
        normals.append(normal)
        axes.append(found[1])
        planes.append(found[2])
    g = len(planes)
    halfplanes = np.zeros((g, MAX_GATE_EDGES, 3))
    count = np.zeros(g, np.int64)
    radii, areas = np.zeros(g), np.zeros(g)
    for i, hp in enumerate(planes):
        halfplanes[i, :len(hp)] = hp
        count[i] = len(hp)
        verts = _halfplane_polygon(hp)
        radii[i] = np.linalg.norm(verts, axis=1).max()
        areas[i] = _polygon_area(verts)
    return GateSet(centre=np.array(centres, float).reshape(-1, 3), normal=np.array(normals, float).reshape(-1, 3),
                   axis_u=np.array(axes, float).reshape(-1, 3), halfplanes=halfplanes, count=count, radius=radii,
                   area=areas, pairs=np.array(pairs, np.int64).reshape(-1, 2))


def paper_gate_radii(seg_edges: np.ndarray, seg_cluster: dict, radius: np.ndarray):
    """The paper's gate radius min(maxball(n1), maxball(n2)) of every segmented edge joining two
    clusters, and the pairs it joins."""
    rows = [(min(radius[a], radius[b]), seg_cluster[int(a)], seg_cluster[int(b)]) for a, b in seg_edges
            if seg_cluster[int(a)] != seg_cluster[int(b)]]
    arr = np.array(rows, float).reshape(-1, 3)
    return arr[:, 0], arr[:, 1:].astype(np.int64)


def merge_wide_gates(count: int, cluster_radius: np.ndarray, gate_radius: np.ndarray, gate_pairs: np.ndarray,
                     fraction: float) -> tuple[np.ndarray, int]:
    """Merge two clusters joined by a gate at least `fraction` as wide as the smaller cluster's
    largest maximal ball: such a gate is no narrowing of the empty space (a door is narrow beside
    a room, the gap beside a block is not beside itself), only a break in the voxel skeleton's
    radii, and light crossing it is barely occluded. Widest gate (relative) first, one at a
    time, the ratios re-evaluated with the merged clusters' largest balls. Returns (new label of
    each old cluster, in order of first appearance; new count)."""
    parent = np.arange(count)
    r_max = np.asarray(cluster_radius, float).copy()

    def root(c):
        while parent[c] != c:
            c = parent[c]
        return c

    while True:
        best, best_ratio = None, -1.0
        for g, (a, b) in enumerate(gate_pairs):
            ra, rb = root(int(a)), root(int(b))
            if ra == rb:
                continue
            ratio = gate_radius[g] / min(r_max[ra], r_max[rb])
            if ratio >= fraction and ratio > best_ratio:
                best, best_ratio = (ra, rb), ratio
        if best is None:
            break
        keep, gone = min(best), max(best)
        parent[gone] = keep
        r_max[keep] = max(r_max[keep], r_max[gone])
    roots = np.array([root(c) for c in range(count)])
    _, first, inverse = np.unique(roots, return_index=True, return_inverse=True)
    order = np.argsort(np.argsort(first))  # relabel in order of first appearance
    return order[inverse].astype(np.int64), len(first)


# ----------------------------------------------------------------------------- 6. voxel -> cluster
def gate_barrier(empty: np.ndarray, origin: np.ndarray, pitch: float, gates: GateSet) -> tuple[np.ndarray, np.ndarray]:
    """The gates rasterised into the voxel grid. For every gate, its layer: the voxels of its
    standard digital plane (n.(c - g) / pitch in [-|n|_1 / 2, |n|_1 / 2): no 6-connected path
    crosses it) within SIDE_REACH gate radii of its centre. Returns int32 grids holding the gate's
    index (else -1): `barrier`, the layer's empty voxels whose centre projects inside the polygon
    grown by one voxel (closing the gap to the occupied voxels of the opening's border), and
    `sided`, the barrier and the layer's occupied voxels connected to it in the layer (the wall
    the opening is cut in), where a voxel holds points of both clusters."""
    barrier = -np.ones(empty.shape, np.int32)
    sided = -np.ones(empty.shape, np.int32)
    dims = np.asarray(empty.shape)
    for g in range(len(gates.radius)):
        c, n, u = gates.centre[g], gates.normal[g], gates.axis_u[g]
        v = np.cross(n, u)
        reach = SIDE_REACH * gates.radius[g] + 2.0 * pitch
        lo = np.clip(np.floor((c - reach - origin) / pitch).astype(np.int64), 0, dims - 1)
        hi = np.clip(np.ceil((c + reach - origin) / pitch).astype(np.int64), 0, dims - 1)
        box = tuple(slice(a, b + 1) for a, b in zip(lo, hi))
        idx = np.stack(np.meshgrid(*[np.arange(a, b + 1) for a, b in zip(lo, hi)], indexing="ij"), -1)
        rel = origin + (idx + 0.5) * pitch - c
        side = rel @ n / pitch
        half = 0.5 * np.abs(n).sum()
        layer = (side >= -half) & (side < half)
        q = np.stack([rel @ u, rel @ v], axis=-1)
        hp = gates.halfplanes[g, :gates.count[g]]
        inside = np.all(q @ hp[:, :2].T <= hp[:, 2] + pitch, axis=-1)
        gate = layer & inside & empty[box]
        frame = layer & (gate | ~empty[box])
        labels, _ = ndimage.label(frame, structure=np.ones((3, 3, 3), bool))
        wall = np.isin(labels, np.unique(labels[gate])) & (labels > 0)
        barrier[box][gate] = g
        sided[box][wall] = g
    return barrier, sided


def cluster_grid(empty: np.ndarray, skel_coords: np.ndarray, node_cluster: np.ndarray,
                 barrier: np.ndarray | None = None, sided: np.ndarray | None = None, gates: GateSet | None = None,
                 origin: np.ndarray | None = None, pitch: float = 1.0) -> np.ndarray:
    """Visibility cluster of every voxel. The gates separate the clusters (paper VII: "if the
    visibility gates were perfect manifolds separating clusters"): the empty space is cut along
    `barrier` (the rasterised gates, `gate_barrier`); a cluster lives in the cut component
    holding most of its skeleton nodes, its nodes in other components (a door's nodes beyond the
    door's gate) are not seeds. Empty voxels: the cluster of the geodesically nearest seed node
    (6-connected steps through the cut empty space): scikit-image's watershed of a flat image
    floods breadth first, in order of arrival, which is that (ties between two nodes aside).
    Every other voxel (surfaces, outside): the cluster of its nearest labelled voxel. The voxels
    `sided` (a gate's own, and its wall's in its plane) hold -(gate + 2) when the clusters on
    the gate's two sides differ: the side of the gate's plane decides there (`Topology.cluster_of`,
    `cluster_at` in topology.glsl); `gates.sides` is set."""
    node_cluster = np.asarray(node_cluster)
    cut = empty if barrier is None else empty & (barrier < 0)
    seed = cut[tuple(skel_coords.T)]
    if barrier is not None and (barrier >= 0).any():
        comp, _ = ndimage.label(cut)  # 6-connectivity, as the flooding
        node_comp = comp[tuple(skel_coords.T)]
        for c in np.unique(node_cluster):
            mine = seed & (node_cluster == c)
            if mine.any():
                home = np.bincount(node_comp[mine]).argmax()
                seed &= ~((node_cluster == c) & (node_comp != home))
    markers = np.zeros(empty.shape, np.int32)
    markers[tuple(skel_coords[seed].T)] = node_cluster[seed] + 1
    flooded = watershed(np.zeros(empty.shape, np.uint8), markers, connectivity=1, mask=cut)
    grid = flooded.astype(np.int32) - 1
    # unreached empty voxels (none when every component holds a seed) and every other voxel:
    # the cluster of the nearest labelled voxel
    _, nearest_idx = ndimage.distance_transform_edt(grid < 0, return_indices=True)
    filled = grid[tuple(nearest_idx)].astype(np.int32)
    if gates is not None and barrier is not None:
        sides = -np.ones((len(gates.radius), 2), np.int64)
        dims = np.asarray(empty.shape)
        for g in range(len(gates.radius)):
            for j, sign in enumerate((-1.0, 1.0)):
                for k in range(1, 6):  # the first flooded voxel beside the gate along its normal
                    v = np.floor((gates.centre[g] + sign * k * pitch * gates.normal[g] - origin) / pitch).astype(int)
                    if np.all((v >= 0) & (v < dims)) and grid[tuple(v)] >= 0:
                        sides[g, j] = grid[tuple(v)]
                        break
            if sides[g, 0] < 0 or sides[g, 1] < 0 or sides[g, 0] == sides[g, 1]:
                sides[g] = -1
        gates.sides = sides
        if len(sides):
            split = (sided >= 0) & (sides[np.maximum(sided, 0), 0] >= 0)
            filled[split] = -(sided[split] + 2)
    return filled


# ----------------------------------------------------------------------------- all steps
def build_topology(vertices: np.ndarray, faces: np.ndarray, resolution: int, alpha_percent: float,
                   merge_fraction: float, seeds=(), scene_name: str = "scene") -> Topology:
    vertices, faces = np.asarray(vertices, float), np.asarray(faces)
    timings = {}
    t = time.perf_counter()
    _, empty, origin, pitch, closed_by_box, surface = voxelize(vertices, faces, resolution, seeds)
    timings["voxelize"] = time.perf_counter() - t
    if not empty.any():
        raise TopologyError(f"scene '{scene_name}' has no empty space at voxel_resolution={resolution}: no "
                            f"enclosed room, and no camera or positional light in the space around it")
    t = time.perf_counter()
    coords, graph = skeleton_graph(empty)
    coords, graph = prune_spurs(coords, graph, empty)
    pos = origin + (coords + 0.5) * pitch
    timings["skeleton"] = time.perf_counter() - t
    t = time.perf_counter()
    radius = surface.distance(pos)
    if closed_by_box:  # the closing box's walls bound the balls too
        box_lo, box_hi = origin + pitch, origin + (np.asarray(empty.shape) - 1) * pitch
        radius = np.minimum(radius, np.minimum(pos - box_lo, box_hi - pos).min(axis=1))
    radius = np.maximum(radius, 1e-3 * pitch)  # a node is an empty voxel's centre: never on a surface
    timings["maximal_balls"] = time.perf_counter() - t
    t = time.perf_counter()
    kind, association, seg_edges, edge_lines = segment(graph, pos, radius)
    seg_nodes = np.flatnonzero(kind != KIND_UNCLASSIFIED)
    label, count = cluster(seg_nodes, seg_edges, pos, radius, kind, alpha_percent)
    greedy_count = count
    cluster_radius = np.zeros(count)
    for node, c in label.items():
        cluster_radius[c] = max(cluster_radius[c], radius[node])
    paper_r, paper_pairs = paper_gate_radii(seg_edges, label, radius)
    relabel, count = merge_wide_gates(count, cluster_radius, paper_r, paper_pairs, merge_fraction)
    label = {node: int(relabel[c]) for node, c in label.items()}
    gates = gates_between(seg_edges, edge_lines, label, pos, radius, surface, OCCUPIED_DISTANCE * pitch)
    node_cluster = np.array([label[int(association[i])] for i in range(len(coords))], np.int32)
    timings["segment_cluster_gates"] = time.perf_counter() - t
    t = time.perf_counter()
    barrier, sided = gate_barrier(empty, origin, pitch, gates)
    grid = cluster_grid(empty, coords, node_cluster, barrier, sided, gates, origin, pitch)
    timings["cluster_grid"] = time.perf_counter() - t
    return Topology(origin=origin, pitch=pitch, dims=tuple(int(x) for x in empty.shape), cluster_grid=grid,
                    node_position=pos, node_radius=radius, node_kind=kind, node_segment=association,
                    node_cluster=node_cluster, segmented_edges=seg_edges, cluster_count=count,
                    greedy_cluster_count=greedy_count, gates=gates, empty_voxels=int(empty.sum()),
                    closed_by_box=closed_by_box, timings_s=timings)
