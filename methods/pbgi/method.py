"""`pbgi`: real-time point-based global illumination in texture space.

Paper: "Real time Point Based Global Illumination" (blog article, University of Luminy school
project; ../shared/papers/pbgi_texture_space.txt), after Bunnell, "Dynamic Ambient Occlusion
and Indirect Lighting", GPU Gems 2 ch. 14 (2005). Every texel of a lightmap is a surfel (a
small disk); light is transferred from every texel to every texel (no visibility), then the
camera view reads the lightmap. Passes:

1. Texture-space G-buffer (in prepare: the benchmark's scenes are static, and the article
   re-renders it only where an object moves): the scene rasterised at its lightmap
   coordinates, conservatively (the article's fix for faces smaller than a texel), into
   position, normal, face normal and albedo textures. Each fragment clips its texel square to
   its triangle and adds the piece's area and area-weighted attributes (additive blending): a
   texel's surfel is the mean of the surface inside it, its area the exact area inside it.
   The UV unwrap (unwrap.py) is the article's: planar projection on the dominant normal axis,
   charts shelf-packed with one texel density for all charts; a chart that folds over itself
   in projection is split into per-triangle charts. Rules recorded here (issue #12, the stress
   suite's degenerate geometry on big_floor, whose floor is two triangles): triangles of a key
   on either side of a T-junction (an edge of one split at a vertex of the other) join one
   chart, as if the edge were shared: a T-junction on a floor triangle split the floor into two
   charts, each with the whole floor's box, the density fell from 5.0 to 3.2 texels/m and the
   indirect image changed by 9% (L1 at 32x24; now 5e-5); a thin diagonal chart's box follows
   its principal axes when that halves its area or more: a zero-area sliver across the floor had
   a 74^2-texel box, -9% density and an indirect change of 4.5% (now -1% density, 0.9%). The
   unwrap works on the scene's float64 positions (re-centred), not the GPU's float32 copies, and
   a face whose two largest |normal| components tie (45 degrees) takes the lower axis: with
   argmax on float32 positions the rounding of each unit chose the axis of sponza's 45-degree
   faces (12 to 33 of them changed between scales), its charts changed, the packing landed on
   another density (36.71 instead of 36.65 texels per R) and the indirect image changed by 4.7%
   (mean -4.6%) in the stress suite's scale perturbations 1e-2, 1e2 and 1e4 (now 1e-6).
2. `lightmap_direct`: per covered texel, the shadowed direct irradiance of the scene lights on
   each side (bench/gl/shaders/direct_lighting.glsl, shared shadow maps), stored as a surfel:
   position, normal, world area, radiosity B = rho E of each side.
3. `emitter_hierarchy` (`gather=hierarchy`; skipped with `all_pairs`): the article's closing
   suggestion against O(n^2), "a quad tree of the geometry", as one tree over every texel of
   the scene (hierarchy.py, topology built in prepare): an octree of the surfels' positions (the
   3-D form of the quadtree) under one root per normal class (dominant axis and sign, as the
   unwrap's charts). A tree per chart (the first version) does not aggregate across charts: a
   real scene has thousands of small charts (sponza 7,300, conference 18,000, most of a texel or
   two), every receiver visited at least one node per chart and the receiver tiles were per
   chart (one workgroup per one-texel chart): sponza's gather took ~26 s per frame. The nodes
   are rebuilt every frame from the surfels, level by level: summed area, area-weighted centroid
   and mean normal, a bounding radius, a flag "flat" (every leaf on the node's plane with its
   normal), and the power the leaves send towards a direction w, exactly as a sum over the
   leaves: P(w) = w . D + |w . S| per colour, D = sum a (B_front - B_back) / 2 n and
   S = sum a (B_front + B_back) / 2 n (emitter_hierarchy.glsl; exact whenever the leaves face w
   on one side, always for a flat node, where it is the disk a B |cos_e|; the emitted power is
   conserved).
4. `gather`: receivers sum emitters with Bunnell's disk-to-point transfer
   a |cos_e| |cos_r| / (pi d^2 + a) into the irradiance of the side facing the emitter.
   `all_pairs`: every texel from every texel (the article's loop). `hierarchy`: one workgroup
   per receiver tile (at most 16 consecutive leaves of the tree: nearby texels, of any charts)
   walks the emitter tree without a stack; a node is used whole (P(w) |cos_r| / (pi d^2 + a))
   when its bounding radius is below `refine_ratio` times its distance to the tile's bounding
   sphere, else refined down to the texels (always summed exactly); a flat node whose plane
   holds the (flat) tile is skipped, since each of its texels sees the tile at cos_e = 0. As
   `refine_ratio` -> 0 the hierarchy is the all-pairs sum exactly; at the default 0.2 the
   lightmap differs from it by < 1% in the mean and < 3% per texel (tested on cornell_spot and
   on a floor of 1,600 separate tiles; 0.4% and 0.5% on cornell_spot). The default was 0.25
   with a tree per chart, whose 64-texel receiver tiles made the test stricter for most of
   their texels; with 16-texel tiles, 0.2 gives the same error against Mitsuba (hidden_bounce
   relMSE +5%, cornell_spot -9%).
5. `resolve`: each camera pixel maps its position through its triangle's chart map to the
   lightmap, interpolates the displayed irradiance of the side it shows bilinearly over
   covered texels, and outputs L = rho / pi * E.

Amortisation over frames (the article: "you can compute this in more than one frame by
sampling only a few emitters each time"): the emitter texels (in tree leaf order) are cut in
W = ceil(texels / `emitter_budget`) consecutive slices; frame f of a window gathers slice
f mod W (for the hierarchy, the node range whose walk covers exactly those texels: slices add
up to the whole sum) into the accumulating half of a double-buffered lightmap, and the other
half, the last complete window, is the one displayed. After W frames every emitter has been
gathered once and the accumulated lightmap is the full sum; the halves then swap. Bounce
k > 1 re-emits B = rho E_{k-1} of the last complete window of bounce k - 1 (pipelined: the
k-th bounce is k - 1 windows behind on a moving scene). `emitter_budget` = 0 gathers every
emitter in every frame (W = 1). The article also blends the new lightmap with the last one
over time; here the last complete window is shown as is (identical on the static scenes of
the benchmark).

How it is measured (bench.run.harness: frame 0 is an untimed warm-up that gives the row's
images): the first render() call has an empty history, so it runs `bounces` x W frames of
accumulation, exactly what the method does over that many frames of a static scene; the row's
image is therefore the converged state the method shows after its accumulation window. Every
later (timed) frame does one frame's work: direct light of all texels, the hierarchy rebuild,
one slice of the gather per bounce, the resolve. So frame_ms is the steady per-frame cost and
the error columns are those of the converged image; the latency (W frames, `extra.window_frames`)
is the price, and a moving light takes up to 2 W frames to settle.

Lightmap size (texel density rule, unwrap.py): the lightmap side is the smallest that packs
all charts at `texel_density` texels per scene radius R (the bounding sphere's, SceneFacts),
at most `max_lightmap_resolution` (then the density is the largest that fits, below the
target). A fixed side gives a scene texels in inverse proportion to its area (big_floor,
2000 m^2, got 2 texels per metre at 128^2 and lost 13% of its indirect light: its 1 m spot
and 15 cm cubes were a texel or two). The density is relative to R, not per metre, so that
the lightmap does not depend on the scene's unit (rule recorded here, issue #12): with 20
texels per metre (the first form of the rule), cornell_spot in centimetres (scaled by 1e-2,
intensities by 1e-4) fell to the 16^2 minimum and its image changed by 9% (indirect 12%,
mean -4.4%), hidden_bounce's by 16%; scaled by 1e2 it jumped to the cap. The default, 144
texels per R, is the least at which big_floor (R 28.7 m) keeps the cap's 256^2 (5.0 texels
per metre; at 100 per R, 3.5 texels/m, its indirect relMSE against Mitsuba doubles, 0.013 ->
0.028, and at 72 it is 0.049), so every scene of the corpus gets the cap's 256^2: hidden_bounce
17.2 texels/m, rooms 13.5, big_floor 5.0 (as with 20 texels/m; rooms had 13.9 before the
T-junction rule below merged its charts); the real scenes were at the cap already (unwrap
alone, before the GL's folded-chart splits: sponza 1.95, sibenik 1.47, conference 6.71
texels/m, 1.95 / 1.48 / 6.60 before the T-junction and rotated-box rules); the small scenes that 20 texels/m left below the cap get it now:
cornell_spot 42 texels/m (123^2 before), cornell_box 42, lit_wall_corner 56, sphere_inside 60.
Their error hardly changes (128x96, indirect against the unshadowed Mitsuba reference at 256
spp, mean ratio and relMSE, 20 texels/m -> the default: cornell_spot 0.995 / 0.0027 -> 0.995 /
0.0025; cornell_box 1.007 / 0.0130 -> 1.009 / 0.0117; sphere_inside 0.9995 -> 1.0002, relMSE
1e-4; lit_wall_corner 1.001 -> 1.004, relMSE 0.0037; rooms 1.006 / 0.0046 -> 1.009 / 0.0047;
big_floor 0.971 / 0.0132 and hidden_bounce 1.004 / 0.0018 unchanged); their texels and their
convergence window grow (cornell_spot 12,400 -> 52,600 texels, 7 -> 26 frames; sphere_inside
3 -> 19; lit_wall_corner 3 -> 17; cornell_box 6 -> 23). Chart boxes have no margin
texels of their own (unwrap.py: ceil(s w + 0.51) texels, the resolve clamps its bilinear taps
to the chart's box), so a chart smaller than a texel costs one texel: with a texel of margin
on each side (9 texels per small chart) sponza's 7,300 charts left it 0.09 texels per metre
and conference's 18,000 did not fit 256^2.

Corrections to the article's formulas (each checked against the invariant it must satisfy):

- Emitter area: the article passes a = 1/128 for every texel. The transfer is the point-to-
  disk form factor (exact on axis: F = r^2 / (h^2 + r^2) = a / (pi h^2 + a)), so `a` must be
  the texel's world area: here the exact area of the surface inside the texel square (the
  squares partition the chart plane, so the texel areas sum to the surface area: tested).
- Aggregated emitters: a node of the hierarchy is a disk of its summed area A, but the `+ a`
  of the denominator (the near-field saturation of one disk) stays its texels' area-weighted
  mean area: pi d^2 + A would damp a far node by A / (pi d^2), 4% at the default refine_ratio,
  which its texels, each pi d^2 + a_texel, do not.
- Receiver: the article writes `rec.alb * rec.shad * gi`, i.e. multiplies by the receiver's
  own direct lighting and omits 1/pi. The radiance leaving a Lambertian receiver is
  L = rho_r / pi * E_r with E_r = sum_e B_e F_e (energy conservation: the cosine-weighted
  integral of L over the hemisphere is rho_r E_r); it does not depend on how lit r is.
- Further bounces: the article feeds its output (radiance, already times albedo) back as the
  "lighting" texture; the quantity to feed back is the irradiance E_k, re-emitted as
  B = rho E_k (otherwise albedo is applied twice), and the displayed indirect light is the sum
  of all bounces, not the last one. Check: inside a sphere E_{k+1} = rho E_k exactly, so two
  bounces give (1 + rho) times the one-bounce radiance (tested).
- Sides: the article clamps both cosines at 0 (one-sided). gibench surfaces are two-sided
  (Mitsuba `twosided`): each texel stores the irradiance and radiosity of both sides; an
  emitter emits from the side facing the receiver, which receives on its side facing the
  emitter (as `manylights`' radiosity_front/back).
- Texel centres: the article samples `p = (2i+1)/(2*128)` for a fixed 128^2 loop; here texels
  are fetched by integer coordinates over the list of covered texels only.

The method is deterministic (no random numbers): the seed does not change the image. As the
texel density grows it converges to `manylights` with `emission=lambert` (the continuous
unshadowed one-bounce integral); the error at a fixed density is largest in concave corners,
where near-field texels see each other at distances comparable to their size. Cost per
frame: all_pairs texels x budget pair evaluations per bounce; with the hierarchy each receiver
tile walks this frame's slice of the tree (for the whole window, a tile visits ~1,150 nodes on
cornell_spot's 12,400 texels, ~330 on a floor of 1,600 separate tiles; `read_visits()`).
Measured at the defaults (gibench run --defaults-only --res 320x180 --frames 3 --timing-budget
0, llvmpipe, 2 shared cores), frame_ms of pbgi / direct: sponza 1.43 s / 0.25 s (5.7x; with a
tree per chart the gather alone took ~26-30 s), sibenik 1.58 / 0.36 (4.4x), conference 1.59 /
0.34 (4.7x; it did not fit the lightmap before), cornell_spot 0.146 / 0.023 (6.5x),
cornell_box 0.124 / 0.0074 (17x: a 30-triangle box whose direct light costs nothing); prepare
2-6 s on the real scenes (up to 33 s on a loaded machine: the conservative lightmap
rasterisation of 66k-331k triangles), the row (prepare, the untimed convergence of W = 22-26
frames of work, 3 frames) 33-40 s. On the small procedural scenes the frame costs ~1.7-1.9x
that of the tree per chart (cornell_spot, cornell_box; same process, alternating; the gather
stage 1.7-2.7x): its nodes are larger (the power vectors) and its 16-texel tiles visit about
as many nodes per texel at refine_ratio 0.2 as the 64-texel ones did at 0.25.

| parameter               | default   | range                 | meaning                                                   |
|-------------------------|-----------|-----------------------|-----------------------------------------------------------|
| texel_density           | 144.0     | 1 .. 10000            | target lightmap texels per scene radius (quality; sweep 36, 72, 144, 288) |
| max_lightmap_resolution | 256       | 16 .. 1024            | largest lightmap side; the density drops when it is reached |
| gather                  | hierarchy | hierarchy, all_pairs  | walk of one emitter octree over all texels, or every texel from every texel |
| refine_ratio            | 0.2       | 0 .. 1                | hierarchy: node used whole when radius < ratio x distance (quality; sweep 0.1, 0.2, 0.5) |
| emitter_budget          | 2048      | 0 .. 2^24             | emitter texels gathered per frame, rotating (0: all every frame) |
| bounces                 | 1         | 1 .. 8                | light bounces summed (the benchmark compares one bounce)  |

A scene whose charts cannot be packed into the lightmap (too many separate charts for the
resolution) is skipped with a message naming `max_lightmap_resolution`.

Limits of the stress suite's parameter extremes (`gibench stress`, issue #12; each a cost the
article states, at the suite's 300 s case timeout on llvmpipe, 2 shared cores):
Stress limit params:refine_ratio=0: every node refined to its texels is the article's all-pairs loop ("Of course this pass is really slow"), texels^2 transfers per bounce (52,600^2 = 2.8e9 on cornell_spot's 256^2 lightmap) through the stackless walk: over 300 s (gather=all_pairs, the same sum without the walk, finishes)
Stress limit params:bounces=8: the untimed first frame converges bounces x W frames of the amortised gather (the article computes the gather "in more than one frame by sampling only a few emitters each time"), each bounce re-gathering its window: 8 x 26 = 208 frames of work on cornell_spot's 256^2 lightmap, over 300 s (hidden_bounce, 256^2 already with 20 texels/m, timed out before the density rule changed)
Stress limit params:max_lightmap_resolution=1024: on a real scene the cap no longer binds, so the untimed first frame converges a window of 7x the texels: sibenik 291,941 texels and W = 143 frames (42,702 and 21 at the default 256), each frame's gather over 7x the receivers, ~50x the default's convergence work, over 300 s with a second stress run sharing the 2 cores; conference (its cap at 1024 done within 300 s on a quieter machine), cornell_box and the procedural scenes pass

Quality ladder (`gibench run`), fast -> accurate:
  1. texel_density 72, max_lightmap_resolution 192, refine_ratio 0.5;
  2. the defaults (144 texels per scene radius, 256^2 at most, refine_ratio 0.2);
  3. texel_density 288, max_lightmap_resolution 384.
The lightmap's density is the error that dominates (the hierarchy at 0.2 is within 1% of the
all-pairs sum, at 0.5 within ~4%), so the rungs turn the density and, on the large and real
scenes where the cap binds (sponza gets 1.3 / 1.8 / 2.8 texels per metre), the cap with it;
the top rung keeps refine_ratio 0.2 (0.1 costs ~2.5x the visits for < 1%). The per-frame cost
hardly depends on the rung (the emitter budget fixes the emitters per frame; more receivers
walk smaller slices of a larger tree); the convergence window (untimed frame 0) grows with
the texel count: on sponza the top rung's window is 48 frames (98k texels, 2x the default's).
Stress limit coplanar: coincident coplanar faces are two charts emitting the same surface (every triangle is unwrapped and emits) while Mitsuba's rays see one surface: the overlapped area emits twice and takes lightmap space (cornell_box 64x48: mean +6.1%; big_floor indirect 5.6%, lit_wall_corner 1.9%).
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import moderngl
import numpy as np

from bench.gl import load_compute, load_program, set_uniforms
from bench.gl.context import check_gl, loop_chunks, park
from bench.protocol.method import FrameOutput, MethodBase, Param, SkipRow

from .hierarchy import build_tree
from .unwrap import LightmapTooSmall, chart_image, find_charts, unwrap

SHADERS = Path(__file__).parent / "shaders"
PBGI_DEFINES = {"BINDING_PBGI_TRIANGLES": 3, "BINDING_PBGI_TEXELS": 4, "BINDING_PBGI_SURFELS": 5,
                "BINDING_PBGI_EMITTERS": 6, "BINDING_PBGI_NODE_LINKS": 7, "BINDING_PBGI_LEVEL_NODES": 8,
                "BINDING_PBGI_TILES": 9, "BINDING_PBGI_VISITS": 10}
HIERARCHY_DEFINES = {
    "FLAT_COSINE_TOLERANCE": 1e-6,    # a node is flat when every leaf normal is within this (1 - cos) of its normal
    "FLAT_DISTANCE_TOLERANCE": 1e-5,  # ... and every child centre within this many node radii of its plane
    "PLANE_TOLERANCE": 1e-4,          # a receiver within this many node radii of a flat node's plane gets nothing from it
}
# the manual's "Stress limit PATTERN: reason" lines (PATTERN may hold colons: params:NAME=VALUE),
# handed to `gibench stress` as the class's stress_limits (it reads the class, not this module)
STRESS_LIMITS = dict(re.findall(r"^Stress limit (\S+): (.+)$", __doc__, re.MULTILINE))
TILE_TEXELS = 16            # hierarchical gather: one workgroup per tile of at most 16 nearby texels
MAX_WORK_GROUPS = 65535     # per dispatch dimension (the GL minimum of GL_MAX_COMPUTE_WORK_GROUP_COUNT)
WELD_TOLERANCE_REL = 1e-6   # vertices closer than this (times the scene radius) share chart edges
SURFEL_BYTES = 64           # struct Surfel: 4 vec4
NODE_BYTES = 144            # struct EmitterNode: 9 vec4
TRIANGLE_BYTES = 64         # struct ChartTriangle: 4 vec4


def _unwrap_positions(gpu, scene) -> np.ndarray:
    """The re-centred vertex positions the unwrap works on, in float64 from the scene's own (the
    GPU's float32 copies round differently in every unit: see the manual's unwrap rules)."""
    return np.asarray(scene.vertices, dtype=np.float64) - gpu.origin


def _tile_records(tiles, position, normal, area, texel_m: float) -> np.ndarray:
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


class TextureSpacePBGI(MethodBase):
    name = "pbgi"
    summary = "Texture-space point-based GI: lightmap texels as surfels, Bunnell disk transfer over an emitter octree"
    ladder = ({"texel_density": 72.0, "max_lightmap_resolution": 192, "refine_ratio": 0.5}, {},
              {"texel_density": 288.0, "max_lightmap_resolution": 384})
    stages = ("lightmap_direct", "emitter_hierarchy", "gather", "resolve")
    needs = frozenset({"gbuffer", "shadow_map", "direct"})
    stress_limits = STRESS_LIMITS
    params = {
        "texel_density": Param(144.0, "lightmap texels per scene radius (the lightmap side is the smallest that "
                                      "packs the charts at this density)", 1.0, 10000.0, quality=True,
                               sweep=(36.0, 72.0, 144.0, 288.0)),
        "max_lightmap_resolution": Param(256, "largest lightmap side in texels (the density drops when reached)",
                                         16, 1024),
        "gather": Param("hierarchy", "emitters: 'hierarchy' (one octree over every texel) or 'all_pairs'",
                        choices=("hierarchy", "all_pairs")),
        "refine_ratio": Param(0.2, "hierarchy: a node is used whole when its radius < this times its distance",
                              0.0, 1.0, quality=True, sweep=(0.1, 0.2, 0.5)),
        "emitter_budget": Param(2048, "emitter texels gathered per frame, rotating (0: all every frame)",
                                0, 2 ** 24),
        "bounces": Param(1, "light bounces summed in the lightmap", 1, 8),
    }

    # ------------------------------------------------------------------ prepare (untimed)
    def prepare(self, gpu, scene, facts, params, view) -> None:
        self.params = params
        self.ctx = ctx = gpu.ctx
        if gpu.triangle_count >= 2 ** 24:  # triangle ids travel as float32 in the lightmap normal's w
            raise SkipRow(f"scene '{scene.name}' has {gpu.triangle_count} triangles; pbgi handles < 2^24")
        if params["max_lightmap_resolution"] > ctx.info["GL_MAX_TEXTURE_SIZE"]:
            raise SkipRow(f"max_lightmap_resolution={params['max_lightmap_resolution']} exceeds "
                          f"GL_MAX_TEXTURE_SIZE {ctx.info['GL_MAX_TEXTURE_SIZE']}")
        self.hierarchical = params["gather"] == "hierarchy"
        self.triangles = ctx.buffer(reserve=gpu.triangle_count * TRIANGLE_BYTES)
        self._unwrap_without_overlaps(gpu, scene)
        self.resolution = res = self.unwrap.resolution

        self.lm_position, self.lm_normal, self.lm_face_normal, self.lm_albedo = (
            self._texture((res, res)) for _ in range(4))
        self.lm_fbo = ctx.framebuffer([self.lm_position, self.lm_normal, self.lm_face_normal, self.lm_albedo])
        self.lm_program = load_program(ctx, SHADERS / "lightmap_gbuffer.glsl", PBGI_DEFINES)
        self.lm_vao = self._scene_vao(gpu, self.lm_program)
        # The scenes are static: the texture-space G-buffer is rendered once (the article
        # re-renders it only where an object moves); the per-frame passes relight it.
        self._render_lightmap_gbuffer(gpu)
        check_gl(ctx, "pbgi lightmap gbuffer")
        position_sum = np.frombuffer(self.lm_position.read(), dtype=np.float32).reshape(res, res, 4)
        normal_sum = np.frombuffer(self.lm_normal.read(), dtype=np.float32).reshape(res, res, 4)
        ys, xs = np.nonzero(position_sum[..., 3] > 0)
        chart = chart_image(self.unwrap)[ys, xs]
        if np.any(chart < 0):
            raise RuntimeError(f"pbgi: {int((chart < 0).sum())} lightmap texel(s) covered outside every chart box")
        area = position_sum[ys, xs, 3].astype(np.float64)
        position = position_sum[ys, xs, :3].astype(np.float64) / area[:, None]
        normal = normal_sum[ys, xs, :3].astype(np.float64)
        normal /= np.maximum(np.linalg.norm(normal, axis=1), 1e-30)[:, None]
        # texels in leaf order (normal class, then octree order): a node is a range of them
        self.tree = tree = build_tree(position, normal)
        order = tree.leaf_order
        xs, ys, chart, area, position, normal = xs[order], ys[order], chart[order], area[order], position[order], normal[order]
        self.texel_xy = np.column_stack([xs, ys])
        self.texel_chart = chart
        self.texel_count = len(xs)
        self.texels = ctx.buffer(self.texel_xy.astype(np.int32).tobytes())
        self.surfels = ctx.buffer(reserve=self.texel_count * SURFEL_BYTES)
        self.surfel_program = load_compute(ctx, SHADERS / "surfel_radiosity.glsl", PBGI_DEFINES)

        defines = dict(PBGI_DEFINES, **HIERARCHY_DEFINES, TILE_TEXELS=TILE_TEXELS)
        self.nodes = self.node_links = self.level_nodes = self.hierarchy_program = self.tiles = None
        self.visits = self.gather_program = self.gather_vao = None
        self.tile_count = 0
        if self.hierarchical:
            self.nodes = ctx.buffer(reserve=tree.node_count * NODE_BYTES)
            self.node_links = ctx.buffer(np.column_stack([tree.skip, tree.lo]).astype(np.int32).tobytes())
            self.level_nodes = ctx.buffer(tree.level_nodes.astype(np.int32).tobytes())
            self.hierarchy_program = load_compute(ctx, SHADERS / "emitter_hierarchy.glsl", defines)
            tiles = tree.receiver_tiles(TILE_TEXELS)
            self.tile_count = len(tiles)
            self.tiles = ctx.buffer(_tile_records(tiles, position, normal, area, 1.0 / self.unwrap.scale).tobytes())
            self.visits = ctx.buffer(reserve=self.tile_count * 4)
            self.visits.clear()
            self.gather_program = load_compute(ctx, SHADERS / "gather_hierarchy.glsl", defines)
        else:
            self.gather_program = load_program(ctx, SHADERS / "gather.glsl", defines)
            self.gather_vao = ctx.vertex_array(self.gather_program, [])
        self.emitter_count = tree.node_count if self.hierarchical else self.texel_count

        # Amortisation: frame f of a window gathers the emitter texels [f B, (f + 1) B) (B the
        # budget) into the accumulating half of a double-buffered lightmap; the other half, the
        # last complete window, is displayed. Slices are emitter index ranges (nodes whose
        # leaves are those texels, with the hierarchy).
        budget = params["emitter_budget"] or self.texel_count
        self.window = max(1, math.ceil(self.texel_count / budget))
        leaf_bounds = [min(f * budget, self.texel_count) for f in range(self.window + 1)]
        if self.hierarchical:
            self.slices = [tree.node_range(a, b) for a, b in zip(leaf_bounds[:-1], leaf_bounds[1:])]
        else:
            self.slices = list(zip(leaf_bounds[:-1], leaf_bounds[1:]))
        # [parity][bounce] = (front, back) irradiance of that bounce; [parity] totals over bounces
        bounces = params["bounces"]
        self.bounce_tex = [[(self._texture((res, res)), self._texture((res, res))) for _ in range(bounces)]
                           for _ in range(2)]
        self.total_tex = [(self._texture((res, res)), self._texture((res, res))) for _ in range(2)]
        self.gather_fbos = [[ctx.framebuffer([*self.bounce_tex[p][k], *self.total_tex[p]]) for k in range(bounces)]
                            for p in range(2)]
        for row in self.gather_fbos:
            for fbo in row:
                fbo.use()
                fbo.clear(0.0, 0.0, 0.0, 0.0)
        self.parity = 0      # the half being accumulated; 1 - parity holds the last complete window
        self.steps = 0       # frames of accumulation run so far
        self.resolve_program = load_program(ctx, SHADERS / "resolve.glsl", PBGI_DEFINES)
        self.resolve_vao = ctx.vertex_array(self.resolve_program, [])
        self.indirect = self._texture((view.width, view.height))
        self.indirect_fbo = ctx.framebuffer([self.indirect])

    def _unwrap_without_overlaps(self, gpu, scene) -> None:
        """Unwrap; charts that fold over themselves in projection (found by counting triangles
        per texel centre on the GL) are split into one chart per triangle and packed again."""
        ctx = self.ctx
        split: set = set()
        count_tex = count_fbo = None
        program = load_program(ctx, SHADERS / "lightmap_overlap.glsl", PBGI_DEFINES)
        vao = self._scene_vao(gpu, program)
        try:
            for attempt in range(3):
                try:
                    uw = unwrap(_unwrap_positions(gpu, scene), gpu.faces.astype(np.int64),
                                self.params["max_lightmap_resolution"], WELD_TOLERANCE_REL * gpu.radius,
                                split=split, density=self.params["texel_density"] / gpu.radius,
                                shading_normals=gpu.normals)
                except LightmapTooSmall as exc:
                    raise SkipRow(f"scene '{scene.name}': {exc}") from None
                res = uw.resolution
                if count_tex is None or count_tex.size != (res, res):
                    park(ctx)
                    for obj in (count_fbo, count_tex):
                        if obj is not None:
                            obj.release()
                    count_tex = self._texture((res, res))
                    count_fbo = ctx.framebuffer([count_tex])
                records = np.zeros((gpu.triangle_count, 4, 4), dtype=np.float32)
                records[:, :2] = uw.rows
                records[:, 2, :3] = uw.face_normal
                x0, y0, w, h = uw.chart_box[uw.chart_of_triangle].T
                records[:, 3] = np.column_stack([x0, y0, x0 + w, y0 + h])
                self.triangles.write(records.tobytes())
                count_fbo.use()
                ctx.viewport = (0, 0, res, res)
                count_fbo.clear(0.0, 0.0, 0.0, 0.0)
                ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
                ctx.enable(moderngl.BLEND)
                ctx.blend_func = moderngl.ONE, moderngl.ONE
                self.triangles.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_TRIANGLES"])
                set_uniforms(program, u_lightmap_size=float(res))
                vao.render(moderngl.TRIANGLES)
                ctx.disable(moderngl.BLEND)
                counts = np.frombuffer(count_tex.read(), dtype=np.float32).reshape(res, res, 4)[..., 0]
                ys, xs = np.nonzero(counts > 1.5)
                folded = np.unique(chart_image(uw)[ys, xs])
                folded = folded[folded >= 0]
                self.unwrap, self.folded_charts = uw, len(split)
                if len(folded) == 0:
                    return
                # ids refer to this attempt's charts: map them back through their triangles
                tri = np.flatnonzero(np.isin(uw.chart_of_triangle, folded))
                split |= set(self._base_charts(gpu, scene, tri))
            raise SkipRow(f"scene '{scene.name}': lightmap charts still overlap after splitting folded charts")
        finally:
            park(ctx)
            for obj in (vao, count_fbo, count_tex, program):
                if obj is not None:
                    obj.release()

    @staticmethod
    def _base_charts(gpu, scene, triangles) -> np.ndarray:
        chart = find_charts(_unwrap_positions(gpu, scene), gpu.faces.astype(np.int64),
                            WELD_TOLERANCE_REL * gpu.radius, shading_normals=gpu.normals)[0]
        return np.unique(chart[triangles])

    def _scene_vao(self, gpu, program):
        """A VAO of the scene's own buffers for `program`, owned (and released) by this method:
        GpuScene.vertex_array caches VAOs by program name, which GL recycles after release."""
        content = [(buf, fmt, name) for buf, fmt, name in ((gpu.vbo_position, "3f", "in_position"),
                                                           (gpu.vbo_normal, "3f", "in_normal"))
                   if name in program]
        return self.ctx.vertex_array(program, content, index_buffer=gpu.ibo, index_element_size=4)

    def _texture(self, size):
        tex = self.ctx.texture(size, 4, dtype="f4")
        tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        return tex

    def _lightmap_textures(self) -> dict:
        return {"u_lightmap_position": self.lm_position, "u_lightmap_normal": self.lm_normal,
                "u_lightmap_face_normal": self.lm_face_normal, "u_lightmap_albedo": self.lm_albedo}

    def _bind_textures(self, program, **textures) -> int:
        unit = 0
        for name, tex in textures.items():
            if program.get(name, None) is not None:
                tex.use(unit)
                program[name].value = unit
                unit += 1
        return unit

    def _render_lightmap_gbuffer(self, gpu) -> None:
        ctx = self.ctx
        self.lm_fbo.use()
        ctx.viewport = (0, 0, self.resolution, self.resolution)
        self.lm_fbo.clear(0.0, 0.0, 0.0, 0.0)
        ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        ctx.enable(moderngl.BLEND)   # pieces of surface in a texel add up
        ctx.blend_func = moderngl.ONE, moderngl.ONE
        gpu.bind_scene_buffers()
        self.triangles.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_TRIANGLES"])
        set_uniforms(self.lm_program, u_lightmap_size=float(self.resolution))
        self.lm_vao.render(moderngl.TRIANGLES)
        ctx.disable(moderngl.BLEND)

    # ------------------------------------------------------------------ render (timed)
    def _build_surfels(self, gpu, passes, bounce: int) -> None:
        """Surfels of `bounce`: radiosity rho E of the direct light (bounce 0) or of the last
        complete window's irradiance of bounce - 1."""
        prog = self.surfel_program
        done = self.bounce_tex[1 - self.parity][max(bounce - 1, 0)]
        unit = self._bind_textures(prog, u_irradiance_front=done[0], u_irradiance_back=done[1],
                                   **self._lightmap_textures())
        passes.shadows.bind(prog, unit)
        gpu.bind_scene_buffers()
        self.triangles.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_TRIANGLES"])
        self.texels.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_TEXELS"])
        self.surfels.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_SURFELS"])
        set_uniforms(prog, u_texel_count=self.texel_count, u_from_direct=bounce == 0,
                     u_light_count=gpu.light_count)
        prog.run(group_x=(self.texel_count + 63) // 64)
        self.ctx.memory_barrier()

    def _build_hierarchy(self) -> None:
        prog, tree = self.hierarchy_program, self.tree
        self.surfels.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_SURFELS"])
        self.nodes.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_EMITTERS"])
        self.node_links.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_NODE_LINKS"])
        self.level_nodes.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_LEVEL_NODES"])
        offsets = tree.level_offsets
        for level in range(len(offsets) - 1):   # children before parents
            first, count = int(offsets[level]), int(offsets[level + 1] - offsets[level])
            if count == 0:
                continue
            set_uniforms(prog, u_first=first, u_count=count, u_texel_m=1.0 / self.unwrap.scale)
            prog.run(group_x=(count + 63) // 64)
            self.ctx.memory_barrier()

    def _gather(self, bounce: int, first: int, end: int) -> None:
        ctx, prog = self.ctx, self.gather_program
        self._bind_textures(prog, **self._lightmap_textures())
        emitters = self.nodes if self.hierarchical else self.surfels
        emitters.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_EMITTERS"])
        # partial sums add up; a walk visits at most end - first emitters (llvmpipe's loop cap)
        chunks = loop_chunks(end - first)
        if self.hierarchical:
            self.node_links.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_NODE_LINKS"])
            self.tiles.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_TILES"])
            self.texels.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_TEXELS"])
            self.surfels.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_SURFELS"])
            self.visits.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_VISITS"])
            images = (*self.bounce_tex[self.parity][bounce], *self.total_tex[self.parity])
            for unit, tex in enumerate(images):
                tex.bind_to_image(unit, read=True, write=True)
            for a, b in chunks:
                set_uniforms(prog, u_first=first + a, u_end=first + b, u_refine_ratio=self.params["refine_ratio"])
                for t0 in range(0, self.tile_count, MAX_WORK_GROUPS):   # GL guarantees 65535 groups per dimension
                    set_uniforms(prog, u_tile_offset=t0)
                    prog.run(group_x=min(MAX_WORK_GROUPS, self.tile_count - t0))
                ctx.memory_barrier()
            return
        self.gather_fbos[self.parity][bounce].use()
        ctx.viewport = (0, 0, self.resolution, self.resolution)
        ctx.disable(moderngl.DEPTH_TEST)
        ctx.enable(moderngl.BLEND)
        ctx.blend_func = moderngl.ONE, moderngl.ONE
        for a, b in chunks:
            set_uniforms(prog, u_first=first + a, u_end=first + b)
            self.gather_vao.render(moderngl.TRIANGLES, vertices=3)
        ctx.disable(moderngl.BLEND)
        ctx.memory_barrier()

    def _accumulate_one_frame(self, gpu, passes, prof) -> None:
        """One frame of accumulation: every bounce gathers this frame's slice of the emitters."""
        slice_index = self.steps % self.window
        if slice_index == 0:   # a new window starts in the accumulating half
            for fbo in self.gather_fbos[self.parity]:
                fbo.use()
                fbo.clear(0.0, 0.0, 0.0, 0.0)
        first, end = self.slices[slice_index]
        for bounce in range(self.params["bounces"]):
            # re-emission of the previous bounce is part of the bounce loop: billed to the gather
            with prof.stage("lightmap_direct" if bounce == 0 else "gather"):
                self._build_surfels(gpu, passes, bounce)
            if self.hierarchical:
                with prof.stage("emitter_hierarchy"):
                    self._build_hierarchy()
            with prof.stage("gather"):
                self._gather(bounce, first, end)
        if slice_index == self.window - 1:
            self.parity = 1 - self.parity   # the window is complete: display it
        self.steps += 1

    def render(self, frame, prof) -> FrameOutput:
        ctx, gpu, passes = self.ctx, frame.gpu, frame.passes
        # An empty history (the first frame) runs the whole accumulation, `bounces` windows (bounce
        # k re-emits the window before), as the method would over that many frames of a static
        # scene: its image is the converged state. Every later frame does one frame of work.
        for _ in range(self.window * self.params["bounces"] if self.steps == 0 else 1):
            self._accumulate_one_frame(gpu, passes, prof)
        with prof.stage("resolve"):
            self.indirect_fbo.use()
            ctx.viewport = (0, 0, frame.width, frame.height)
            ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
            g = passes.gbuffer
            front, back = self.total_tex[1 - self.parity]
            self._bind_textures(self.resolve_program, u_gbuffer_position=g.position,
                                u_gbuffer_geo_normal=g.geo_normal, u_gbuffer_albedo=g.albedo,
                                u_total_front=front, u_total_back=back, **self._lightmap_textures())
            self.triangles.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_TRIANGLES"])
            self.resolve_vao.render(moderngl.TRIANGLES, vertices=3)
        skipped = () if self.hierarchical else ("emitter_hierarchy",)
        return FrameOutput(direct=passes.direct.radiance, indirect=self.indirect, skipped_stages=skipped,
                           extra={"texels": self.texel_count, "emitters": self.emitter_count,
                                  "charts": self.unwrap.chart_count, "texels_per_m": self.unwrap.scale,
                                  "lightmap_resolution": self.resolution, "window_frames": self.window,
                                  "receiver_tiles": self.tile_count})

    # ------------------------------------------------------------------ diagnostics and release
    def read_lightmap(self) -> dict:
        """The lightmap textures as numpy arrays indexed [y, x] (GL rows, not flipped). The
        texture-space G-buffer holds area-weighted sums: position = (sum a p, sum a), normal =
        (sum a n, 0), face_normal, albedo likewise; total_front/back = the displayed (last
        complete window's) irradiance summed over bounces."""
        def rd(tex):
            return np.frombuffer(tex.read(), dtype=np.float32).reshape(self.resolution, self.resolution, 4).copy()
        front, back = self.total_tex[1 - self.parity]
        return {"position": rd(self.lm_position), "normal": rd(self.lm_normal), "face_normal": rd(self.lm_face_normal),
                "albedo": rd(self.lm_albedo), "total_front": rd(front), "total_back": rd(back)}

    def read_nodes(self) -> np.ndarray:
        """The emitter hierarchy's nodes (N, 9, 4) float32 (pre-order, see hierarchy.py): centroid/
        area, mean normal/radius, (mean leaf area, flat flag, 0, 0), flux_odd[3],
        flux_even[3] (pbgi_records.glsl)."""
        return np.frombuffer(self.nodes.read(), np.float32).reshape(-1, 9, 4).copy()

    def read_visits(self) -> np.ndarray:
        """(tiles,) nodes visited by each receiver tile's walks since prepare, over all slices and
        bounces gathered (gather=hierarchy)."""
        return np.frombuffer(self.visits.read(), np.uint32).astype(np.int64)

    def release(self) -> None:
        if getattr(self, "ctx", None) is None:
            return
        park(self.ctx)
        objects = [getattr(self, name, None) for name in (
            "indirect_fbo", "indirect", "resolve_vao", "resolve_program", "gather_vao", "gather_program",
            "surfel_program", "hierarchy_program", "nodes", "node_links", "level_nodes", "tiles", "visits", "surfels",
            "texels", "lm_vao", "lm_program", "lm_fbo", "lm_position", "lm_normal", "lm_face_normal", "lm_albedo", "triangles")]
        for row in getattr(self, "gather_fbos", None) or ():
            objects += row
        for row in getattr(self, "bounce_tex", None) or ():
            for pair in row:
                objects += pair
        for pair in getattr(self, "total_tex", None) or ():
            objects += pair
        for obj in objects:
            if obj is not None:
                obj.release()
        for name in ("indirect_fbo", "indirect", "resolve_vao", "resolve_program", "gather_vao", "gather_program",
                     "surfel_program", "hierarchy_program", "nodes", "node_links", "level_nodes", "tiles", "visits", "surfels",
                     "texels", "lm_vao", "lm_program", "lm_fbo", "lm_position", "lm_normal", "lm_face_normal", "lm_albedo",
                     "triangles", "gather_fbos", "bounce_tex", "total_tex"):
            setattr(self, name, None)
        self.ctx = None
