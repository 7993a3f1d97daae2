"""`dss`: Deep Screen Space (Nalbach, Ritschel, Seidel, I3D 2014) for one-bounce diffuse light.

As reimplemented for the comparison in the Forward Light Cuts paper (Sec. 7, Table 2):
one-bounce, unshadowed diffuse indirect light from surfels of all scene geometry (hidden
surfaces included), splatted into an interleaved multi-resolution screen-space framebuffer.

Every frame, all of the scene's triangles, hidden ones included (no camera culling), go
through the tessellator as patches; the control stage picks tessellation levels from each
triangle's edge lengths and area so that sub-triangles have about the target surfel area
`a = total scene area / surfel_count`: the surfel density is uniform in object space, and a
triangle smaller than `a` gives one surfel at its centroid (the tessellator refines, it never
decimates: the contrast with Forward Light Cuts; the original DSS adapts the density to the
projected size). The geometry stage turns each sub-triangle into a surfel (centroid y, exact
area A, the triangle's normal n_y, the shading normal at y, and the shadowed direct light on
both sides of the shading normal, B = rho E, from the shared shadow maps, E averaged over the
4^k centroids of the sub-triangle's k-fold regular subdivision, k = `irradiance_splits`)
appended to a buffer; its atomic counter doubles as the splat's indirect draw command. The
buffer is sized exactly by a count-only run of the same tessellation in prepare() (the count
depends on geometry only). Triangles that would need more than the tessellator's 64 levels are
pre-split once in prepare() into K x K sub-patches of their regular subdivision (one patch
record per sub-triangle; the levels themselves are chosen every frame on the GPU).

Each lit surfel is then splatted (additive RGBA32F blending) as screen-aligned quads into a
multi-resolution, interleaved framebuffer: a receiver x at view depth z takes the surfel at
level 0 (full resolution) while |x - y| < 2 S p(z) (p = pixel footprint), at level l in the
shell [2^l, 2^(l+1)) S p(z), and at the coarsest level beyond: fine sampling where the
contribution varies fast, coarse sampling far away (the paper's shell splatting). Each level is
split into M x M interleaved sub-buffers and each surfel goes to one of them per level (hashed,
weight M^2, so the expectation is the full sum). A receiver adds the unshadowed transfer

    E(x) += B_side(y) / pi <n_x, w>+ |<n_y, w>| A / d2

with d2 the near field of a surfel of area A at distance d (bench/gl/near_field.py, shared with
the VPL methods): by default max(d^2, A / pi), the clamp at the surfel's own radius, so a surfel
never lights a receiver more than its exitance B (the point term's 1/d^2 gave sponza spikes:
relMSE 0.92-1.47 by surfel count, 20-41% of the squared error in 20 pixels; with the bound
0.41-0.48; NOTES.md); `max(eps, d)^2` (clamp) and `d^2 + A / pi` (disc_element) remain options.
(Lambertian emission of the side of the surfel's shading normal the receiver is on, n_y its
geometric normal: Mitsuba's twosided diffuse with shading normals, as `manylights`),
only within the surfel's cut radius r = R sqrt(lum(B) / (threshold lum(B_max))): the distance at
which its contribution per unit emitting area, B / (pi^2 d^2), falls under `threshold` times the
brightest surfel's at one scene radius R. `threshold` 0 cuts nothing; the threshold is relative
so that it does not depend on the scene's units, light power or surfel density. Then each level
is unshuffled and blurred over (2 blur_radius + 1)^2 same-surface neighbours (normal and
tangent-plane tests), the coarse levels are upsampled with geometry-aware bilinear weights and
summed (a pixel with no grid receiver of its surface near: rule (4)), and the receiver's rho/pi is
applied: L(x) = rho_x / pi sum_levels E_l(x).

Level l's receiver of level pixel X is the full-resolution pixel X 2^l (the last node of a row
or column on the screen's last pixel), and the upsampling puts X's bilinear node exactly there:
the receivers nest, so at a pixel that is a receiver of every level each level decides the
shell at the same point and every surfel is counted by exactly one level (the shells partition
the surfels: the image there equals the brute-force sum over the surfels, tested).

Rules recorded here: (1) the surfel's radiosity is the mean of rho E over 4^k points of its
sub-triangle, because a point sample at the centroid misjudges sub-triangles that a spot cone's
edge crosses (NOTES.md: big_floor). (2) The emitter's incident cosine and side use the shading
normal, the geometric term the face normal (Mitsuba's convention; the face-normal cosine is
biased on smooth-shaded meshes). (3) A surfel's interleaved sub-buffer (per level and frame) is
a hash of the frame's seed, its sub-triangle (sub-patch and tessellation coordinates) and its
triangle's key: the triangle's centroid relative to the scene's centre, in units of the scene
radius, quantised to 2^-20 (`triangle_keys`; float64 in prepare, stored in the triangle
record's normal.w). The key does not depend on the triangle's index, winding, the scene's unit
or position, so the sampling pattern follows the geometry: re-triangulating part of a scene
changes the surfels of the split triangles only, not the pattern of the whole scene.
(4) Thin faces (issue #23). A pixel takes a coarse level l from the level's grid receivers on
its own surface (normal and tangent-plane tests): the four bilinear nodes, else the 3 x 3 around
the nearest. A face one or two pixels wide (the side of a column, a moulding, a block's step
seen edge-on) has none at level 2 (grid receivers every 4 pixels) and often none at level 1.
Such pixels get receivers of their own: each level l >= 1 has a second slot of the same layout,
whose receiver of level pixel X is the first pixel (row by row) of X's 2^l x 2^l block that has
no grid receiver of its surface (the same test as the upsampling's; none if every pixel has
one). Every surfel's quad of level l is drawn over both slots (same box, same interleaved
class), the slot is blurred like the level, and such a pixel takes the thin-face receiver of its
own block if on its surface, else those of its surface in the 3 x 3 around it: the refinement
at discontinuities of multi-resolution splatting (Nichols and Wyman 2009), the fine sampling
where the coarse one has no sample of the surface. Where that fails too (two thin surfaces in
one block), the mean of the level's grid receivers of its orientation (the normal test alone)
closer than half the level's inner shell radius, 2^(l-1) S footprints, searched within S/2 level
pixels (`orient_radius`, at most 8): the level holds the unshadowed light of surfels at least
2^l S footprints away, which changes with the receiver's orientation at once but with its
position only over the shell's radius; with none, the level adds nothing there. The first
version took plain bilinear weights over the covered grid nodes there, i.e. another surface's
irradiance: on sponza 4% of the pixels took it, held 78% of the relMSE (2-3x too bright where
the reference is dark) and made the ladder rise (relMSE 0.458, 0.553, 0.466, while the plain
sum, levels 1 without interleaving or blur, falls 0.095, 0.081, 0.075: the surfel count only
changed which wrong values those pixels drew). Cost: every surfel draws a second quad per level >= 1 (llvmpipe pays per
primitive): sponza's frame at 320x180 655 -> 870 ms, sibenik's 904 -> 1139 ms (NOTES.md); a
depth mask of the slots' receivers (1 where a receiver is) lets the splat's early depth test
drop empty slot pixels before shading (10% of the splat). Figures: NOTES.md, "Thin faces". The
paper's text is not in the project's papers folder: the thin-face slots are our reading of its
multi-resolution splatting's refinement, not a quoted step.

(5) The contact's near field (issue #23; on by default since 2026-12-03, `exact_reach` 1). A
receiver closer to a surfel's centre than k = `exact_reach` times the surfel's reach (its farthest
corner from the centre) takes the exact transfer from the surfel's sub-triangle: E = B F, F the form
factor from the receiver to the part of the sub-triangle above its tangent plane (Lambert's contour
integral over the clipped triangle, at most 4 corners; a receiver within tau = max(1e-4 sqrt(A),
1e-2 eps) of the emitter's plane gets nothing, so a surface never lights itself; where the surfel's
shading side is not its geometric side, the point term). Why: the point term's emitter cosine,
taken at the centre, is ~0 for a receiver in or near the surfel's plane, but a receiver at height
h beside a perpendicular lit surface gets F -> 1/2 of its radiosity as h -> 0, almost all from
within a few h of the contact: lost_empire's 20 worst pixels (a wall row under a lit ceiling whose
0.5 m^2 voxel triangles are one surfel each) read 0.026 where Mitsuba has 0.15.
Two further steps make it faithful at the defaults' surfel size (sponza 0.9 m^2, reach ~1.2 m):
(a) the contact's radiosity. B is not uniform over a surfel, and a contact sees the emitter
within ~h of its closest point c on the sub-triangle (at height h over a plane, the share
s^2 / (s^2 + h^2) of the form factor comes from within s of the foot). So the exact transfer
takes B' = B_c w + B (1 - w), w = s^2 / (s^2 + h^2), h = |c - x|, s = `contact_scale` (0.5)
times the reach, B_c = rho E evaluated by the shadow maps at the point a quarter of the way from
c to the centre (inside the sub-triangle, off the edge where the adjacent surface's own
shadow-map depth meets it: at c itself rooms/main's relMSE rose 7%): a contact in the shadow of
a column's base gets the shadow's light, not the surfel's partly lit mean (with the mean alone,
k = 4: sponza's relMSE 0.149 -> 0.244). (b) The near field is not interleaved: a surfel whose
near-field sphere spans at least 4 pixels on the screen (NEAR_SPLIT_PIXELS) draws it in a
second pass into every interleaved sub-buffer with weight 1 (the far field as before, hashed,
weight M^2): a near field taken from one of M^2 sub-buffers with weight M^2 is the variance of a
few large surfels on a few pixels (holodeck's top-20 share 0.285 -> 0.328 with it interleaved).
A smaller near field keeps the point term in the hashed pass (llvmpipe pays per primitive: M^2
quads per level for each of ~10^5 small surfels). The surfel record carries two corners and the
albedo (112 bytes instead of 80). Cost: the splat about doubles (sponza 1.7 -> 3.9 s, conference
5.3 -> 11 s at 320x180 on llvmpipe). Figures: NOTES.md, "Contact light at the defaults".

With threshold 0, levels 1 and interleave 1 (and blur_radius 0) this is the exact sum over the
surfels, which converges to the continuous one-bounce integral (and to jittered `manylights`,
emission `lambert`) as surfel_count grows (tests/methods/test_dss.py).

Parameters:

<!-- parameters: generated from the Param declarations by `gibench manuals --write` -->
| parameter         | default   | range                          | meaning |
|-------------------|-----------|--------------------------------|---|
| surfel_count      | 8192      | 1 .. 100000000                 | target surfels over the whole scene (target area = total area / count); small triangles still give one surfel each (quality knob; sweep 1024, 4096, 16384, 65536) |
| threshold         | 0.002     | 0.0 .. 100.0                   | cut radius: contribution per unit area below threshold x the brightest surfel's at one scene radius (0: no cut) (quality knob; sweep 0.05, 0.01, 0.002, 0.0005) |
| irradiance_splits | 1         | 0 .. 3                         | surfel irradiance: mean over the 4^k centroids of the sub-triangle's k-fold subdivision (0: the centroid alone) (quality knob) |
| levels            | 3         | 1 .. 6                         | resolution levels of the splat framebuffer |
| interleave        | 2         | 1 .. 8                         | M: M x M interleaved sub-buffers per level (1: none) |
| shell_pixels      | 8.0       | 0.25 .. 256.0                  | S: level 0 takes receivers within 2 S pixel footprints of a surfel, level l those in [2^l, 2^(l+1)) S (splat cost grows as S^2) (quality knob; sweep 2.0, 4.0, 8.0, 16.0) |
| blur_radius       | 1         | 0 .. 8                         | blur window (2 b + 1)^2 in level pixels |
| blur_normal_cos   | 0.9       | -1.0 .. 1.0                    | blur/upsample: minimum cosine between receiver normals |
| blur_plane_pixels | 1.0       | 0.0 .. 10000.0                 | blur/upsample: maximum tangent-plane distance in pixel footprints |
| eps_rel           | 0.0001    | 1e-07 .. 1.0                   | distance clamp eps relative to the scene radius |
| near_field        | footprint | clamp, disc_element, footprint | how an emitter's 1/d^2 is bounded near it, d the emitter-receiver distance, A the area it stands for: clamp max(eps, d)^2; disc_element d^2 + A / pi (a disc's form factor); footprint max(d^2, s A / pi) (a clamp at the radius of s times the emitter's area); each at least eps^2 |
| near_field_scale  | 1.0       | 0.001 .. 100.0                 | s of near_field=footprint: the clamp's area as a fraction of the area the emitter stands for |
| exact_reach       | 1.0       | 0.0 .. 1000.0                  | a receiver closer to a surfel's centre than this many times its reach (farthest corner) takes the exact form factor of its sub-triangle instead of the point term, in every interleaved sub-buffer with weight 1 (0: the point term everywhere) |
| contact_scale     | 0.5       | 0.0 .. 100.0                   | with exact_reach > 0: the exact transfer takes the radiosity at the receiver's contact (the emitter's closest point, rho E there by the shadow maps) for the share s^2 / (s^2 + h^2) of it, h the distance to that point, s this times the surfel's reach, the surfel's mean for the rest (0: the mean alone) |
| max_surfels       | 16000000  | 1 .. 100000000                 | skip a scene whose surfel count exceeds this |
<!-- end of parameters -->

Quality ladder (`gibench run`): (surfel_count, threshold) = (2048, 0.01), (8192, 0.002) (default),
(32768, 0.0005): finer surfels and a farther cut radius together, as the paper's quality settings
trade splat fill for accuracy.

Example:

    gibench run --scenes cornell_spot --methods dss --res 128x96 --defaults-only

Stages: `surfels` (tessellation, surfel shading), `deinterleave` (level receivers in the
interleaved layout), `splat`, `unshuffle_blur` (unshuffle, blur, upsample, sum), after the
shared `gbuffer_shadow` and `direct_light`. Needs: gbuffer, shadow_map, direct.

Scale: every triangle gives at least one surfel, so a 10M-triangle scene needs a 10M-surfel
buffer (112 B each, 1.1 GB; 80 B with `exact_reach` 0) beside its 1.1 GB triangle records;
`max_surfels` (16M) bounds that.
These buffers exceed the GL_MAX_SHADER_STORAGE_BLOCK_SIZE llvmpipe reports (128 MB) but are bound
whole; llvmpipe and desktop GPUs (2 GB and more) address them. The cost is linear in the surfel
count: the series' slope is in the report's cost-vs-triangles plot.

Measurements: NOTES.md beside this file holds the figures behind the rules above and the
history of the receiver placement and the sampling keys.

In motion (bench.run.sequence): It keeps nothing between states: a frame where anything moved
prepares it again, surfel generation from the triangles included. Measured update per moved frame at
160x90, light (rooms_light_sweep) 32 ms, camera (sponza_camera_walk) 204 ms, geometry
(cornell_spot_moving_block) 59 ms (`python -m studies.motion_costs`, 2 cores shared with other
work).

Stress limit coplanar: coincident coplanar faces both carry surfels, so the overlapped area emits twice while Mitsuba's rays see one surface (cornell_box 64x48: mean +6.3%).
"""
from __future__ import annotations

from pathlib import Path

import moderngl
import numpy as np

from bench.gl import load_program, set_uniforms
from bench.gl.near_field import (NEAR_FIELD_DEFAULT, NEAR_FIELD_DOC, NEAR_FIELDS, NEAR_SCALE_DEFAULT,
                                   NEAR_SCALE_DOC, NEAR_SCALE_RANGE, near_field_defines)
from bench.protocol.method import FrameOutput, MethodBase, Param, SkipRow

SHADERS = Path(__file__).parent / "shaders"
DSS_DEFINES = {"BINDING_DSS_TRIANGLES": 3, "BINDING_DSS_PATCHES": 4, "BINDING_DSS_SURFELS": 5,
               "BINDING_DSS_COUNTER": 6, "NEAR_SPLIT_PIXELS": 4.0,
               "CONTACT_INSET": 0.25}
MAX_TESS_LEVEL = 64               # GL_MAX_TESS_GEN_LEVEL guaranteed by GL 4.x
TRIANGLES_PER_LEVEL_SQ = 1.5      # GL's triangle tessellation with all levels n makes ~1.5 n^2 triangles
SURFEL_BYTES = {False: 80, True: 112}   # std430 Surfel (dss_common.glsl), without / with the corners of exact_reach
COUNTER_INIT = np.array([0, 1, 0, 0, 0, 0], dtype=np.uint32)  # count, instances, first, base, pad, max lum
KEY_CELL_BITS = 20                # triangle keys: centroids quantised to 2^-20 scene radii
MAX_ORIENT_RADIUS = 8             # compose: same-orientation search window at most 17 x 17 level pixels


def orient_radius(shell_pixels: float) -> int:
    """Level pixels the compose pass searches for receivers of a pixel's orientation when none of
    its surface is near: half the level's inner shell radius (2^l S footprints = S level pixels),
    at least 1, at most MAX_ORIENT_RADIUS."""
    return int(min(MAX_ORIENT_RADIUS, max(1, shell_pixels // 2)))


def sub_triangle_edge(target_area: float) -> float:
    """Edge length matching a sub-triangle of `target_area` in GL's triangle tessellation
    (an equilateral triangle of side s at level n has T n^2 sub-triangles and n segments per
    edge, so s / n = sqrt(4 T a / sqrt(3)), T = TRIANGLES_PER_LEVEL_SQ)."""
    return float(np.sqrt(4.0 * TRIANGLES_PER_LEVEL_SQ * target_area / np.sqrt(3.0)))


def split_factors(tri: np.ndarray, target_area: float) -> np.ndarray:
    """K per triangle: the smallest K such that each sub-triangle of the K x K subdivision needs
    at most MAX_TESS_LEVEL (the levels the control shader would pick, divided by K)."""
    edges = np.stack([tri[:, 2] - tri[:, 1], tri[:, 0] - tri[:, 2], tri[:, 1] - tri[:, 0]], axis=1)
    edge_levels = np.linalg.norm(edges, axis=2) / sub_triangle_edge(target_area)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    inner = np.sqrt(area / (TRIANGLES_PER_LEVEL_SQ * target_area))
    need = np.maximum(edge_levels.max(axis=1), inner)
    return np.maximum(1, np.ceil(need / MAX_TESS_LEVEL)).astype(np.int64)


def triangle_keys(vertices: np.ndarray, faces: np.ndarray, center, radius: float) -> np.ndarray:
    """(T,) keys < 2^24 of the triangles from their centroids (float64, relative to the scene's
    centre and radius, quantised to 2^-KEY_CELL_BITS radii): a triangle keeps its key whatever its
    index, winding, the scene's unit or position, so the interleaved sub-buffer of its surfels
    (their sampling pattern) does not change when other triangles are added, removed or reordered."""
    v, f = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    centroid = v[f[:, 0]] + v[f[:, 1]]   # corner by corner: no (T, 3, 3) copy on a 10M-triangle scene
    centroid += v[f[:, 2]]
    centroid /= 3.0
    rel = (centroid - np.asarray(center, np.float64)) / max(float(radius), 1e-300)
    q = np.floor(np.clip(rel, -2.0, 2.0) * 2.0 ** KEY_CELL_BITS).astype(np.int64).view(np.uint64)
    h = np.full(len(q), 0x9E3779B97F4A7C15, dtype=np.uint64)
    with np.errstate(over="ignore"):
        for axis in range(3):   # splitmix64 steps over the three cell coordinates
            h = (h ^ q[:, axis]) * np.uint64(0xBF58476D1CE4E5B9)
            h ^= h >> np.uint64(31)
            h *= np.uint64(0x94D049BB133111EB)
            h ^= h >> np.uint64(29)
    return (h >> np.uint64(40)).astype(np.uint32)


def patch_records(split: np.ndarray) -> np.ndarray:
    """(P, 4) uint32 patch records (triangle, K, sub-triangle q, 0) with q < K^2."""
    per = split * split
    tri = np.repeat(np.arange(len(split), dtype=np.int64), per)
    start = np.repeat(np.cumsum(per) - per, per)
    q = np.arange(len(tri), dtype=np.int64) - start
    rec = np.zeros((len(tri), 4), dtype=np.uint32)
    rec[:, 0], rec[:, 1], rec[:, 2] = tri, np.repeat(split, per), q
    return rec


def level_layout(width: int, height: int, levels: int, interleave: int) -> tuple[np.ndarray, np.ndarray, tuple]:
    """Per slot (W_l, H_l, tile width, tile height) and atlas row offsets, and the atlas size. Slots
    0 .. levels - 1 are the levels' grid receivers; slot levels - 1 + l (l >= 1) holds level l's
    thin-face receivers (rule (4)), laid out as level l."""
    slots = 2 * levels - 1
    sizes = np.zeros((slots, 4), dtype=np.int32)
    rows = np.zeros(slots, dtype=np.int32)
    y = 0
    for slot in range(slots):
        lvl = slot if slot < levels else slot - levels + 1
        # level pixel X's receiver is full-resolution pixel min(X 2^l, size - 1): one more node
        # than ceil(size / 2^l) when needed, so that the last pixels lie between two nodes
        w, h = -(-(width - 1) // 2 ** lvl) + 1, -(-(height - 1) // 2 ** lvl) + 1
        tw, th = -(-w // interleave), -(-h // interleave)
        sizes[slot] = (w, h, tw, th)
        rows[slot] = y
        y += interleave * th
    return sizes, rows, (int(interleave * sizes[0, 2]), int(y))


class DeepScreenSpace(MethodBase):
    name = "dss"
    summary = "Deep Screen Space: tessellated surfels of all geometry splatted to interleaved multi-resolution buffers"
    ladder = ({"surfel_count": 2048, "threshold": 0.01}, {}, {"surfel_count": 32768, "threshold": 0.0005})
    stages = ("surfels", "deinterleave", "splat", "unshuffle_blur")
    needs = frozenset({"gbuffer", "shadow_map", "direct"})
    params = {
        "surfel_count": Param(8192, "target surfels over the whole scene (target area = total area / count); "
                              "small triangles still give one surfel each", 1, 100_000_000,
                              quality=True, sweep=(1024, 4096, 16384, 65536)),
        "threshold": Param(0.002, "cut radius: contribution per unit area below threshold x the brightest "
                           "surfel's at one scene radius (0: no cut)", 0.0, 100.0,
                           quality=True, sweep=(0.05, 0.01, 0.002, 0.0005)),
        "irradiance_splits": Param(1, "surfel irradiance: mean over the 4^k centroids of the sub-triangle's "
                                   "k-fold subdivision (0: the centroid alone)", 0, 3, quality=True),
        "levels": Param(3, "resolution levels of the splat framebuffer", 1, 6),
        "interleave": Param(2, "M: M x M interleaved sub-buffers per level (1: none)", 1, 8),
        "shell_pixels": Param(8.0, "S: level 0 takes receivers within 2 S pixel footprints of a surfel, "
                              "level l those in [2^l, 2^(l+1)) S (splat cost grows as S^2)", 0.25, 256.0,
                              quality=True, sweep=(2.0, 4.0, 8.0, 16.0)),
        "blur_radius": Param(1, "blur window (2 b + 1)^2 in level pixels", 0, 8),
        "blur_normal_cos": Param(0.9, "blur/upsample: minimum cosine between receiver normals", -1.0, 1.0),
        "blur_plane_pixels": Param(1.0, "blur/upsample: maximum tangent-plane distance in pixel footprints",
                                   0.0, 1e4),
        "eps_rel": Param(1e-4, "distance clamp eps relative to the scene radius", 1e-7, 1.0),
        "near_field": Param(NEAR_FIELD_DEFAULT, NEAR_FIELD_DOC, choices=NEAR_FIELDS),
        "near_field_scale": Param(NEAR_SCALE_DEFAULT, NEAR_SCALE_DOC, *NEAR_SCALE_RANGE),
        "exact_reach": Param(1.0, "a receiver closer to a surfel's centre than this many times its reach (farthest "
                             "corner) takes the exact form factor of its sub-triangle instead of the point term, "
                             "in every interleaved sub-buffer with weight 1 (0: the point term everywhere)",
                             0.0, 1000.0),
        "contact_scale": Param(0.5, "with exact_reach > 0: the exact transfer takes the radiosity at the receiver's "
                               "contact (the emitter's closest point, rho E there by the shadow maps) for the share "
                               "s^2 / (s^2 + h^2) of it, h the distance to that point, s this times the surfel's "
                               "reach, the surfel's mean for the rest (0: the mean alone)", 0.0, 100.0),
        "max_surfels": Param(16_000_000, "skip a scene whose surfel count exceeds this", 1, 100_000_000),
    }

    @classmethod
    def cost_terms(cls, params, size):
        # surfels generated from the triangles, splatted into the deep screen buffer's levels. Every
        # triangle makes at least one surfel, so the count is about surfel_count + triangles (conference:
        # 367 k surfels at 8192), and the row's `triangles` term carries that share. The exact near field's
        # fragments (exact_reach) scale with the projected area of the surfels near the camera, which no
        # term before the frame sees: a real view costs 30-55 us a surfel, big_floor 13, sphere_inside 117
        return {"surfels": params["surfel_count"], "pixel_levels": size.pixels * params["levels"]}

    def prepare(self, gpu, scene, facts, params, view) -> None:
        self.params = params
        ctx = gpu.ctx
        self.ctx = ctx
        levels, interleave = params["levels"], params["interleave"]
        target_area = facts.total_area_m2 / params["surfel_count"]
        tri = gpu.positions[gpu.faces.astype(np.int64)].astype(np.float64)
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        records = np.zeros((len(tri), 7, 4), dtype=np.float32)  # DssTriangle (surfels.glsl)
        records[:, :3, :3] = tri
        records[:, 3, :3] = normal
        records[:, 3, 3] = triangle_keys(scene.vertices, scene.faces, facts.scene_center, facts.scene_radius)
        records[:, 4:, :3] = gpu.normals[gpu.faces.astype(np.int64)]
        patches = patch_records(split_factors(tri, target_area))
        self.patch_count = len(patches)

        defines = dict(DSS_DEFINES, LEVELS=levels, SLOTS=2 * levels - 1, INTERLEAVE=interleave, MAX_TESS_LEVEL=MAX_TESS_LEVEL,
                       TRIANGLES_PER_LEVEL_SQ=TRIANGLES_PER_LEVEL_SQ, IRRADIANCE_SPLITS=params["irradiance_splits"],
                       EXACT_CONTACT=int(params["exact_reach"] > 0.0))
        self.surfel_bytes = SURFEL_BYTES[params["exact_reach"] > 0.0]   # the corners only where rule (5) reads them
        self.triangles = ctx.buffer(records.tobytes())
        self.patches = ctx.buffer(patches.tobytes())
        self.counter = ctx.buffer(COUNTER_INIT.tobytes())
        self.generate = load_program(ctx, SHADERS / "surfels.glsl", dict(defines, COUNT_ONLY=False))
        self.generate_vao = ctx.vertex_array(self.generate, [])
        sizes, rows, atlas = level_layout(view.width, view.height, levels, interleave)
        # the grid receivers' slots (the levels); the thin-face slots follow them in the atlas
        self.level_sizes, self.level_rows, self.atlas_size = sizes[:levels], rows[:levels], atlas

        # Receivers of every level (deinterleaved), splat accumulation, blurred levels, output.
        self.receiver_position = ctx.texture(atlas, 4, dtype="f4")
        self.receiver_normal = ctx.texture(atlas, 4, dtype="f4")
        self.splat_tex = ctx.texture(atlas, 4, dtype="f4")
        self.levels_tex = ctx.texture(atlas, 4, dtype="f4")
        self.indirect = ctx.texture((view.width, view.height), 4, dtype="f4")
        for t in (self.receiver_position, self.receiver_normal, self.splat_tex, self.levels_tex, self.indirect):
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        # depth 1 where a slot pixel has a receiver, 0 elsewhere (deinterleave.glsl): the splat's
        # early depth test drops the fragments of empty slot pixels before shading
        self.receiver_mask = ctx.depth_texture(atlas)
        self.receiver_fbo = ctx.framebuffer([self.receiver_position, self.receiver_normal], self.receiver_mask)
        self.splat_fbo = ctx.framebuffer([self.splat_tex], self.receiver_mask)
        self.splat_fbo.depth_mask = False
        self.levels_fbo = ctx.framebuffer([self.levels_tex])
        self.indirect_fbo = ctx.framebuffer([self.indirect])

        # The surfel count depends on the geometry only: count once, size the buffer exactly.
        counting = load_program(ctx, SHADERS / "surfels.glsl", dict(defines, COUNT_ONLY=True))
        try:
            counting_vao = ctx.vertex_array(counting, [])
            self._run_generation(counting, counting_vao, target_area, capacity=0)
            counting_vao.release()
        finally:
            counting.release()
        self.surfel_count = int(np.frombuffer(self.counter.read(4), dtype=np.uint32)[0])
        if self.surfel_count > params["max_surfels"]:
            raise SkipRow(f"scene '{scene.name}' gives {self.surfel_count} surfels, more than "
                          f"max_surfels={params['max_surfels']}")
        self.surfels = ctx.buffer(reserve=max(1, self.surfel_count) * self.surfel_bytes)
        self.target_area = target_area

        self.deinterleave = load_program(ctx, SHADERS / "deinterleave.glsl", defines)
        splat_defines = dict(defines, **near_field_defines(params["near_field"], params["near_field_scale"]))
        self.splat = load_program(ctx, SHADERS / "splat.glsl", dict(splat_defines, NEAR_PASS=0))
        # rule (5): the near field of every surfel in every interleaved sub-buffer, weight 1
        self.splat_near = (load_program(ctx, SHADERS / "splat.glsl", dict(splat_defines, NEAR_PASS=1))
                           if params["exact_reach"] > 0.0 else None)
        self.unshuffle = load_program(ctx, SHADERS / "unshuffle_blur.glsl", defines)
        self.compose = load_program(ctx, SHADERS / "compose.glsl", defines)
        self.deinterleave_vao = ctx.vertex_array(self.deinterleave, [])
        self.splat_vao = ctx.vertex_array(self.splat, [])
        self.splat_near_vao = ctx.vertex_array(self.splat_near, []) if self.splat_near is not None else None
        self.unshuffle_vao = ctx.vertex_array(self.unshuffle, [])
        self.compose_vao = ctx.vertex_array(self.compose, [])
        fov = np.radians(view.camera.fov_y_deg)
        layout = dict(u_level_size=sizes, u_level_y=rows, u_pixel_k=float(2.0 * np.tan(fov / 2) / view.height),
                      u_shell_pixels=params["shell_pixels"], u_blur_normal_cos=params["blur_normal_cos"],
                      u_blur_plane_pixels=params["blur_plane_pixels"])
        self.splats = (self.splat,) if self.splat_near is None else (self.splat, self.splat_near)
        for prog in (self.deinterleave, self.unshuffle, self.compose) + self.splats:
            set_uniforms(prog, u_view=view.view, **layout)
        for prog in self.splats:
            set_uniforms(prog, u_proj=view.proj, u_near=float(view.near), u_screen=(view.width, view.height),
                         u_atlas=tuple(float(v) for v in atlas), u_scene_radius=float(gpu.radius),
                         u_radius_max=float(2.0 * gpu.radius * 1.01), u_threshold=params["threshold"],
                         u_eps=float(params["eps_rel"] * gpu.radius), u_capacity=self.surfel_count,
                         u_exact_reach=float(params["exact_reach"]), u_contact_scale=float(params["contact_scale"]))
        set_uniforms(self.unshuffle, u_blur_radius=params["blur_radius"])
        set_uniforms(self.compose, u_orient_radius=orient_radius(params["shell_pixels"]))

    def _run_generation(self, program, vao, target_area: float, capacity: int) -> None:
        ctx = self.ctx
        self.counter.write(COUNTER_INIT.tobytes())
        self.splat_fbo.use()  # no default framebuffer: something must be bound to draw
        self.triangles.bind_to_storage_buffer(DSS_DEFINES["BINDING_DSS_TRIANGLES"])
        self.patches.bind_to_storage_buffer(DSS_DEFINES["BINDING_DSS_PATCHES"])
        self.counter.bind_to_storage_buffer(DSS_DEFINES["BINDING_DSS_COUNTER"])
        set_uniforms(program, u_target_area=float(target_area), u_edge_length=sub_triangle_edge(target_area),
                     u_capacity=int(capacity))
        ctx.patch_vertices = 3
        vao.render(moderngl.PATCHES, vertices=3 * self.patch_count)
        ctx.memory_barrier()

    def render(self, frame, prof) -> FrameOutput:
        ctx, gpu, passes = self.ctx, frame.gpu, frame.passes
        atlas_viewport = (0, 0) + tuple(self.atlas_size)
        ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
        with prof.stage("surfels"):
            gpu.bind_scene_buffers()
            self.surfels.bind_to_storage_buffer(DSS_DEFINES["BINDING_DSS_SURFELS"])
            passes.shadows.bind(self.generate, 0)
            set_uniforms(self.generate, u_light_count=gpu.light_count)
            self._run_generation(self.generate, self.generate_vao, self.target_area, self.surfel_count)
        with prof.stage("deinterleave"):
            self.receiver_fbo.use()
            ctx.viewport = atlas_viewport
            ctx.enable(moderngl.DEPTH_TEST)
            ctx.depth_func = "1"   # always: every atlas pixel writes its receiver mask
            passes.gbuffer.bind(self.deinterleave)
            self.deinterleave_vao.render(moderngl.TRIANGLES, vertices=3)
        with prof.stage("splat"):
            self.splat_fbo.use()
            ctx.viewport = atlas_viewport
            self.splat_fbo.clear(0.0, 0.0, 0.0, 0.0)   # colour only: the fbo's depth mask is off
            ctx.depth_func = "<"   # quads at depth 0.5 pass where the mask is 1
            ctx.enable(moderngl.BLEND)
            ctx.blend_func = moderngl.ONE, moderngl.ONE
            self.receiver_position.use(0)
            self.receiver_normal.use(1)
            set_uniforms(self.splat, u_receiver_position=0, u_receiver_normal=1, u_rand=frame.random_u32(0))
            self.surfels.bind_to_storage_buffer(DSS_DEFINES["BINDING_DSS_SURFELS"])
            self.counter.bind_to_storage_buffer(DSS_DEFINES["BINDING_DSS_COUNTER"])
            self.splat_vao.render_indirect(self.counter, mode=moderngl.POINTS, count=1)
            if self.splat_near is not None:
                gpu.bind_scene_buffers()
                passes.shadows.bind(self.splat_near, 2)   # the contact radiosity's direct light
                set_uniforms(self.splat_near, u_receiver_position=0, u_receiver_normal=1, u_light_count=gpu.light_count)
                self.surfels.bind_to_storage_buffer(DSS_DEFINES["BINDING_DSS_SURFELS"])
                self.counter.bind_to_storage_buffer(DSS_DEFINES["BINDING_DSS_COUNTER"])
                self.splat_near_vao.render_indirect(self.counter, mode=moderngl.POINTS, count=1)
            ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST)
        with prof.stage("unshuffle_blur"):
            self.levels_fbo.use()
            ctx.viewport = atlas_viewport
            self.receiver_position.use(0)
            self.receiver_normal.use(1)
            self.splat_tex.use(2)
            set_uniforms(self.unshuffle, u_receiver_position=0, u_receiver_normal=1, u_splat=2)
            self.unshuffle_vao.render(moderngl.TRIANGLES, vertices=3)
            self.indirect_fbo.use()
            ctx.viewport = (0, 0, frame.width, frame.height)
            unit = passes.gbuffer.bind(self.compose)
            self.receiver_position.use(unit)
            self.receiver_normal.use(unit + 1)
            self.levels_tex.use(unit + 2)
            set_uniforms(self.compose, u_receiver_position=unit, u_receiver_normal=unit + 1, u_levels=unit + 2)
            self.compose_vao.render(moderngl.TRIANGLES, vertices=3)
        return FrameOutput(direct=passes.direct.radiance, indirect=self.indirect,
                           extra={"surfel_count": self.surfel_count, "patch_count": self.patch_count,
                                  "target_area_m2": self.target_area})

    def release(self) -> None:
        from bench.gl.context import park
        if getattr(self, "ctx", None) is None:  # prepare() stopped before allocating anything
            return
        park(self.ctx)
        for name in ("receiver_fbo", "splat_fbo", "levels_fbo", "indirect_fbo", "receiver_mask", "receiver_position",
                     "receiver_normal", "splat_tex", "levels_tex", "indirect", "generate_vao", "deinterleave_vao",
                     "splat_vao", "splat_near_vao", "unshuffle_vao", "compose_vao", "generate", "deinterleave", "splat",
                     "splat_near", "unshuffle",
                     "compose", "surfels", "counter", "patches", "triangles"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.release()
                setattr(self, name, None)
