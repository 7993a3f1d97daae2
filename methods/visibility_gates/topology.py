"""Visibility Gates precomputation (paper section IV), on the CPU with numpy / scipy / scikit-image / trimesh.
`build_topology` runs the steps; each module describes its own:

1. voxels.py, `voxelize`: the binary voxelization by exact distances (`SurfaceIndex`) and the
   empty space light travels in.
2. skeleton.py, `skeleton_graph`, `prune_spurs`: the curvilinear skeleton of the empty space as
   a graph, its spurs pruned; here each node's maximal-ball radius, its exact distance to the
   nearest triangle (and to the closing box's walls).
3. skeleton.py, `segment`: topology, curvature and coverage nodes.
4. skeleton.py, `cluster`: the paper's greedy visibility clusters.
5. gates.py, `merge_wide_gates`, `gates_between`: clusters joined by a wide gate merged; one
   convex polygon gate per segmented edge joining two clusters.
6. `cluster_grid` (this module): each empty voxel gets the cluster of its geodesically nearest skeleton node
   (breadth-first flooding through the empty space cut along the gates, `gate_barrier`;
   scikit-image's watershed); every other voxel (surfaces, outside) the cluster of its nearest
   empty voxel, so a surface point looked up one voxel off its surface along its normal finds
   its room; in the voxels a gate's plane cuts (the gate's and its wall's) the side of the
   plane decides.
7. gates.py, `border_gates` (opt-in, the method's `border_gates`): every patch of the
   clusters' borders in that grid which no gate of step 5 covers gets gates of its own.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage
from skimage.segmentation import watershed

from .gates import GateSet, border_gates, gates_between, merge_wide_gates, paper_gate_radii
from .skeleton import KIND_UNCLASSIFIED, cluster, prune_spurs, segment, skeleton_graph
from .voxels import DEFAULT_OCCUPANCY, OCCUPIED_DISTANCE, voxelize

SIDE_REACH = 3.0     # gate radii: how far along its wall a gate's plane decides the side of a point


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
                   merge_fraction: float, seeds=(), scene_name: str = "scene",
                   merge_visible: float = 0.0, cover_borders: bool = False,
                   occupancy: str = DEFAULT_OCCUPANCY) -> Topology:
    vertices, faces = np.asarray(vertices, float), np.asarray(faces)
    timings = {}
    t = time.perf_counter()
    _, empty, origin, pitch, closed_by_box, surface = voxelize(vertices, faces, resolution, seeds, occupancy)
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
    greedy_of_node = np.array([label[int(association[i])] for i in range(len(coords))], np.int64)
    relabel, count = merge_wide_gates(count, cluster_radius, paper_r, paper_pairs, merge_fraction,
                                      empty, coords, greedy_of_node, merge_visible)
    label = {node: int(relabel[c]) for node, c in label.items()}
    gates = gates_between(seg_edges, edge_lines, label, pos, radius, surface, OCCUPIED_DISTANCE * pitch)
    node_cluster = np.array([label[int(association[i])] for i in range(len(coords))], np.int32)
    timings["segment_cluster_gates"] = time.perf_counter() - t
    t = time.perf_counter()
    barrier, sided = gate_barrier(empty, origin, pitch, gates)
    grid = cluster_grid(empty, coords, node_cluster, barrier, sided, gates, origin, pitch)
    if cover_borders:
        gates = border_gates(grid, empty, origin, pitch, gates)
    timings["cluster_grid"] = time.perf_counter() - t
    return Topology(origin=origin, pitch=pitch, dims=tuple(int(x) for x in empty.shape), cluster_grid=grid,
                    node_position=pos, node_radius=radius, node_kind=kind, node_segment=association,
                    node_cluster=node_cluster, segmented_edges=seg_edges, cluster_count=count,
                    greedy_cluster_count=greedy_count, gates=gates, empty_voxels=int(empty.sum()),
                    closed_by_box=closed_by_box, timings_s=timings)
