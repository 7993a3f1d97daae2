"""Lightmap UV unwrap of `pbgi`: planar projection by dominant normal axis, then shelf packing.

The article projects every face on the dominant axis of its normal and packs the small
charts into one texture. Here a chart is a connected set of triangles (sharing a welded edge)
with the same dominant axis and sign (two |normal| components within AXIS_TIE are a tie, which
the lower axis takes: a 45-degree face must not change its axis with the rounding of the
scene's unit): locally a height field over that axis plane (planar
walls become one chart, a sphere six caps). A patch can still fold over itself globally (a
helical ramp); the method detects that on the GL and passes such charts back in `split`.
Two triangles of a key also join when an unshared edge of one runs along an unshared edge of
the other from a common vertex, on either side of it in projection (a T-junction: a vertex in the middle of
the neighbour's edge leaves that edge unshared; the floor of big_floor, two triangles, fell
apart into two charts each with the whole floor's box when one of them was split). A chart's
projected coordinates are rotated to their principal axes when the box along them has at most
half the area of the box along the projection axes (a thin diagonal chart, a sliver: its axis
box was mostly empty, 74^2 texels for a zero-area sliver across big_floor's floor). Every chart
is mapped with one uniform scale `s` (texels per unit length, the same for all charts) into a box of
ceil(s w + 0.51) by ceil(s h + 0.51) texels, the chart starting half a texel inside its box:
the conservatively rasterised chart (texels its surface overlaps) stays inside its own box,
and the resolve clamps its bilinear footprint to the box, so charts never bleed into each
other. A chart smaller than a texel costs one texel (real scenes have thousands of
them: sponza 7,000 charts, conference 18,000; with a texel of margin on each side, 9 texels
per chart, sponza's 256^2 lightmap fell to 0.09 texels per metre and conference did not fit).
`s` is the largest scale (bisection) at which a shelf packing of the boxes fits the lightmap.

Lightmap size (texel density rule): given a target density D (texels per unit length of the
coordinates; the method passes its `texel_density` per scene radius divided by the radius), the
resolution is the smallest side R in [MIN_RESOLUTION, max_resolution] at which the charts pack
at density D (bisection on R); `s` is then the largest density that fits R (>= D). When even
max_resolution cannot hold D, R = max_resolution and `s` < D. So a scene gets lightmap texels
in proportion to its surface area (about area * D^2 / fill, fill ~ 0.6) until the cap.

All coordinates are the GPU's re-centred float coordinates; the chart map of triangle t is the
affine map uv = (row0 . p + row0.w, row1 . p + row1.w) in texel units (texel (i, j) covers
[i, i+1] x [j, j+1]).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


MIN_RESOLUTION = 16
CHART_OFFSET = 0.5   # texels between a chart box's low corner and the chart's extent
END_MARGIN = 0.01    # at least this many texels between the chart's extent and its box's high end
COLLINEAR_COSINE = 1e-6  # two edges from a vertex run along each other when 1 - cos is below this
SECTOR_OVERLAP_RAD = 1e-4   # ... and their triangles meet side by side when their angles there overlap by at most this
ROTATED_BOX_GAIN = 0.5   # a chart's box follows its principal axes when that at least halves its area
AXIS_TIE = 1e-9         # |normal| components this close count as equal (the lowest axis wins)


class LightmapTooSmall(ValueError):
    """The charts cannot be packed into the requested lightmap resolution."""


@dataclass
class Unwrap:
    resolution: int
    scale: float                 # texels per metre, all charts
    chart_of_triangle: np.ndarray   # (T,) int64
    chart_axis: np.ndarray          # (C,) dominant axis 0/1/2
    chart_area_m2: np.ndarray       # (C,) true surface area of the chart
    chart_box: np.ndarray           # (C, 4) int64 x0, y0, width, height of the chart's box in texels
    rows: np.ndarray                # (T, 2, 4) float64 affine texel map per triangle
    face_normal: np.ndarray         # (T, 3) unit geometric normals
    axis_cosine: np.ndarray         # (T,) |n[axis of its chart]| >= 1/sqrt(3)

    @property
    def chart_count(self) -> int:
        return int(len(self.chart_axis))


def _weld(vertices: np.ndarray, tolerance: float) -> np.ndarray:
    keys = np.round(vertices / tolerance).astype(np.int64)
    _, ids = np.unique(keys, axis=0, return_inverse=True)
    return ids.reshape(-1)


def _sector(vertices, faces, tri, corner, u, w):
    """(start, length) of triangle `tri`'s angle at its corner `corner`, in the plane basis (u, w)."""
    f = faces[tri]
    p = vertices[f[np.arange(len(tri)), corner]]
    ang = []
    for k in (1, 2):
        d = vertices[f[np.arange(len(tri)), (corner + k) % 3]] - p
        ang.append(np.arctan2(np.einsum("ij,ij->i", d, w), np.einsum("ij,ij->i", d, u)))
    diff = np.mod(ang[1] - ang[0], 2 * np.pi)
    short = diff <= np.pi
    return np.where(short, ang[0], ang[1]), np.where(short, diff, 2 * np.pi - diff)


def _disjoint_sectors(vertices, faces, normal, first, second) -> np.ndarray:
    """For pairs of triangles (tri, corner) meeting at a vertex: True where their angles at that
    vertex, projected on the plane of `normal`, overlap by at most SECTOR_OVERLAP_RAD (the
    triangles do not overlap there in projection)."""
    helper = np.where(np.abs(normal[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    w = np.cross(normal, u)
    s1, l1 = _sector(vertices, faces, *first, u, w)
    s2, l2 = _sector(vertices, faces, *second, u, w)
    overlap = np.zeros(len(s1))
    for k in (-1, 0, 1):
        s2k = s2 + 2 * np.pi * k
        overlap = np.maximum(overlap, np.minimum(s1 + l1, s2k + l2) - np.maximum(s1, s2k))
    return overlap <= SECTOR_OVERLAP_RAD


def dominant_axis(normal: np.ndarray) -> np.ndarray:
    """Index of each row's largest |component|; components within AXIS_TIE of the largest tie
    and the lowest index wins, so a 45-degree face keeps its axis under rounding noise."""
    mag = np.abs(normal)
    return np.argmax(mag >= mag.max(axis=1, keepdims=True) - AXIS_TIE, axis=1)


def find_charts(vertices: np.ndarray, faces: np.ndarray, tolerance: float, split=(), shading_normals=None):
    """Chart id per triangle, chart axis, face normals and areas. Charts listed in `split`
    (ids of an earlier call with the same arguments) become one chart per triangle. With
    `shading_normals` (per vertex), each face normal is turned to the side of its corners'
    shading normals, so a triangle's winding does not change its chart (surfaces are two-sided)."""
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    double_area = np.linalg.norm(cross, axis=1)
    normal = cross / np.maximum(double_area, 1e-300)[:, None]
    if shading_normals is not None:
        sn = np.asarray(shading_normals, dtype=np.float64)
        corner_sum = sn[faces[:, 0]] + sn[faces[:, 1]] + sn[faces[:, 2]]
        normal[np.einsum("ij,ij->i", normal, corner_sum) < 0] *= -1.0
    axis = dominant_axis(normal)
    key = axis * 2 + (normal[np.arange(len(faces)), axis] >= 0)
    wid = _weld(vertices, tolerance)[faces]                       # (T, 3) welded vertex ids
    edges = np.concatenate([wid[:, [0, 1]], wid[:, [1, 2]], wid[:, [2, 0]]])
    edges.sort(axis=1)
    owner = np.tile(np.arange(len(faces)), 3)
    rows = np.column_stack([edges, np.tile(key, 3)])
    order = np.lexsort(rows.T[::-1])
    rows, owner = rows[order], owner[order]
    same = np.all(rows[1:] == rows[:-1], axis=1)                  # consecutive triangles sharing an edge and a key
    a, b = owner[:-1][same], owner[1:][same]
    # T-junctions: an edge left unshared because its neighbour is split at a point of it is
    # linked to the unshared edge that runs along it from a common vertex (same direction), when
    # the two triangles (same key) lie on either side of it in the chart's projection plane
    # (disjoint angles at the vertex): the link the shared edge gave before the split
    shared = np.zeros(len(rows), dtype=bool)
    shared[1:] |= same
    shared[:-1] |= same
    lone = order[~shared]                                         # indices into the (3T) edge list
    etri, ek = lone % len(faces), lone // len(faces)              # edge k runs from corner k to k + 1
    if len(lone):
        rays = []
        for c, o in ((ek, (ek + 1) % 3), ((ek + 1) % 3, ek)):     # each unshared edge from both ends
            d = vertices[faces[etri, o]] - vertices[faces[etri, c]]
            d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
            rays.append((etri, c, wid[etri, c], d))
        rtri = np.concatenate([r[0] for r in rays])
        rcorner = np.concatenate([r[1] for r in rays])
        rvert = np.concatenate([r[2] for r in rays])
        rdir = np.concatenate([r[3] for r in rays])
        rkey = key[rtri]
        ro = np.lexsort((rdir[:, 2], rdir[:, 1], rdir[:, 0], rkey, rvert))
        rtri, rcorner, rvert, rdir, rkey = rtri[ro], rcorner[ro], rvert[ro], rdir[ro], rkey[ro]
        cand = np.flatnonzero((rvert[1:] == rvert[:-1]) & (rkey[1:] == rkey[:-1]) & (rtri[1:] != rtri[:-1])
                              & (np.einsum("ij,ij->i", rdir[1:], rdir[:-1]) >= 1.0 - COLLINEAR_COSINE))
        if len(cand):
            plane_normal = np.eye(3)[axis[rtri[cand]]]   # the chart's projection plane
            ok = _disjoint_sectors(vertices, faces, plane_normal, (rtri[cand], rcorner[cand]),
                                   (rtri[cand + 1], rcorner[cand + 1]))
            a = np.concatenate([a, rtri[cand][ok]])
            b = np.concatenate([b, rtri[cand + 1][ok]])
    graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(len(faces), len(faces)))
    count, chart = connected_components(graph, directed=False)
    split = np.asarray(sorted(set(int(c) for c in split)), dtype=np.int64)
    if len(split):
        alone = np.isin(chart, split)
        chart = chart.copy()
        chart[alone] = count + np.arange(int(alone.sum()))
        _, chart = np.unique(chart, return_inverse=True)
        count = int(chart.max()) + 1
    chart_axis = np.zeros(count, dtype=np.int64)
    chart_axis[chart] = axis
    chart_area = np.bincount(chart, weights=0.5 * double_area, minlength=count)
    return chart.astype(np.int64), chart_axis, normal, chart_area


def shelf_pack(widths: np.ndarray, heights: np.ndarray, size: int):
    """(x, y) of each box in a size x size square, tallest first on shelves (a shelf takes boxes
    while their widths fit, its height is its first box's); None if it does not fit."""
    order = np.argsort(-np.asarray(heights), kind="stable")
    w = np.asarray(widths, dtype=np.int64)[order]
    h = np.asarray(heights, dtype=np.int64)[order]
    pos = np.zeros((len(w), 2), dtype=np.int64)
    if len(w) == 0:
        return pos
    if int(w.max()) > size:
        return None
    run = np.concatenate([[0], np.cumsum(w)])
    k = y = 0
    while k < len(w):   # one shelf per step: boxes k .. j - 1
        if y + int(h[k]) > size:
            return None
        j = int(np.searchsorted(run, run[k] + size, side="right")) - 1
        pos[order[k:j], 0] = run[k:j] - run[k]
        pos[order[k:j], 1] = y
        y += int(h[k])
        k = j
    return pos


def unwrap(vertices: np.ndarray, faces: np.ndarray, resolution: int, tolerance: float, split=(),
           density: float | None = None, shading_normals=None) -> Unwrap:
    """Charts, packing and per-triangle texel maps (`split`: see find_charts). With `density`
    (texels per unit length), `resolution` is the largest lightmap side allowed and the side used is
    the smallest that packs the charts at that density (module docstring); without it the
    lightmap is `resolution`^2."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    chart, chart_axis, normal, chart_area = find_charts(vertices, faces, tolerance, split, shading_normals)
    count = len(chart_axis)
    u_axis = (chart_axis + 1) % 3
    v_axis = (chart_axis + 2) % 3
    corner_chart = np.repeat(chart, 3)
    corners = vertices[faces.reshape(-1)]
    cu = corners[np.arange(len(corners)), u_axis[corner_chart]]
    cv = corners[np.arange(len(corners)), v_axis[corner_chart]]
    cos_t, sin_t = chart_rotation(cu, cv, corner_chart, count)
    cu, cv = (cos_t[corner_chart] * cu + sin_t[corner_chart] * cv,
              -sin_t[corner_chart] * cu + cos_t[corner_chart] * cv)
    lo_u = np.full(count, np.inf); hi_u = np.full(count, -np.inf)
    lo_v = np.full(count, np.inf); hi_v = np.full(count, -np.inf)
    np.minimum.at(lo_u, corner_chart, cu); np.maximum.at(hi_u, corner_chart, cu)
    np.minimum.at(lo_v, corner_chart, cv); np.maximum.at(hi_v, corner_chart, cv)
    extent_u, extent_v = hi_u - lo_u, hi_v - lo_v

    def boxes(scale):
        return (np.ceil(scale * extent_u + CHART_OFFSET + END_MARGIN).astype(np.int64),
                np.ceil(scale * extent_v + CHART_OFFSET + END_MARGIN).astype(np.int64))

    if density is not None:
        resolution = fit_resolution(boxes(float(density)), int(resolution))
    largest = max(float(extent_u.max()), float(extent_v.max()), 1e-300)
    hi = (resolution - 2) / largest
    lo = hi * 1e-6
    if shelf_pack(*boxes(lo), resolution) is None:
        raise LightmapTooSmall(f"{count} charts do not fit a {resolution}^2 lightmap even at the smallest "
                               f"texel density: raise max_lightmap_resolution")
    if shelf_pack(*boxes(hi), resolution) is not None:
        lo = hi
    elif density is not None and density < hi and shelf_pack(*boxes(float(density)), resolution) is not None:
        lo = float(density)   # the target fits: the result is never below it
    for _ in range(40):  # bisection on log scale: packing is monotone up to shelf effects
        if hi / lo < 1.0 + 1e-4:
            break
        mid = np.sqrt(lo * hi)
        if shelf_pack(*boxes(mid), resolution) is None:
            hi = mid
        else:
            lo = mid
    scale = lo
    bw, bh = boxes(scale)
    pos = shelf_pack(bw, bh, resolution)
    rows = np.zeros((len(faces), 2, 4))
    t = np.arange(len(faces))
    rows[t, 0, u_axis[chart]] = scale * cos_t[chart]
    rows[t, 0, v_axis[chart]] = scale * sin_t[chart]
    rows[t, 1, u_axis[chart]] = -scale * sin_t[chart]
    rows[t, 1, v_axis[chart]] = scale * cos_t[chart]
    rows[:, 0, 3] = (pos[chart, 0] + CHART_OFFSET) - scale * lo_u[chart]
    rows[:, 1, 3] = (pos[chart, 1] + CHART_OFFSET) - scale * lo_v[chart]
    axis_cos = np.abs(normal[t, chart_axis[chart]])
    return Unwrap(resolution=int(resolution), scale=float(scale), chart_of_triangle=chart, chart_axis=chart_axis,
                  chart_area_m2=chart_area, chart_box=np.column_stack([pos, bw, bh]), rows=rows,
                  face_normal=normal, axis_cosine=axis_cos)


def chart_rotation(cu: np.ndarray, cv: np.ndarray, corner_chart: np.ndarray, count: int):
    """(cos, sin) per chart of the in-plane rotation of its projected corners (cu, cv): the
    principal axes of the corners when the box along them has at most ROTATED_BOX_GAIN times the
    area of the box along the projection axes (a thin diagonal chart, a sliver, whose axis box
    is mostly empty), else no rotation (a square or an axis-aligned chart keeps its box)."""
    n = np.maximum(np.bincount(corner_chart, minlength=count), 1)
    mu = np.bincount(corner_chart, weights=cu, minlength=count) / n
    mv = np.bincount(corner_chart, weights=cv, minlength=count) / n
    du, dv = cu - mu[corner_chart], cv - mv[corner_chart]
    suu = np.bincount(corner_chart, weights=du * du, minlength=count)
    svv = np.bincount(corner_chart, weights=dv * dv, minlength=count)
    suv = np.bincount(corner_chart, weights=du * dv, minlength=count)
    theta = 0.5 * np.arctan2(2.0 * suv, suu - svv)
    c, s = np.cos(theta), np.sin(theta)

    def extent_product(c, s):
        ru = c[corner_chart] * cu + s[corner_chart] * cv
        rv = -s[corner_chart] * cu + c[corner_chart] * cv
        out = []
        for r in (ru, rv):
            lo, hi = np.full(count, np.inf), np.full(count, -np.inf)
            np.minimum.at(lo, corner_chart, r)
            np.maximum.at(hi, corner_chart, r)
            out.append(hi - lo)
        return out[0] * out[1]

    rotate = extent_product(c, s) <= ROTATED_BOX_GAIN * extent_product(np.ones(count), np.zeros(count))
    return np.where(rotate, c, 1.0), np.where(rotate, s, 0.0)


def fit_resolution(box_sizes, max_resolution: int) -> int:
    """Smallest lightmap side in [MIN_RESOLUTION, max_resolution] whose shelf packing holds boxes
    of sizes `box_sizes` (widths, heights); max_resolution if none does."""
    widths, heights = box_sizes
    lo, hi = min(MIN_RESOLUTION, max_resolution), int(max_resolution)
    if shelf_pack(widths, heights, hi) is None:
        return hi
    while lo < hi:   # packing success is monotone in the side (the shelves only get longer)
        mid = (lo + hi) // 2
        if shelf_pack(widths, heights, mid) is None:
            lo = mid + 1
        else:
            hi = mid
    return hi


def chart_image(unwrap_: Unwrap) -> np.ndarray:
    """(resolution, resolution) int64 image [y, x]: the chart whose box holds each texel, -1 in none."""
    img = np.full((unwrap_.resolution, unwrap_.resolution), -1, dtype=np.int64)
    for c, (x0, y0, w, h) in enumerate(unwrap_.chart_box):
        img[y0:y0 + h, x0:x0 + w] = c
    return img
