"""`pbgi`: real-time point-based global illumination in texture space.

Paper: "Real time Point Based Global Illumination" (blog article, University of Luminy school
project; ../shared/papers/pbgi_texture_space.txt), after Bunnell, "Dynamic Ambient Occlusion
and Indirect Lighting", GPU Gems 2 ch. 14 (2005). Every texel of a lightmap is a surfel (a
small disk); light is transferred from every texel to every texel (no visibility), then the
camera view reads the lightmap:

    E(r) = sum_e B_e a_e |cos_e| |cos_r| / (pi d^2 + a_e),   B_e = rho_e E_e,   L(x) = rho_x / pi * E(x)

The measurements and the history behind the rules below (the figures that chose each rule and
default, costs per scene) are in NOTES.md beside this file. Passes (stages `lightmap_direct`,
`emitter_hierarchy`, `gather`, `resolve`; needs the shared gbuffer, shadow_map and direct):

1. Texture-space G-buffer (in prepare: the benchmark's scenes are static, and the article
   re-renders it only where an object moves): the scene rasterised at its lightmap
   coordinates, conservatively (the article's fix for faces smaller than a texel), into
   position, normal, face normal and albedo textures. Each fragment clips its texel square to
   its triangle and adds the piece's area and area-weighted attributes (additive blending): a
   texel's surfel is the mean of the surface inside it, its area the exact area inside it.
   The UV unwrap (unwrap.py) is the article's: planar projection on the dominant normal axis,
   charts shelf-packed with one texel density for all charts; a chart that folds over itself
   in projection is split into per-triangle charts. Rules (issue #12): triangles of a key on
   either side of a T-junction (an edge of one split at a vertex of the other) join one chart,
   as if the edge were shared; a thin diagonal chart's box follows its principal axes when
   that halves its area or more; the unwrap works on the scene's float64 positions
   (re-centred), not the GPU's float32 copies, and a face whose two largest |normal|
   components tie (45 degrees) takes the lower axis, so that the charts do not depend on the
   scene's unit.
2. `lightmap_direct`: per covered texel, the shadowed direct irradiance of the scene lights on
   each side (bench/gl/shaders/direct_lighting.glsl, shared shadow maps), stored as a surfel:
   position, normal, world area, radiosity B = rho E of each side.
3. `emitter_hierarchy` (`gather=hierarchy`; skipped with `all_pairs`): the article's closing
   suggestion against O(n^2), "a quad tree of the geometry", as one tree over every texel of
   the scene (hierarchy.py, topology built in prepare): an octree of the surfels' positions (the
   3-D form of the quadtree) under one root per normal class (dominant axis and sign, as the
   unwrap's charts); one tree, not one per chart, since real scenes have thousands of charts of
   a texel or two, which a tree per chart does not aggregate. The nodes
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
   on a floor of 1,600 separate tiles).
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
target). A fixed side would give a scene texels in inverse proportion to its area; the density
is relative to R, not per metre, so that the lightmap does not depend on the scene's unit
(issue #12). The default, 144 texels per R, is the least at which big_floor keeps the cap's
256^2, so every scene of the corpus gets the cap's 256^2. Chart boxes have no margin texels of
their own (unwrap.py: ceil(s w + 0.51) texels, the resolve clamps its bilinear taps to the
chart's box), so a chart smaller than a texel costs one texel.

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
tile walks this frame's slice of the tree (`read_visits()` counts the nodes visited).

Parameters:

<!-- parameters: generated from the Param declarations by `gibench manuals --write` -->
| parameter               | default   | range                | meaning |
|-------------------------|-----------|----------------------|---|
| texel_density           | 144.0     | 1.0 .. 10000.0       | lightmap texels per scene radius (the lightmap side is the smallest that packs the charts at this density) (quality knob; sweep 36.0, 72.0, 144.0, 288.0) |
| max_lightmap_resolution | 256       | 16 .. 1024           | largest lightmap side in texels (the density drops when reached) |
| gather                  | hierarchy | hierarchy, all_pairs | emitters: 'hierarchy' walks one octree over every texel; 'all_pairs' sums every texel from every texel (the article's loop) |
| refine_ratio            | 0.2       | 0.0 .. 1.0           | hierarchy: a node is used whole when its radius < this times its distance (quality knob; sweep 0.1, 0.2, 0.5) |
| emitter_budget          | 2048      | 0 .. 16777216        | emitter texels gathered per frame, rotating (0: all every frame) |
| bounces                 | 1         | 1 .. 8               | light bounces summed in the lightmap (the benchmark compares one bounce) |
<!-- end of parameters -->

A scene whose charts cannot be packed into the lightmap (too many separate charts for the
resolution) is skipped with a message naming `max_lightmap_resolution`.

Example: `gibench run --scenes cornell_spot,rooms --methods pbgi --res 128x96 --param
pbgi.gather=hierarchy,all_pairs` (the hierarchy against the article's all-pairs loop).

Limits of the stress suite's parameter extremes (`gibench stress`, issue #12; each a cost the
article states, at the suite's 300 s case timeout on llvmpipe, 2 shared cores):
In motion (bench.run.sequence): A moved light or camera costs it nothing to redo (update keeps the
amortised gather: every frame relights the texels from its own shadow maps), but the displayed
window catches up with the new light only over the next windows: its `lag_frames`. Moved geometry
prepares it again (unwrap, texture-space G-buffer) and its next frame converges a whole window.
Measured update per moved frame at 160x90, light (rooms_light_sweep) 0 ms, camera
(sponza_camera_walk) 0 ms, geometry (cornell_spot_moving_block) 372 ms (`python -m
studies.motion_costs`, 2 cores shared with other work).

Stress limit params:refine_ratio=0: every node refined to its texels is the article's all-pairs loop ("Of course this pass is really slow"), texels^2 transfers per bounce (52,600^2 = 2.8e9 on cornell_spot's 256^2 lightmap) through the stackless walk: over 300 s (gather=all_pairs, the same sum without the walk, finishes)
Stress limit params:bounces=8: the untimed first frame converges bounces x W frames of the amortised gather (the article computes the gather "in more than one frame by sampling only a few emitters each time"), each bounce re-gathering its window: 8 x 26 = 208 frames of work on cornell_spot's 256^2 lightmap, over 300 s (hidden_bounce, 256^2 already with 20 texels/m, timed out before the density rule changed)
Stress limit params:max_lightmap_resolution=1024: on a real scene the cap no longer binds, so the untimed first frame converges a window of 7x the texels: sibenik 291,941 texels and W = 143 frames (42,702 and 21 at the default 256), each frame's gather over 7x the receivers, ~50x the default's convergence work, over 300 s with a second stress run sharing the 2 cores; conference (its cap at 1024 done within 300 s on a quieter machine), cornell_box and the procedural scenes pass
Stress limit coplanar: coincident coplanar faces are two charts emitting the same surface (every triangle is unwrapped and emits) while Mitsuba's rays see one surface: the overlapped area emits twice and takes lightmap space (cornell_box 64x48: mean +6.1%; big_floor indirect 5.6%, lit_wall_corner 1.9%).

Quality ladder (`gibench run`), fast -> accurate:
  1. texel_density 72, max_lightmap_resolution 192, refine_ratio 0.5;
  2. the defaults (144 texels per scene radius, 256^2 at most, refine_ratio 0.2);
  3. texel_density 288, max_lightmap_resolution 384.
The lightmap's density is the error that dominates (the hierarchy at 0.2 is within 1% of the
all-pairs sum), so the rungs turn the density, and the cap with it where it binds; the top rung
keeps refine_ratio 0.2 (0.1 costs ~2.5x the visits for < 1%).
"""
from __future__ import annotations

import math
from pathlib import Path

import moderngl
import numpy as np

from bench.gl import load_compute, load_program, set_uniforms
from bench.gl.context import check_gl, loop_chunks, park
from bench.protocol.method import FrameOutput, MethodBase, Param, SkipRow

from .hierarchy import HIERARCHY_DEFINES, build_tree, tile_records
from .unwrap import LightmapTooSmall, chart_image, find_charts, unwrap

SHADERS = Path(__file__).parent / "shaders"
PBGI_DEFINES = {"BINDING_PBGI_TRIANGLES": 3, "BINDING_PBGI_TEXELS": 4, "BINDING_PBGI_SURFELS": 5,
                "BINDING_PBGI_EMITTERS": 6, "BINDING_PBGI_NODE_LINKS": 7, "BINDING_PBGI_LEVEL_NODES": 8,
                "BINDING_PBGI_TILES": 9, "BINDING_PBGI_VISITS": 10}
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


class TextureSpacePBGI(MethodBase):
    name = "pbgi"
    summary = "Texture-space point-based GI: lightmap texels as surfels, Bunnell disk transfer over an emitter octree"
    ladder = ({"texel_density": 72.0, "max_lightmap_resolution": 192, "refine_ratio": 0.5}, {},
              {"texel_density": 288.0, "max_lightmap_resolution": 384})
    stages = ("lightmap_direct", "emitter_hierarchy", "gather", "resolve")
    needs = frozenset({"gbuffer", "shadow_map", "direct"})
    params = {
        "texel_density": Param(144.0, "lightmap texels per scene radius (the lightmap side is the smallest that "
                                      "packs the charts at this density)", 1.0, 10000.0, quality=True,
                               sweep=(36.0, 72.0, 144.0, 288.0)),
        "max_lightmap_resolution": Param(256, "largest lightmap side in texels (the density drops when reached)",
                                         16, 1024),
        "gather": Param("hierarchy", "emitters: 'hierarchy' walks one octree over every texel; 'all_pairs' "
                                     "sums every texel from every texel (the article's loop)",
                        choices=("hierarchy", "all_pairs")),
        "refine_ratio": Param(0.2, "hierarchy: a node is used whole when its radius < this times its distance",
                              0.0, 1.0, quality=True, sweep=(0.1, 0.2, 0.5)),
        "emitter_budget": Param(2048, "emitter texels gathered per frame, rotating (0: all every frame)",
                                0, 2 ** 24),
        "bounces": Param(1, "light bounces summed in the lightmap (the benchmark compares one bounce)", 1, 8),
    }

    # ------------------------------------------------------------------ prepare (untimed)
    @classmethod
    def cost_terms(cls, params, size):
        # lightmap texels: the charts at texel_density per scene radius, up to the largest lightmap
        density = params["texel_density"] / max(size.radius, 1e-9)
        texels = min(density * density * size.area_m2, params["max_lightmap_resolution"] ** 2)
        return {"texels": texels, "texel_emitters": texels * params["emitter_budget"]}

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
            self.tiles = ctx.buffer(tile_records(tiles, position, normal, area, 1.0 / self.unwrap.scale).tobytes())
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

    def update(self, gpu, scene, facts, params, view, changes) -> None:
        """A scene in motion (bench.run.sequence): moved geometry invalidates the unwrap and the
        texture-space G-buffer, so it prepares again (the article re-renders them where an object
        moves; here the whole scene, as the charts are packed together). A moved light or camera
        invalidates nothing it keeps: every frame relights the texels from the frame's own shadow
        maps and resolves through the frame's own G-buffer, so the amortised gather goes on, and the
        displayed window catches up with the new light over the next windows (the lag the article's
        amortisation costs)."""
        if "geometry" in changes:
            super().update(gpu, scene, facts, params, view, changes)

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
