"""The emitter hierarchy of `pbgi`: one tree over every lightmap texel (surfel) of the scene,
across charts, laid out in depth-first (pre-)order with skip links, so that a receiver walks
it without a stack.

The article's closing suggestion is "a quad tree of the geometry". A tree per chart does not
aggregate across charts: a real scene has thousands of small charts (sponza 7,000, most of a
texel or two), so every receiver visited at least one node per chart and the cost went back to
O(texels x charts). Here the tree is an octree of the surfels' positions (the 3-D form of the
quadtree), under one root per normal class:

- class: the dominant axis and sign of the texel's normal (the six classes of the planar
  unwrap): every node's normals lie within 55 degrees of its axis, so its leaves' cosines
  towards a receiver rarely differ in sign (see emitter_hierarchy.glsl for why that matters);
- then the Morton (Z-order) code of the position quantised to 2^21 cells per axis in the
  scene's bounding cube: a cube of the octree is a contiguous range [lo, hi) of leaves.

Every cube of every level that holds a texel is a node; a cube with the same texels as its
only child cube is the same node (kept once, at its lowest level); level 0 is the texels
themselves, so a leaf is exactly a node with one texel. In pre-order (lo ascending, ancestors
first) the subtree of node i is the contiguous range [i, skip[i]) of node indices, which gives:

- a stackless walk: at node i either use the node (its aggregate stands for all its leaves)
  and go to skip[i], or refine and go to i + 1 (its first child);
- any range [first, end) of node indices can be walked on its own: a node is used whole only
  if skip <= end (else refined), so consecutive ranges count every leaf exactly once. This is
  how the gather is split in draws (llvmpipe's loop cap) and in frames (the amortised mode):
  the leaves [k0, k1) are the nodes [leaf_start[k0], leaf_start[k1]).

Node aggregates are built on the GL every frame (emitter_hierarchy.glsl), level by level from
the leaves up (a parent's lowest level is above each child's); a node reads its children as
j = i + 1, skip[j], ... while j < skip[i]. Receivers are grouped in tiles of at most
`tile_texels` consecutive leaves (receiver_tiles): sibling cubes, so a tile is compact in space
whatever chart its texels come from; `tile_records` gives each tile's bounding sphere, mean
normal and flat flag (the nodes' flatness tolerances, HIERARCHY_DEFINES) for the gather.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MORTON_BITS = 21   # per axis: 63 bits of code
HIERARCHY_DEFINES = {
    "FLAT_COSINE_TOLERANCE": 1e-6,    # a node is flat when every leaf normal is within this (1 - cos) of its normal
    "FLAT_DISTANCE_TOLERANCE": 1e-5,  # ... and every child centre within this many node radii of its plane
    "PLANE_TOLERANCE": 1e-4,          # a receiver within this many node radii of a flat node's plane gets nothing from it
}


def morton3(q: np.ndarray) -> np.ndarray:
    """Interleaved bits of non-negative int coordinates q (E, 3) < 2^21 (x in bit 0)."""
    def spread(v):
        v = np.asarray(v, dtype=np.uint64) & np.uint64(0x1FFFFF)
        v = (v | (v << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
        v = (v | (v << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
        v = (v | (v << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
        v = (v | (v << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
        v = (v | (v << np.uint64(2))) & np.uint64(0x1249249249249249)
        return v
    q = np.asarray(q)
    return (spread(q[:, 0]) | (spread(q[:, 1]) << np.uint64(1)) | (spread(q[:, 2]) << np.uint64(2))).astype(np.int64)


def normal_class(normal: np.ndarray) -> np.ndarray:
    """Dominant axis and sign of each normal (E, 3): 2 axis + (component >= 0), in 0..5."""
    normal = np.asarray(normal, dtype=np.float64)
    axis = np.argmax(np.abs(normal), axis=1)
    return (2 * axis + (normal[np.arange(len(normal)), axis] >= 0)).astype(np.int64)


@dataclass
class EmitterTree:
    leaf_order: np.ndarray   # (E,) permutation: leaf k is input texel leaf_order[k]
    lo: np.ndarray           # (N,) first leaf of each node (pre-order)
    hi: np.ndarray           # (N,) one past its last leaf
    level: np.ndarray        # (N,) octree level (0: a texel)
    skip: np.ndarray         # (N,) index of the node after its subtree
    leaf_start: np.ndarray   # (E + 1,) first node (pre-order) whose leaves start at leaf k; [E] = N
    level_nodes: np.ndarray  # (N,) node indices grouped by level, ascending
    level_offsets: np.ndarray  # (levels + 1,) group boundaries in level_nodes

    @property
    def node_count(self) -> int:
        return int(len(self.lo))

    @property
    def leaf_count(self) -> int:
        return int(len(self.leaf_order))

    @property
    def roots(self) -> np.ndarray:
        """Top nodes (one per normal class present), in pre-order."""
        out, i = [], 0
        while i < self.node_count:
            out.append(i)
            i = int(self.skip[i])
        return np.asarray(out, dtype=np.int64)

    def children(self, i: int) -> list[int]:
        out, j = [], i + 1
        while j < self.skip[i]:
            out.append(j)
            j = int(self.skip[j])
        return out

    def receiver_tiles(self, tile_texels: int) -> np.ndarray:
        """(T, 2) first leaf and leaf count of each receiver tile: the largest nodes of at most
        `tile_texels` leaves, consecutive siblings merged while they fit. Tiles partition the
        leaves in order."""
        tiles: list[tuple[int, int]] = []

        def visit(siblings):
            run_lo = run_hi = -1
            for j in siblings:
                size = int(self.hi[j] - self.lo[j])
                if size > tile_texels:
                    if run_lo >= 0:
                        tiles.append((run_lo, run_hi - run_lo))
                    run_lo = run_hi = -1
                    visit(self.children(j))
                    continue
                if run_lo >= 0 and int(self.hi[j]) - run_lo > tile_texels:
                    tiles.append((run_lo, run_hi - run_lo))
                    run_lo = -1
                if run_lo < 0:
                    run_lo = int(self.lo[j])
                run_hi = int(self.hi[j])
            if run_lo >= 0:
                tiles.append((run_lo, run_hi - run_lo))

        visit(self.roots)
        return np.asarray(tiles, dtype=np.int64).reshape(-1, 2)

    def node_range(self, first_leaf: int, end_leaf: int) -> tuple[int, int]:
        """Node indices [first, end) whose walk covers exactly the leaves [first_leaf, end_leaf)."""
        return int(self.leaf_start[first_leaf]), int(self.leaf_start[end_leaf])


def build_tree(position: np.ndarray, normal: np.ndarray) -> EmitterTree:
    """Octree (per normal class) over the surfels at `position` (E, 3) with normals (E, 3)."""
    position = np.asarray(position, dtype=np.float64)
    if position.ndim != 2 or position.shape[1] != 3 or len(position) == 0:
        raise ValueError("pbgi: no covered lightmap texel to build an emitter hierarchy from")
    if not np.all(np.isfinite(position)):
        raise ValueError("pbgi: a lightmap texel has a non-finite position")
    cls = normal_class(normal)
    low = position.min(axis=0)
    extent = max(float((position.max(axis=0) - low).max()), 1e-30)
    cells = (1 << MORTON_BITS) - 1
    q = np.clip(np.floor((position - low) / extent * cells), 0, cells).astype(np.int64)
    code = morton3(q)
    order = np.lexsort((code, cls))
    code, cls = code[order], cls[order]
    count = len(order)
    los, his, levels = [np.arange(count)], [np.arange(1, count + 1)], [np.zeros(count, dtype=np.int64)]
    for level in range(1, MORTON_BITS + 2):   # level l: cubes of code >> 3 (l - 1); the last: the class
        shift = 3 * (level - 1)
        block = code >> np.int64(shift) if shift < 63 else np.zeros_like(code)
        new = np.r_[True, (block[1:] != block[:-1]) | (cls[1:] != cls[:-1])]
        starts = np.flatnonzero(new)
        los.append(starts)
        his.append(np.r_[starts[1:], count])
        levels.append(np.full(len(starts), level, dtype=np.int64))
    lo, hi, level = np.concatenate(los), np.concatenate(his), np.concatenate(levels)
    # one node per distinct leaf range, at its lowest level; pre-order: lo up, ancestors (larger hi) first
    order_nodes = np.lexsort((level, -hi, lo))
    lo, hi, level = lo[order_nodes], hi[order_nodes], level[order_nodes]
    keep = np.r_[True, (lo[1:] != lo[:-1]) | (hi[1:] != hi[:-1])]
    lo, hi, level = lo[keep], hi[keep], level[keep]
    skip = np.searchsorted(lo, hi, side="left").astype(np.int64)
    leaf_start = np.searchsorted(lo, np.arange(count + 1), side="left").astype(np.int64)
    level_nodes = np.argsort(level, kind="stable").astype(np.int64)
    level_offsets = np.searchsorted(level[level_nodes], np.arange(int(level.max()) + 2), side="left")
    return EmitterTree(leaf_order=order, lo=lo, hi=hi, level=level, skip=skip, leaf_start=leaf_start,
                       level_nodes=level_nodes, level_offsets=level_offsets.astype(np.int64))


def tile_records(tiles, position, normal, area, texel_m: float) -> np.ndarray:
    """ReceiverTile records (gather_hierarchy.glsl) of the tiles (first leaf, count): bounding
    sphere of the texels (area-weighted centre; each texel's radius as its leaf node's), mean
    normal and flat flag (every texel with that normal, on its plane: the tolerances of the
    emitter nodes), then the leaf range. Texel arrays in leaf order."""
    first, count = tiles[:, 0], tiles[:, 1]
    owner = np.repeat(np.arange(len(tiles)), count)
    a = area[:, None]
    centre = np.zeros((len(tiles), 3))
    np.add.at(centre, owner, a * position)
    centre /= np.bincount(owner, weights=area)[:, None]
    mean_n = np.zeros((len(tiles), 3))
    np.add.at(mean_n, owner, a * normal)
    mean_n /= np.maximum(np.linalg.norm(mean_n, axis=1), 1e-30)[:, None]
    axis_cos = np.maximum(np.abs(normal).max(axis=1), 1.0 / np.sqrt(3.0))
    reach = np.linalg.norm(position - centre[owner], axis=1) + np.sqrt(0.5) * texel_m / axis_cos
    radius = np.zeros(len(tiles))
    np.maximum.at(radius, owner, reach)
    along = np.einsum("ij,ij->i", normal, mean_n[owner])
    height = np.abs(np.einsum("ij,ij->i", position - centre[owner], mean_n[owner]))
    ok = (along >= 1.0 - HIERARCHY_DEFINES["FLAT_COSINE_TOLERANCE"]) & (
        height <= HIERARCHY_DEFINES["FLAT_DISTANCE_TOLERANCE"] * radius[owner])
    flat = np.bincount(owner, weights=~ok, minlength=len(tiles)) == 0
    records = np.zeros((len(tiles), 12), dtype=np.float32)
    records[:, :3], records[:, 3] = centre, radius
    records[:, 4:7], records[:, 7] = mean_n, flat
    records.view(np.int32)[:, 8], records.view(np.int32)[:, 9] = first, count
    return records
