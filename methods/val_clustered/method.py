"""`val_clustered`: real-time indirect illumination with clustered visibility (Dong, Grosch,
Ritschel, Kautz, Seidel, "Real-time Indirect Illumination with Clustered Visibility", VMV 2009).

Instant radiosity whose N VPLs are clustered into M << N virtual area lights (VALs); every
receiver is lit by all N VPLs, but visibility is computed for the M VALs only, with a soft
shadow per VAL, so a penumbra is a sum of soft shadows instead of N hard ones:

    L(x) = rho_x / pi * sum_i Phi_i / pi * <n_x, w_i>+ <n_i, -w_i>+ / max(eps, d_i)^2 * V_C(i)(x)

Per frame (stages, after the shared `gbuffer_shadow`, `direct_light`, `rsm`):

1. `vpl_sample`: N VPLs from the reflective shadow map. Default (`vpl_sampling=importance`):
   importance-sampled exactly as `ir_unshadowed` / `ir_shadowed` (same code and frame 0's
   random numbers: identical VPLs for a given seed), which isolates the effect of the
   clustered visibility in comparisons. `vpl_sampling=halton`: the paper's point sampling of
   the RSM at N Halton locations (VPL flux = texel flux x texels / N, unlit texels give empty
   VPLs that no cluster takes). Either pattern is the same every frame of a seed (the paper's
   fixed QMC sequence). Only the Halton pattern gives the paper's temporal coherence when the
   light moves: the importance sampler's 1-D inverse CDF over row-major texels moves VPL k
   along a texel row when the flux changes slightly anywhere before it.
2. `val_clustering`: k-means on the GPU by scattering (paper Sec. 5, 6). VAL k starts at VPL
   k N / M, the same indices every frame (the paper's restart for temporal coherence). Each
   iteration draws one point per VPL whose vertex shader finds the nearest VAL under
   d = w_x |dx| / R + w_a angle(n_vpl, n_val) and scatters position, normal, flux and a count
   to that VAL's texel with additive blending; a compute pass divides by the count. A final
   scatter writes the mapping C (VPL -> VAL) and, with MAX blending, the bounding rectangle of
   the VPLs projected on the VAL's plane; the VAL's size is lambda = sqrt(its area).
3. `val_shadow_maps`: one paraboloid map per VAL (a tile of one R32F atlas), oriented around
   its normal. A compute pass (`map_split.glsl`) tests every (VAL, triangle) pair: pairs of an
   empty VAL, triangles behind the VAL's plane, inside its ignore radius or seen edge-on are
   dropped; a pair whose projected edges need no split and whose image's bounding box holds at
   most SPLAT_MAX_TEXELS = 64 texel centres is rasterised there (each covered texel centre gets
   the exact distance by an atomic minimum into an R32UI splat image, merged into the atlas);
   the others are listed for two draws with vertices pulled from the scene's buffers: plain
   triangles, and a tessellated draw for the pairs whose edges must bend (the projection turns
   straight edges into arcs; each edge is split into pieces whose chord strays at most
   TESS_SAGITTA_TEXELS = 0.5 texel from the arc, the level set from the projected edge length
   in map units per VAL and frame). Each texel stores the exact distance along its own
   direction to the plane of the triangle drawn there (an interpolated distance is off by
   percents across a tessellated piece). Then, for `visibility=cssm`: the map's far distance
   far_j (largest drawn distance, the depth normalisation), the Fourier basis and basis-z
   atlases (`fourier_terms` terms, same tiling; paper Sec. 6) and their MIP maps.
4. `val_visibility`: V_j(x) for every pixel and VAL (compute): parabolic CSSM (blocker
   search, penumbra estimate, MIP-filtered convolution of the basis, sharpened shadow test)
   or, with `visibility=hard`, one binary shadow-map test at the VAL centre.
5. `gather`: the sum above with interleaved sampling in `interleave` x `interleave` blocks
   (the paper: 8 x 8 blocks, 1024 VPLs -> 16 VPLs per pixel).
6. `blur`: geometry-aware blur over the block (alpha = 10% of the scene extent, beta = 0.8,
   Laine et al. 2007); skipped when `interleave` = 1.

Limits: with `cluster_count` = `vpl_count`, `visibility=hard` and `interleave` = 1 every VAL is
one VPL with a hard shadow and the method is `ir_shadowed` up to the shadow-map
parameterisation (paraboloid vs hemicube). Receivers behind a VAL's plane are taken as visible
(paper Sec. 5.1); geometry within `near_ignore` x lambda of a VAL centre is ignored.

Corrections and choices relative to the paper's text (recorded here as the house rule asks):
- Clustering distance: the paper's d = w_x dx + w_a da adds metres to radians, so the weights
  would depend on the scene's unit; dx is divided by the scene radius R here.
- Initial centres: "the VPL at index k-N/n" is k * N / M (VAL k of M).
- Penumbra (Fig. 3): p cos(beta) = (d - z_avg) lambda / z_avg and alpha = atan(p cos(beta) / d);
  the receiver slope beta cancels, alpha = atan(lambda (d - z_avg) / (z_avg d)) -> 0 for a
  point VAL (lambda = 0) or a contact blocker (z_avg = d): the hard-shadow limit holds.
- Kernel size: the paper's alpha / pi (texture width per half circle) is the map's scale only
  on average; the paraboloid map is conformal with 1 / (2 (1 + cos theta)) texture widths per
  radian at angle theta from the VAL normal, used here (alpha / pi is 27% too large at the
  centre and 36% too small at the rim).
- CSM shadow test: f(d, z) = 1/2 + 2 sum_k sin(c_k (z - d)) / c_k, c_k = pi (2k - 1) (lit for
  z > d). An unoccluded receiver reads its own surface (z = d, f = 1/2), so the filtered
  F = [w * f] must be rescaled; Annen et al.'s V = clamp(2 F, 0, 1) leaks: the 4-term step
  ramps over 7.6% of the depth range (with the scene-extent normalisation, a blocker 0.5 m in
  front of a receiver in `rooms` let 40% through) and its ringing lets up to 11% through an
  umbra, which gave 1.21x the visible one-bounce reference on `rooms` (+16% over per-VPL hard
  shadows). The default test is the scaled and biased reconstruction
  V = clamp(1 + s (F - 1/2), 0, 1) with s = `csm_sharpening` = 3 (s = 2 is Annen's): still 1
  at F = 1/2, 0 from F = 1/6, which removes the ringing and narrows the ramp to 4.5% of the
  range; the price is a darker penumbra (V = 1 - 1.5 b where a fraction b of the kernel is
  blocked by a distant occluder, instead of 1 - b). The blocker search uses the unscaled f.
- Depth normalisation: z = distance / far_j with far_j the largest distance drawn in VAL j's
  map (a reduction pass), not the scene's extent: the step's width is a fixed fraction of
  the range, so a tight range sharpens it in metres (`rooms`: 1.11 -> 1.08 of the reference).
- Map resolution: the paper's 256^2 maps serve 800 x 800 images (3 map texels per pixel for
  M = 30) and take 8% of its frame, the per-pixel gather 69%. At the benchmark's 128 x 96 the
  per-pixel stages are 50x cheaper while the maps are not, so the default is 128^2 (still 40
  map texels per pixel); 256 is a sweep value.
- Map rasterisation (issue #11): drawing every (VAL, triangle) pair through the tessellation
  pipeline ("the scene needs to be rendered once for each VAL", paper Sec. 6) made the map
  stage 67-74% of the frame on hidden_bounce and big_floor (M x triangles = 170 k and 250 k
  primitives on the software rasteriser, where each primitive costs a fixed set-up, and a
  tessellated one about 4x a plain one, whatever its size). Yet 98-100% of the pairs need no
  split at 128^2, and half of big_floor's pairs cover no texel centre at all: the compute pass
  above rasterises the small pairs (the same chord triangle, clip distances and exact
  per-texel distance as the draw; the maps agree with the all-tessellated pass on all but a
  handful of texels where a texel centre lies on a shared edge) and the GL pipeline gets the
  few large ones (big_floor: 60 of 250 k pairs, all tessellated; cornell_spot 3 k of 30 k). In
  one process, per-stage minima over 6 frames at 128 x 96 (a shared 2-core machine, so only
  ratios mean anything), the map stage's share of the frame went from 0.73 to 0.30 .. 0.44 on
  hidden_bounce, 0.84 to 0.29 on big_floor and 0.45 to 0.24 on cornell_spot; at 320 x 180 it
  is 0.05 .. 0.12 on every default scene. Culling by the VAL's hemisphere alone would not have
  helped: 78-100% of the pairs face their VAL.
- The basis is kept in 2-D atlases tiled as the depth atlas instead of texture arrays: MIP
  maps of one atlas cost a third of those of a 30-layer array on the software rasteriser, and
  with power-of-two tiles no MIP texel mixes two maps; lookups are clamped half a texel of
  the coarser level inside the tile. `shadow_resolution` must be a power of two.
- The basis-z images (z sin, z cos, z) are made at half resolution, each texel the mean of
  2 x 2 map texels, i.e. exactly level 1 of their MIP chain: the blocker search reads them
  with a kernel of at least 2 texels (the VAL's extent seen from the receiver, usually far
  wider), and the basis images it is divided by are read at the same level.
- The VAL "irradiance" texture holds the cluster's total flux (diagnostics); lighting uses
  the N VPLs themselves, as the paper does.
- The blur averages the unweighted gather (without receiver albedo), the albedo is applied
  after it, so that albedo edges stay sharp.

| parameter          | default | range            | meaning                                                    |
|--------------------|---------|------------------|------------------------------------------------------------|
| vpl_count          | 1024    | 1 .. 8192        | VPLs per frame (paper: 1024)                               |
| vpl_sampling       | importance | importance, halton | shared RSM importance sampler, or the paper's Halton    |
| cluster_count      | 30      | 1 .. 256         | VALs M (quality; sweep 5, 10, 20, 30, 60; paper: 30)       |
| kmeans_iterations  | 8       | 0 .. 64          | k-means iterations per frame (0: initial centres only)     |
| weight_position    | 0.7     | 0 .. 10          | w_x of the clustering distance (per scene radius)          |
| weight_angle       | 0.3     | 0 .. 10          | w_a of the clustering distance (per radian)                |
| visibility         | cssm    | cssm, hard       | soft CSSM per VAL, or one hard shadow test per VAL         |
| shadow_resolution  | 128     | 16 .. 1024       | paraboloid map resolution, a power of two (quality; sweep 64, 128, 256; paper: 256) |
| fourier_terms      | 4       | 4, 8             | CSM Fourier terms (paper: 4)                               |
| csm_sharpening     | 3.0     | 2 .. 16          | slope s of the CSM test clamp(1 + s (F - 1/2)) (2: Annen's) |
| near_ignore        | 0.5     | 0 .. 4           | ignore geometry within this x lambda of a VAL centre       |
| normal_offset      | 0.5     | 0 .. 16          | receiver offset along its normal, in map texel footprints  |
| interleave         | 8       | 1 .. 16          | interleaved-sampling block size B (1: no interleave/blur)  |
| blur_distance_rel  | 0.1     | 0 .. 10          | blur alpha: max position difference / scene extent (2R)    |
| blur_normal_dot    | 0.8     | -1 .. 1          | blur beta: min normal dot product                          |
| clamp_distance_rel | 1e-4    | 1e-7 .. 1        | eps of max(eps, d), relative to the scene radius           |

Quality ladder (fast -> accurate; `ladder`): {cluster_count 10, shadow_resolution 64},
{cluster_count 20}, {} (the paper's 30 VALs at 128^2), {cluster_count 60, shadow_resolution 256}.
The two knobs that trade time for visibility error together: more VALs give finer clusters
(smaller penumbra errors), a finer map sharper occluders; the VPL count stays at the paper's
1024 on every rung (the IR baselines are compared at the same count).

Memory: the basis atlases hold (tiles >= cluster_count) x shadow_resolution^2 x
(2 x fourier_terms + (2 x fourier_terms + 1) / 4) half floats (+1/3 for MIP maps), the visibility array width x height x
cluster_count floats, the map pass's pair list 4 x min(cluster_count x triangles, MAX_MAP_PAIRS)
bytes (16 MiB at most: triangles are processed in chunks); a combination over 1 GiB, an atlas over GL_MAX_TEXTURE_SIZE, or a
shadow_resolution that is not a power of two is refused in prepare() with an error naming the
parameters.

Stress limit params:vpl_count=1: fewer VPLs than `cluster_count` (30) cannot be clustered into that many VALs; prepare() refuses it with one line naming both parameters.
"""
from __future__ import annotations

import math
from pathlib import Path

import moderngl
import numpy as np

from bench.gl import load_compute, load_program, set_uniforms
from bench.gl.context import loop_chunks, park
from bench.gl.passes import frame_random
from bench.protocol.method import FrameOutput, MethodBase, Param, ParamError
from bench.gl.vpl import CLAMP_DOC
from bench.gl.vpl import VPL_DEFINES, RsmVplSampler

SHADERS = Path(__file__).parent / "shaders"
VAL_RECORD_BYTES = 3 * 16            # struct Val in val_records.glsl: three vec4
VAL_DEFINES = dict(VPL_DEFINES, BINDING_VALS=7, BINDING_VPL_CLUSTER=8, BINDING_VAL_COUNT=9, BINDING_MAP_POSITIONS=10,
                   BINDING_MAP_FACES=11, BINDING_MAP_PAIRS=12, BINDING_MAP_COMMANDS=13)
TESS_SAGITTA_TEXELS = 0.5           # largest chord-to-arc distance of a tessellated edge piece in the map
TESS_MAX_LEVEL = 64                  # GL guarantees tessellation levels up to 64
LIFT_SCALE = 1e-4                    # VAL map centre above its surface / scene radius (as ir_shadowed)
NEAR_SCALE = 1e-5                    # smallest ignore radius / scene radius (ir_shadowed's near plane)
BLOCKER_MIN = 0.02                   # filtered blocker fraction below which a receiver is unoccluded
MAX_BASIS_BYTES = 1 << 30
PAIR_TRIANGLE_BITS = 24              # a listed map pair is one uint: VAL << 24 | triangle - chunk start (<= 256 VALs)
MAX_MAP_PAIRS = 1 << 22              # (VAL, triangle) pairs per chunk of the map pass (a 16 MiB pair list at most)
MAP_GROUP = 64                       # local_size_x of map_split.glsl
SPLAT_MAX_TEXELS = 64                # map_split.glsl rasterises a pair whose image's bounding box holds <= this many texel centres
SPLAT_MIN_COS = 0.05                 # ... unless a corner lies within acos(SPLAT_MIN_COS - 1) of the direction opposite the VAL normal
MAP_EMPTY = 3.0e38                   # distance of an empty map texel
# two DrawArraysIndirect commands (count, instances, first, base instance; moderngl's 5-uint stride): the
# untessellated and the tessellated listed map pairs; map_split.glsl adds 3 to a count per listed pair
MAP_COMMANDS_RESET = np.array([0, 1, 0, 0, 0, 0, 1, 0, 0, 0], np.uint32).tobytes()
GL_R32UI = 0x8236
GL_R32F = 0x822E


class HaltonVplSampler(RsmVplSampler):
    """The paper's VPL generation: the RSM point-sampled at N Halton locations (toroidally
    shifted by the frame's random value), each VPL carrying texel flux x texels / N. Same VPL
    SSBO and interface as the shared importance sampler (whose buffers it reuses)."""

    def __init__(self, ctx: moderngl.Context, vpl_count: int):
        super().__init__(ctx, vpl_count)
        self.halton_pass = load_compute(ctx, SHADERS / "halton_vpls.glsl", VAL_DEFINES)

    def sample(self, rsm, rand_u32: int) -> None:
        shift = np.random.default_rng(int(rand_u32)).random(2)
        self.vpls.bind_to_storage_buffer(VPL_DEFINES["BINDING_VPLS"])
        rsm.bind(self.halton_pass, 0)
        set_uniforms(self.halton_pass, u_vpl_count=self.vpl_count, u_shift=tuple(float(v) for v in shift))
        self.halton_pass.run(group_x=(self.vpl_count + 63) // 64)
        self.ctx.memory_barrier()

    def release(self) -> None:
        super().release()
        self.halton_pass.release()


class ValClustering:
    """k-means of the VPLs into M VALs by point scattering (paper Sec. 5, 6)."""

    def __init__(self, gpu, vpl_count: int, cluster_count: int, weights: tuple):
        ctx = self.ctx = gpu.ctx
        self.gpu, self.vpl_count, self.cluster_count = gpu, int(vpl_count), int(cluster_count)
        self.vals = ctx.buffer(reserve=self.cluster_count * VAL_RECORD_BYTES)
        self.vpl_cluster = ctx.buffer(reserve=self.vpl_count * 4)
        self.val_vpl_count = ctx.buffer(reserve=self.cluster_count * 4)
        self.zero_counts = np.zeros(self.cluster_count, np.uint32).tobytes()
        self.sums = [ctx.texture((self.cluster_count, 1), 4, dtype="f4") for _ in range(3)]
        self.bounds = ctx.texture((self.cluster_count, 1), 4, dtype="f4")
        for t in (*self.sums, self.bounds):
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.sum_fbo = ctx.framebuffer(self.sums)
        self.bounds_fbo = ctx.framebuffer([self.bounds])
        self.init_pass = load_compute(ctx, SHADERS / "kmeans_init.glsl", VAL_DEFINES)
        self.scatter = load_program(ctx, SHADERS / "kmeans_scatter.glsl", dict(VAL_DEFINES, ASSIGN_PASS=0))
        self.assign = load_program(ctx, SHADERS / "kmeans_scatter.glsl", dict(VAL_DEFINES, ASSIGN_PASS=1))
        self.update = load_compute(ctx, SHADERS / "kmeans_update.glsl", dict(VAL_DEFINES, FINALIZE=0))
        self.finalize = load_compute(ctx, SHADERS / "kmeans_update.glsl", dict(VAL_DEFINES, FINALIZE=1))
        self.scatter_vao = ctx.vertex_array(self.scatter, [])
        self.assign_vao = ctx.vertex_array(self.assign, [])
        box_min = np.asarray(gpu.scene.vertices.min(axis=0) - gpu.origin, np.float32)
        box_max = np.asarray(gpu.scene.vertices.max(axis=0) - gpu.origin, np.float32)
        self.common = dict(u_cluster_count=self.cluster_count, u_vpl_count=self.vpl_count,
                           u_weight_position=float(weights[0]), u_weight_angle=float(weights[1]),
                           u_inv_scene_radius=1.0 / gpu.radius, u_val_lift=LIFT_SCALE * gpu.radius,
                           u_box_min=tuple(float(v) for v in box_min), u_box_max=tuple(float(v) for v in box_max))

    def bind(self) -> None:
        self.vals.bind_to_storage_buffer(VAL_DEFINES["BINDING_VALS"])
        self.vpl_cluster.bind_to_storage_buffer(VAL_DEFINES["BINDING_VPL_CLUSTER"])
        self.val_vpl_count.bind_to_storage_buffer(VAL_DEFINES["BINDING_VAL_COUNT"])

    def run(self, sampler: RsmVplSampler, iterations: int) -> None:
        ctx = self.ctx
        groups = (self.cluster_count + 63) // 64
        sampler.bind()
        self.bind()
        for prog in (self.init_pass, self.scatter, self.assign, self.update, self.finalize):
            set_uniforms(prog, **self.common)
        self.init_pass.run(group_x=groups)
        ctx.memory_barrier()
        ctx.disable(moderngl.DEPTH_TEST)
        ctx.enable(moderngl.BLEND)
        for _ in range(iterations):
            self.sum_fbo.use()
            ctx.viewport = (0, 0, self.cluster_count, 1)
            self.sum_fbo.clear(0.0, 0.0, 0.0, 0.0)
            ctx.blend_equation = moderngl.FUNC_ADD
            ctx.blend_func = moderngl.ONE, moderngl.ONE
            self.scatter_vao.render(moderngl.POINTS, vertices=self.vpl_count)
            for unit, (name, tex) in enumerate(zip(("u_sum_position", "u_sum_normal", "u_sum_flux"), self.sums)):
                tex.use(unit)
                set_uniforms(self.update, **{name: unit})
            self.update.run(group_x=groups)
            ctx.memory_barrier()
        # final pass: the mapping C, the VPL count of each VAL and its bounding rectangle (MAX blending)
        self.val_vpl_count.write(self.zero_counts)
        self.bounds_fbo.use()
        ctx.viewport = (0, 0, self.cluster_count, 1)
        self.bounds_fbo.clear(-3.0e38, -3.0e38, -3.0e38, -3.0e38)
        ctx.blend_equation = moderngl.MAX
        self.assign_vao.render(moderngl.POINTS, vertices=self.vpl_count)
        ctx.blend_equation = moderngl.FUNC_ADD
        ctx.disable(moderngl.BLEND)
        ctx.memory_barrier()
        self.bounds.use(0)
        set_uniforms(self.finalize, u_bounds=0)
        self.finalize.run(group_x=groups)
        ctx.memory_barrier()

    def read(self) -> dict:
        """VALs and the mapping as numpy (tests, diagnostics): positions re-centred."""
        rec = np.frombuffer(self.vals.read(), np.float32).reshape(self.cluster_count, 3, 4)
        return {"position": rec[:, 0, :3].copy(), "count": rec[:, 0, 3].copy(), "normal": rec[:, 1, :3].copy(),
                "size": rec[:, 1, 3].copy(), "flux": rec[:, 2, :3].copy(), "far": rec[:, 2, 3].copy(),
                "mapping": np.frombuffer(self.vpl_cluster.read(), np.int32).copy()}

    def release(self) -> None:
        park(self.ctx)
        for obj in (self.sum_fbo, self.bounds_fbo, *self.sums, self.bounds, self.scatter_vao, self.assign_vao,
                    self.scatter, self.assign, self.init_pass, self.update, self.finalize, self.vals,
                    self.vpl_cluster, self.val_vpl_count):
            obj.release()


class ParaboloidShadowMaps:
    """One paraboloid distance map per VAL (tiles of an R32F atlas) and, for CSSM, the Fourier
    basis atlases (same tiling) with their MIP maps."""

    BASIS_NAMES = ("u_basis_sin", "u_basis_cos", "u_basis_zsin", "u_basis_zcos")

    def __init__(self, gpu, clustering: ValClustering, resolution: int, cssm: bool, term_groups: int,
                 near_ignore: float):
        ctx = self.ctx = gpu.ctx
        self.gpu, self.clustering, self.resolution = gpu, clustering, int(resolution)
        self.cssm, self.term_groups, self.near_ignore = bool(cssm), int(term_groups), float(near_ignore)
        m = clustering.cluster_count
        self.tiles_x = math.ceil(math.sqrt(m))
        self.tiles_y = math.ceil(m / self.tiles_x)
        size = (self.tiles_x * self.resolution, self.tiles_y * self.resolution)
        max_size = int(ctx.info["GL_MAX_TEXTURE_SIZE"])
        if max(size) > max_size:
            raise ParamError(f"method 'val_clustered': cluster_count={m} x shadow_resolution={resolution} needs a "
                             f"{size[0]}x{size[1]} map atlas, over GL_MAX_TEXTURE_SIZE={max_size}")
        # a chord c of a circle of radius >= 1 (uv units) strays at most c^2 / 8 from its arc
        max_arc_uv = math.sqrt(8.0 * TESS_SAGITTA_TEXELS * 2.0 / self.resolution)
        self.max_lod = int(math.log2(self.resolution))  # level at which a tile is one texel
        self.defines = dict(VAL_DEFINES, TERM_GROUPS=self.term_groups, TESS_MAX_ARC_UV=max_arc_uv,
                            TESS_MAX_LEVEL=TESS_MAX_LEVEL, MAX_LOD=self.max_lod,
                            PAIR_TRIANGLE_BITS=PAIR_TRIANGLE_BITS, SPLAT_MAX_TEXELS=SPLAT_MAX_TEXELS, SPLAT_MIN_COS=SPLAT_MIN_COS,
                            MAP_EMPTY=MAP_EMPTY)
        self.atlas = ctx.texture(size, 1, dtype="f4")
        self.atlas.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.fbo = ctx.framebuffer([self.atlas])
        # (VAL, triangle) pairs, chunk by chunk of triangles: map_split.glsl splats the small ones, lists the others
        self.chunk_triangles = min(gpu.triangle_count, max(1, MAX_MAP_PAIRS // m), 1 << PAIR_TRIANGLE_BITS,
                                   MAP_GROUP * 65535)   # GL guarantees 65535 work groups per dimension
        self.pair_capacity = m * self.chunk_triangles
        self.pairs = ctx.buffer(reserve=4 * self.pair_capacity)
        self.commands = ctx.buffer(MAP_COMMANDS_RESET)
        self.commands_reset = ctx.buffer(MAP_COMMANDS_RESET)  # copied on the GPU: no CPU upload in a frame
        empty_bits = np.full(size[0] * size[1], MAP_EMPTY, np.float32).view(np.uint32)
        self.splat = ctx.texture(size, 1, empty_bits.tobytes(), dtype="u4")   # map_merge.glsl resets it each frame
        self.splat.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.split_pass = load_compute(ctx, SHADERS / "map_split.glsl", self.defines)
        self.program = load_program(ctx, SHADERS / "paraboloid_depth.glsl", self.defines)
        self.tess_program = load_program(ctx, SHADERS / "paraboloid_depth_tess.glsl", self.defines)
        self.merge_program = load_program(ctx, SHADERS / "map_merge.glsl", self.defines)
        self.vao = ctx.vertex_array(self.program, [])
        self.tess_vao = ctx.vertex_array(self.tess_program, [])
        self.merge_vao = ctx.vertex_array(self.merge_program, [])
        # RGBA16F atlases: sin_g, cos_g per group g at the map resolution; zsin_g, zcos_g per
        # group and the R16F z at half resolution (level 1 of their MIP chain, see cssm_basis.glsl).
        # (The paper's 8-bit sin/cos would save a third of the basis pass here, but their MIP
        # levels, each rounded to 8 bits, shift F by ~0.01 for the wide kernels of large VALs.)
        self.basis_full, self.basis_half = [], []
        self.basis_fbos, self.basis_programs, self.basis_vaos = [], [], []
        self.far_pass = None
        if self.cssm:
            half = (size[0] // 2, size[1] // 2)
            for _ in range(self.term_groups):
                self.basis_full += [ctx.texture(size, 4, dtype="f2") for _ in range(2)]
                self.basis_half += [ctx.texture(half, 4, dtype="f2") for _ in range(2)]
            self.basis_half.append(ctx.texture(half, 1, dtype="f2"))
            for t in self.textures():
                t.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
                t.repeat_x = t.repeat_y = False
            for half_res, targets in ((0, self.basis_full), (1, self.basis_half)):
                prog = load_program(ctx, SHADERS / "cssm_basis.glsl", dict(self.defines, HALF_RES=half_res))
                self.basis_programs.append(prog)
                self.basis_vaos.append(ctx.vertex_array(prog, []))
                self.basis_fbos.append(ctx.framebuffer(targets))
            self.far_pass = load_compute(ctx, SHADERS / "map_far.glsl", self.defines)

    def textures(self) -> list:
        return self.basis_full + self.basis_half

    def render(self) -> None:
        ctx = self.ctx
        self.fbo.use()
        ctx.viewport = (0, 0, self.atlas.width, self.atlas.height)
        ctx.scissor = None
        self.fbo.clear(MAP_EMPTY, 0.0, 0.0, 0.0)
        ctx.enable_only(moderngl.BLEND)
        ctx.blend_equation = moderngl.MIN
        for i in range(5):
            ctx.enable_direct(0x3000 + i)  # GL_CLIP_DISTANCE0 + i
        self.clustering.bind()
        gpu = self.gpu
        gpu.vbo_position.bind_to_storage_buffer(VAL_DEFINES["BINDING_MAP_POSITIONS"])
        gpu.ibo.bind_to_storage_buffer(VAL_DEFINES["BINDING_MAP_FACES"])
        self.pairs.bind_to_storage_buffer(VAL_DEFINES["BINDING_MAP_PAIRS"])
        self.commands.bind_to_storage_buffer(VAL_DEFINES["BINDING_MAP_COMMANDS"])
        self.splat.bind_to_image(0, read=True, write=True, level=0, format=GL_R32UI)
        m = self.clustering.cluster_count
        for prog in (self.split_pass, self.program, self.tess_program):
            set_uniforms(prog, **self.clustering.common)
            set_uniforms(prog, u_tiles_x=self.tiles_x, u_tiles_y=self.tiles_y, u_near_ignore=self.near_ignore,
                         u_resolution=self.resolution, u_near_min=NEAR_SCALE * gpu.radius,
                         u_pair_capacity=self.pair_capacity)
        ctx.patch_vertices = 3
        for first, end in loop_chunks(gpu.triangle_count, self.chunk_triangles):
            ctx.copy_buffer(self.commands, self.commands_reset)
            for prog in (self.split_pass, self.program, self.tess_program):
                set_uniforms(prog, u_first_triangle=first, u_chunk_triangles=end - first)
            self.split_pass.run(group_x=(end - first + MAP_GROUP - 1) // MAP_GROUP, group_y=m)
            ctx.memory_barrier()
            self.vao.render_indirect(self.commands, mode=moderngl.TRIANGLES, count=1, first=0)
            self.tess_vao.render_indirect(self.commands, mode=moderngl.PATCHES, count=1, first=1)
        for i in range(5):
            ctx.disable_direct(0x3000 + i)
        ctx.memory_barrier()
        self.merge_vao.render(moderngl.TRIANGLES, vertices=3)   # still MIN blending
        ctx.memory_barrier()
        ctx.blend_equation = moderngl.FUNC_ADD
        ctx.disable(moderngl.BLEND)
        if self.cssm:
            ctx.memory_barrier()
            self.atlas.use(0)
            set_uniforms(self.far_pass, **self.clustering.common)
            set_uniforms(self.far_pass, u_depth_atlas=0, u_tiles_x=self.tiles_x, u_resolution=self.resolution)
            self.far_pass.run(group_x=self.clustering.cluster_count)
            ctx.memory_barrier()
            self.atlas.use(0)
            for prog, vao, fbo in zip(self.basis_programs, self.basis_vaos, self.basis_fbos):
                fbo.use()
                ctx.viewport = (0, 0, fbo.width, fbo.height)
                set_uniforms(prog, **self.clustering.common)
                set_uniforms(prog, u_depth_atlas=0, u_tiles_x=self.tiles_x, u_tiles_y=self.tiles_y)
                vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=self.tiles_x * self.tiles_y)
            for tex in self.basis_full:
                tex.build_mipmaps(0, self.max_lod)
            for tex in self.basis_half:
                tex.build_mipmaps(0, self.max_lod - 1)

    def bind(self, program, unit: int) -> int:
        self.atlas.use(unit)
        set_uniforms(program, u_depth_atlas=unit, u_tiles_x=self.tiles_x, u_resolution=self.resolution,
                     u_atlas_size=tuple(float(v) for v in self.atlas.size))
        unit += 1
        if self.cssm:
            # group g's sin, cos in basis_full[2g:2g+2]; its zsin, zcos in basis_half[2g:2g+2]
            for k, name in enumerate(self.BASIS_NAMES):
                textures = (self.basis_full if k < 2 else self.basis_half)[k % 2:2 * self.term_groups:2]
                units = []
                for tex in textures:
                    tex.use(unit)
                    units.append(unit)
                    unit += 1
                member = program.get(name, None)
                if member is not None:
                    member.value = units if len(units) > 1 else units[0]
            self.basis_half[-1].use(unit)
            set_uniforms(program, u_basis_z=unit)
            unit += 1
        return unit

    def release(self) -> None:
        park(self.ctx)
        for obj in (*self.basis_fbos, self.fbo, self.atlas, self.vao, self.tess_vao, self.merge_vao, self.program,
                    self.tess_program, self.merge_program, self.split_pass, self.pairs, self.commands, self.commands_reset,
                    self.splat, *self.textures(), *self.basis_vaos, *self.basis_programs, self.far_pass):
            if obj is not None:
                obj.release()


class ClusteredVirtualAreaLights(MethodBase):
    name = "val_clustered"
    summary = "Instant radiosity with VPLs clustered into virtual area lights with soft (CSSM) visibility"
    stages = ("vpl_sample", "val_clustering", "val_shadow_maps", "val_visibility", "gather", "blur")
    needs = frozenset({"gbuffer", "shadow_map", "direct", "rsm"})
    ladder = ({"cluster_count": 10, "shadow_resolution": 64}, {"cluster_count": 20}, {},
              {"cluster_count": 60, "shadow_resolution": 256})
    params = {
        "vpl_count": Param(1024, "VPLs drawn from the RSM per frame (importance sampled, stratified)", 1, 8192),
        "vpl_sampling": Param("importance", "VPL pattern: the shared RSM importance sampler (the IR baselines' "
                              "VPLs) or the paper's Halton point sampling of the RSM", choices=("importance", "halton")),
        "cluster_count": Param(30, "virtual area lights M (k-means clusters of the VPLs)", 1, 256,
                               quality=True, sweep=(5, 10, 20, 30, 60)),
        "kmeans_iterations": Param(8, "k-means iterations per frame (0: the initial centres only)", 0, 64),
        "weight_position": Param(0.7, "w_x: clustering weight of the position difference (per scene radius)", 0.0, 10.0),
        "weight_angle": Param(0.3, "w_a: clustering weight of the normal angle (per radian)", 0.0, 10.0),
        "visibility": Param("cssm", "per-VAL visibility: soft (parabolic CSSM) or one hard shadow test",
                            choices=("cssm", "hard")),
        "shadow_resolution": Param(128, "paraboloid shadow map resolution per VAL (texels, a power of two)", 16, 1024,
                                   quality=True, sweep=(64, 128, 256)),
        "fourier_terms": Param(4, "Fourier terms of the convolution shadow maps", choices=(4, 8)),
        "csm_sharpening": Param(3.0, "slope s of the scaled CSM shadow test V = clamp(1 + s (F - 1/2), 0, 1) "
                                     "(2: Annen et al.'s plain scaling)", 2.0, 16.0),
        "near_ignore": Param(0.5, "ignore geometry closer to a VAL centre than this times the VAL size", 0.0, 4.0),
        "normal_offset": Param(0.5, "receiver offset along its geometric normal for the VAL shadow test, "
                                    "in map texel footprints at the receiver", 0.0, 16.0),
        "interleave": Param(8, "interleaved sampling block size B (B x B pixels share the VPLs; 1: off)", 1, 16),
        "blur_distance_rel": Param(0.1, "geometry-aware blur: max position difference / scene extent", 0.0, 10.0),
        "blur_normal_dot": Param(0.8, "geometry-aware blur: min dot product of the normals", -1.0, 1.0),
        "clamp_distance_rel": Param(1e-4, CLAMP_DOC, 1e-7, 1.0),
    }

    def prepare(self, gpu, scene, facts, params, view) -> None:
        self.params = params
        self.ctx = ctx = gpu.ctx
        n, m = params["vpl_count"], params["cluster_count"]
        if m > n:
            raise ParamError(f"method 'val_clustered': cluster_count={m} is more than vpl_count={n}")
        if params["weight_position"] == 0.0 and params["weight_angle"] == 0.0:
            raise ParamError("method 'val_clustered': weight_position and weight_angle are both 0")
        cssm = params["visibility"] == "cssm"
        res = params["shadow_resolution"]
        groups = params["fourier_terms"] // 4
        if res & (res - 1):
            raise ParamError(f"method 'val_clustered': shadow_resolution={res} is not a power of two (the MIP "
                             f"levels of the map atlases must not mix the maps of neighbouring VALs)")
        tiles = math.ceil(math.sqrt(m)) * math.ceil(m / math.ceil(math.sqrt(m)))
        basis_bytes = tiles * res * res * (8 * groups + (8 * groups + 1) // 4) * 2 * 4 // 3 if cssm else 0
        if basis_bytes > MAX_BASIS_BYTES:
            raise ParamError(f"method 'val_clustered': cluster_count={m} x shadow_resolution={res} x "
                             f"fourier_terms={params['fourier_terms']} needs {basis_bytes / 2**30:.1f} GiB of "
                             f"basis maps, over {MAX_BASIS_BYTES / 2**30:.0f} GiB")
        visibility_bytes = view.width * view.height * m * 4
        if visibility_bytes > MAX_BASIS_BYTES:
            raise ParamError(f"method 'val_clustered': cluster_count={m} at {view.width}x{view.height} needs "
                             f"{visibility_bytes / 2**30:.1f} GiB of per-pixel VAL visibility, over "
                             f"{MAX_BASIS_BYTES / 2**30:.0f} GiB")
        self.width, self.height = view.width, view.height
        self.eps = params["clamp_distance_rel"] * gpu.radius
        self.radius = gpu.radius
        sampler_cls = HaltonVplSampler if params["vpl_sampling"] == "halton" else RsmVplSampler
        self.sampler = sampler_cls(ctx, n)
        self.clustering = ValClustering(gpu, n, m, (params["weight_position"], params["weight_angle"]))
        self.maps = ParaboloidShadowMaps(gpu, self.clustering, res, cssm, groups, params["near_ignore"])
        defines = dict(self.maps.defines, VISIBILITY_CSSM=int(cssm))
        self.visibility_pass = load_compute(ctx, SHADERS / "val_visibility.glsl", defines)
        self.visibility = ctx.texture_array((view.width, view.height, m), 1, dtype="f4")
        self.visibility.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.gather_prog = load_program(ctx, SHADERS / "gather.glsl", defines)
        self.gather_vao = ctx.vertex_array(self.gather_prog, [])
        self.gathered = ctx.texture((view.width, view.height), 4, dtype="f4")
        self.gathered.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.gather_fbo = ctx.framebuffer([self.gathered])
        self.blur_prog = load_program(ctx, SHADERS / "blur.glsl", defines)
        self.blur_vao = ctx.vertex_array(self.blur_prog, [])
        self.indirect = ctx.texture((view.width, view.height), 4, dtype="f4")
        self.indirect.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.blur_fbo = ctx.framebuffer([self.indirect])

    def render(self, frame, prof) -> FrameOutput:
        ctx, passes, p = self.ctx, frame.passes, self.params
        interleave = p["interleave"]
        with prof.stage("vpl_sample"):
            # one VPL pattern for every frame of a seed (the paper's fixed QMC sequence), so that
            # a static scene keeps its VPLs and VALs; frame 0's equals ir_shadowed's
            self.sampler.sample(passes.rsm, frame_random(frame.seed, 0, 0))
        with prof.stage("val_clustering"):
            self.clustering.run(self.sampler, p["kmeans_iterations"])
        with prof.stage("val_shadow_maps"):
            self.maps.render()
        with prof.stage("val_visibility"):
            prog = self.visibility_pass
            self.clustering.bind()
            set_uniforms(prog, **self.clustering.common)
            unit = passes.gbuffer.bind(prog)
            self.maps.bind(prog, unit)
            set_uniforms(prog, u_normal_offset=float(p["normal_offset"]), u_size=(self.width, self.height),
                         u_blocker_min=BLOCKER_MIN, u_csm_sharpening=float(p["csm_sharpening"]))
            self.visibility.bind_to_image(5, read=False, write=True, level=0, format=GL_R32F)
            prog.run(group_x=(self.width + 7) // 8, group_y=(self.height + 7) // 8)
            ctx.memory_barrier()
        with prof.stage("gather"):
            fbo = self.blur_fbo if interleave == 1 else self.gather_fbo
            fbo.use()
            ctx.viewport = (0, 0, self.width, self.height)
            fbo.clear(0.0, 0.0, 0.0, 0.0)
            ctx.disable(moderngl.DEPTH_TEST)
            ctx.enable(moderngl.BLEND)  # additive: each draw sums one chunk of the VPLs
            ctx.blend_func = moderngl.ONE, moderngl.ONE
            prog = self.gather_prog
            unit = passes.gbuffer.bind(prog)
            self.visibility.use(unit)
            set_uniforms(prog, u_visibility=unit, u_interleave=interleave, u_apply_albedo=interleave == 1,
                         u_eps=float(self.eps))
            self.sampler.bind()
            self.clustering.bind()
            # the loop limit counts iterations: a draw scans chunk * B^2 VPL indices
            for first, end in loop_chunks(self.sampler.vpl_count, 16384 * interleave * interleave):
                set_uniforms(prog, u_vpl_first=first, u_vpl_end=end)
                self.gather_vao.render(moderngl.TRIANGLES, vertices=3)
            ctx.disable(moderngl.BLEND)
        skipped = ()
        if interleave > 1:
            with prof.stage("blur"):
                self.blur_fbo.use()
                ctx.viewport = (0, 0, self.width, self.height)
                prog = self.blur_prog
                unit = passes.gbuffer.bind(prog)
                self.gathered.use(unit)
                set_uniforms(prog, u_gathered=unit, u_interleave=interleave,
                             u_max_distance=float(p["blur_distance_rel"] * 2.0 * self.radius),
                             u_min_normal_dot=float(p["blur_normal_dot"]))
                self.blur_vao.render(moderngl.TRIANGLES, vertices=3)
        else:
            skipped = ("blur",)
        return FrameOutput(direct=passes.direct.radiance, indirect=self.indirect, skipped_stages=skipped)

    def release(self) -> None:
        if getattr(self, "ctx", None) is None:
            return
        park(self.ctx)
        for name in ("blur_fbo", "indirect", "blur_vao", "blur_prog", "gather_fbo", "gathered", "gather_vao",
                     "gather_prog", "visibility", "visibility_pass", "maps", "clustering", "sampler"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.release()
                setattr(self, name, None)
