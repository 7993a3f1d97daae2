"""The emitter hierarchy of `pbgi`: a quadtree of each chart's lightmap texels, laid out in
depth-first (pre-)order with skip links, so that a receiver walks it without a stack.

The leaves are the covered texels of a chart, ordered by chart, then by the Morton (Z-order)
code of their texel coordinates inside the chart's box: a 2^l x 2^l block of the chart is then
a contiguous range [lo, hi) of leaves. Every block of every level that holds a texel is a node,
up to one root per chart; a block with the same texels as its only child block is the same
node (kept once, at its lowest level). In pre-order (lo ascending, ancestors first) the
subtree of node i is the contiguous range [i, skip[i]) of node indices, which gives:

- a stackless walk: at node i either use the node (its aggregate stands for all its leaves)
  and go to skip[i], or refine and go to i + 1 (its first child);
- any range [first, end) of node indices can be walked on its own: a node is used whole only
  if skip <= end (else refined), so consecutive ranges count every leaf exactly once. This is
  how the gather is split in draws (llvmpipe's loop cap) and in frames (the amortised mode):
  the leaves [k0, k1) are the nodes [leaf_start[k0], leaf_start[k1]).

Node aggregates are built on the GL every frame (emitter_hierarchy.glsl), level by level from
the leaves up; a node reads its children as j = i + 1, skip[j], ... while j < skip[i].
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def morton2(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Interleaved bits of non-negative ints x, y < 2^16 (x in the even bits)."""
    def spread(v):
        v = np.asarray(v, dtype=np.uint64) & np.uint64(0xFFFF)
        v = (v | (v << np.uint64(8))) & np.uint64(0x00FF00FF)
        v = (v | (v << np.uint64(4))) & np.uint64(0x0F0F0F0F)
        v = (v | (v << np.uint64(2))) & np.uint64(0x33333333)
        v = (v | (v << np.uint64(1))) & np.uint64(0x55555555)
        return v
    return (spread(x) | (spread(y) << np.uint64(1))).astype(np.int64)


@dataclass
class EmitterTree:
    leaf_order: np.ndarray   # (E,) permutation: leaf k is input texel leaf_order[k]
    lo: np.ndarray           # (N,) first leaf of each node (pre-order)
    hi: np.ndarray           # (N,) one past its last leaf
    level: np.ndarray        # (N,) quadtree level (0: a texel)
    skip: np.ndarray         # (N,) index of the node after its subtree
    leaf_start: np.ndarray   # (E + 1,) first node (pre-order) whose leaves start at leaf k; [E] = N
    level_nodes: np.ndarray  # (N,) node indices grouped by level, ascending
    level_offsets: np.ndarray  # (levels + 1,) group boundaries in level_nodes
    leaf_code: np.ndarray    # (E,) Morton code of each leaf in its chart's box
    leaf_chart: np.ndarray   # (E,) chart of each leaf

    @property
    def node_count(self) -> int:
        return int(len(self.lo))

    @property
    def leaf_count(self) -> int:
        return int(len(self.leaf_order))

    def receiver_tiles(self, xs: np.ndarray, ys: np.ndarray, tile_level: int):
        """The 2^L x 2^L blocks of each chart (L = tile_level) as receiver tiles: (node index of
        the block, (x0, y0, x1, y1) lightmap pixel box) per tile. xs, ys: texels in leaf order."""
        starts = np.flatnonzero(np.r_[True, self._block_change(tile_level)])
        ends = np.r_[starts[1:], self.leaf_count]
        index = {(int(a), int(b)): i for i, (a, b) in enumerate(zip(self.lo, self.hi))}
        nodes = np.array([index[(int(a), int(b))] for a, b in zip(starts, ends)], dtype=np.int64)
        boxes = np.column_stack([np.minimum.reduceat(xs, starts), np.minimum.reduceat(ys, starts),
                                 np.maximum.reduceat(xs, starts) + 1, np.maximum.reduceat(ys, starts) + 1])
        return nodes, boxes

    def _block_change(self, level: int) -> np.ndarray:
        block = self.leaf_code >> np.int64(2 * level)
        return (block[1:] != block[:-1]) | (self.leaf_chart[1:] != self.leaf_chart[:-1])

    def node_range(self, first_leaf: int, end_leaf: int) -> tuple[int, int]:
        """Node indices [first, end) whose walk covers exactly the leaves [first_leaf, end_leaf)."""
        return int(self.leaf_start[first_leaf]), int(self.leaf_start[end_leaf])


def build_tree(xs: np.ndarray, ys: np.ndarray, chart: np.ndarray, chart_box: np.ndarray) -> EmitterTree:
    """Quadtree over covered texels (xs, ys) of charts `chart`, boxes (x0, y0, w, h) per chart."""
    xs, ys, chart = (np.asarray(a, dtype=np.int64) for a in (xs, ys, chart))
    if len(xs) == 0:
        raise ValueError("pbgi: no covered lightmap texel to build an emitter hierarchy from")
    box = np.asarray(chart_box, dtype=np.int64)
    lx, ly = xs - box[chart, 0], ys - box[chart, 1]
    code = morton2(lx, ly)
    order = np.lexsort((code, chart))
    code, chart_sorted = code[order], chart[order]
    count = len(order)
    side = int(max(box[:, 2].max(), box[:, 3].max()))
    top = max(int(np.ceil(np.log2(max(side, 1)))), 0)
    los, his, levels = [], [], []
    for level in range(top + 1):
        block = code >> np.int64(2 * level)
        new = np.r_[True, (block[1:] != block[:-1]) | (chart_sorted[1:] != chart_sorted[:-1])]
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
                       level_nodes=level_nodes, level_offsets=level_offsets.astype(np.int64),
                       leaf_code=code, leaf_chart=chart_sorted)
