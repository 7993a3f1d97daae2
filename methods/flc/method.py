"""`flc`: Forward Light Cuts (Laurent, Delalandre, de La Rivière, Boubekeur, EGSR 2016).

One-bounce diffuse indirect lighting without indirect visibility, estimated without bias
(with `last_level_unbounded`) from the many-lights sum of eq. 4,

    L_ML(x) = sum_t H(t, x, n_x) A(t),
    H = rho_x / pi * L_t(y_t -> x) <n_x, xy>+ <n_t, yx>+ / max(eps, |x - y_t|)^2,
    L_t(w) = rho_t E(t) 3/(2 pi) <n_t, w>+                                     (eq. 5, 6)

by a stochastic multiscale cut computed forward, every frame, with no precomputation:

1. Alg. 2: every vertex carries a uint32 `v_rand` (set at load); a triangle's random value is
   u_rand xor its three v_rand (u_rand changes every frame); u is its PCG hash in [0, 1).
2. Alg. 1: S_0 = 4 pi D_near^2 / N_avg (eq. 1), S_k = S_0 mu^k (eq. 17), S_bar_k =
   1 / sum_{j<=k} 1/S_j; a triangle goes to the first level k with u < A / S_bar_k, else it is
   discarded. Triangles with A > S_bar_N are divergent.
3. Regular pass (stage `regular`): one draw of the whole scene. Its geometry shader classifies
   each triangle, appends divergent ones to a storage buffer and atomically grows an indirect
   draw command, and turns each kept regular triangle into one VPL at its centre (jittered over
   the triangle in progressive mode) with the shadowed direct radiosity rho E of both sides
   (two-sided surfaces, like `manylights`), emitted as a quad over the screen-space bound of
   its support in one random interleaved-sampling tile. The fragment stage reads the GBuffer
   and adds H S_k f^k(d) with d = |x - y| / |<n_t, (x - y)/|x - y|>| (eq. 10, 14).
4. Divergent pass (stage `divergent`): the buffer drawn with `render_indirect` (no CPU
   read-back) as patches through the tessellator, at the smallest uniform level whose largest
   piece is regular (measured once on the tessellator, `tessellation.py`); triangles that need
   more than level 64 are pre-split into m^2 equal sub-patches when appended. A piece's random
   value is u_rand xor the base triangle's v_rand xor the noise texture at its three vertices'
   barycentric coordinates (Alg. 2, Fig. 8); then the same splat. Skipped (and recorded as
   skipped) when the scene facts say no triangle is divergent, or with `divergent_pass` off
   (divergent triangles are then dropped: Fig. 7 top).
5. Stage `upscale_blur`: untile the 4^L tiles and a separable geometry-aware tent blur (each
   tile's samples linearly interpolated, every tile weighing the same), then rho_x / pi.

A triangle lands in level k with probability A / S_k, and F^k = S_k f^k, so
E[K] = sum_t H sum_k S_k f^k A / S_k = sum_t H A sum_k f^k: the estimator is unbiased wherever
the f^k sum to 1. Interleaved sampling keeps that: a VPL splats into one of the T = 4^L tiles
at random with weight T. Progressive mode averages F sub-frames (new u_rand, jittered VPLs)
inside one render() and converges to `manylights` with `emission=flc` and the same jitter.

Corrections to the paper (see `levels.py`):
- eq. 3 prints P(t in L^k) = A / S_bar_k; by Alg. 1 that is the probability of levels 0..k.
  The level-k probability is A / S_k, which is what makes eq. 9 hold with F^k = S_k f^k.
- eq. 16 prints f^0 = 1 on ]0, D_1], overlapping f^1's ramp on ]D_0, D_1] (sum > 1 there).
  We use hats that sum to 1 on ]0, D_N]: f^0 = 1 up to D_0 and falls to 0 at D_1; f^k rises on
  ]D_{k-1}, D_k] and falls on ]D_k, D_{k+1}] (D_{N+1} = D_N: f^N does not fall). Chosen because
  it keeps the paper's nodes D_k = sqrt(S_k) (eq. 18), so that every interior level reaches a
  receiver with the same expected number of VPLs (Sec. 5; `FlcLevels.expected_vpls_reaching`).
- Beyond D_N every f^k is 0 (the paper's choice): far and grazing bounces are cut.
  `last_level_unbounded` sets f^N = 1 beyond D_N for the exact estimator (every level-N VPL
  then splats over the whole screen).

Choosing parameters: the reach is D_N = dnear_factor R sqrt(4 pi / N_avg) mu^(N/2), so raising
N_avg alone shrinks it (more energy cut) unless N or mu grows too. A level-k VPL stands for
S_k of surface, so a lit region of area A_lit holds about A_lit / S_k level-k VPLs: when the
light falls on a small patch and the receivers are far from it (d in the top levels), a frame
rests on a handful of powerful VPLs and is very noisy (the paper's "spikes"); progressive
mode removes that noise. `analysis.energy_beyond_support` measures the share cut beyond D_N.

Noise, not bias (measured on `cornell_spot`, 96x72, defaults with `last_level_unbounded` and 16
progressive frames). The image mean of one render has a relative standard deviation of 18.6%
over 512 seeds (`analysis.level_statistics` predicts 17.8% from the level noise alone): 95% of
the image comes through levels 4 and 5 (d of 0.6 to 2.5 m in a 2 m box), and the spot's lit
5 m^2 holds 3.4 level-4 and 0.84 level-5 VPLs per sub-frame (S_4 = 1.5 m^2, S_5 = 6 m^2). The
error comes from a few powerful VPLs that each light much of the frame (4x4-block ratios
spread by 23% per seed, correlated 0.57 between blocks) and is skewed (renders up to 1.55x).
Over the 512 seeds the mean ratio to `manylights` (emission=flc,
64 jitter frames) is 1.000 +- 0.008; seeds 0..3 happen to give 0.84, 0.93, 0.92, 0.89 (a mean
of four seeds falls this low in 12% of draws). With one level (N = 0, every VPL over the whole
screen) the same pipeline (spot falloff, shadowed two-sided E, jitter, tessellated pieces)
matches `manylights` to 0.1% (1.001 +- 0.001). The spread falls as 1/sqrt(F) in progressive
frames, or with a smaller top-level S_N: predicted 8.9% with N = 3, 6.3% with mu = 2 (16
frames), at the price of larger unbounded last-level splats. The blur (`blur_radius`) is the
one spatial bias: at 64x48 (tiles of 8x6 px, r = 7) 4x4-block means move by -2% to +8% against
`manylights` while the image mean moves by +0.3%; `tiling_level` without blur adds none.

| parameter             | default | range        | meaning                                                       |
|-----------------------|---------|--------------|---------------------------------------------------------------|
| n_avg                 | 256     | 8 .. 4096    | N_avg of eq. 1: VPLs per pixel and level (quality)            |
| mu                    | 4.0     | 1.05 .. 16   | level size ratio S_k = S_0 mu^k (paper: 1.4 .. 5)             |
| levels                | 5       | 0 .. 15      | N: levels 0..N (paper Fig. 10: 5)                             |
| dnear_factor          | 0.2     | 1e-3 .. 10   | D_near / R_scene (eq. 1)                                      |
| eps_rel               | 1e-4    | 1e-7 .. 1    | eps of d_i = max(eps, |x - y|), relative to R_scene           |
| tiling_level          | 3       | 0 .. 5       | L: 4^L interleaved tiles (paper Table 1: x64) (quality)       |
| blur_radius           | -1      | -1 .. 32     | tent blur radius r in pixels; -1: 2^L - 1; 0: off             |
| blur_depth_threshold  | 0.05    | 0 .. 10      | tangent-plane distance / camera distance for a blur neighbour |
| blur_normal_threshold | 0.9     | -1 .. 1      | min cosine between normals for a blur neighbour               |
| progressive_frames    | 1       | 1 .. 4096    | F sub-frames averaged in one render (jittered VPLs if F > 1)  |
| last_level_unbounded  | false   |              | f^N = 1 beyond D_N (exact, unbiased; slower)                  |
| divergent_pass        | true    |              | tessellate divergent triangles (off: they are dropped)        |

Stages: `regular`, `divergent`, `upscale_blur` (after the shared `gbuffer_shadow` and
`direct_light`); the paper's "indirect" total is their sum.
"""
from __future__ import annotations

from pathlib import Path

import moderngl
import numpy as np

from bench.gl import load_program, set_uniforms
from bench.gl.context import park
from bench.method import FrameOutput, MethodBase, Param, SkipRow

from .levels import FlcLevels, presplit_count
from .tessellation import MAX_TESS_LEVEL, measure_fmax

SHADERS = Path(__file__).parent / "shaders"
BINDINGS = {"BINDING_DIVERGENT_VERTICES": 3, "BINDING_DIVERGENT_COMMAND": 4}
NOISE_SIZE = 1024
DIVERGENT_VERTEX_BYTES = 32
MAX_DIVERGENT_BYTES = 128 * 1024 * 1024   # GL_MAX_SHADER_STORAGE_BLOCK_SIZE guaranteed on llvmpipe
CPU_MARGIN = 1e-3  # float64 facts vs float32 GPU areas: borderline triangles counted as divergent
RESET_COMMAND = np.array([0, 1, 0, 0, 0, 0, 0, 0], dtype=np.uint32).tobytes()


class ForwardLightCuts(MethodBase):
    name = "flc"
    summary = "Forward Light Cuts: stochastic multiscale VPLs from triangles, splatted (Laurent et al. 2016)"
    stages = ("regular", "divergent", "upscale_blur")
    needs = frozenset({"gbuffer", "shadow_map", "direct"})
    params = {
        "n_avg": Param(256, "N_avg of eq. 1: about how many VPLs light a pixel per level", 8, 4096,
                       quality=True, sweep=(64, 128, 256, 512, 1024)),
        "mu": Param(4.0, "level size ratio mu of S_k = S_0 mu^k (paper: 1.4 .. 5)", 1.05, 16.0),
        "levels": Param(5, "N: levels 0..N", 0, 15),
        "dnear_factor": Param(0.2, "D_near / R_scene in eq. 1", 1e-3, 10.0),
        "eps_rel": Param(1e-4, "eps of d_i = max(eps, |x - y|), relative to the scene radius", 1e-7, 1.0),
        "tiling_level": Param(3, "L: the viewport is split into 4^L interleaved tiles", 0, 5,
                              quality=True, sweep=(0, 1, 2, 3)),
        "blur_radius": Param(-1, "tent blur radius in pixels (-1: 2^L - 1, i.e. 0 when L = 0; 0: no blur)", -1, 32),
        "blur_depth_threshold": Param(0.05, "max tangent-plane distance of a blur neighbour / camera distance", 0.0, 10.0),
        "blur_normal_threshold": Param(0.9, "min cosine between the normals of blur neighbours", -1.0, 1.0),
        "progressive_frames": Param(1, "sub-frames averaged in one render (new u_rand, jittered VPLs)", 1, 4096),
        "last_level_unbounded": Param(False, "f^N = 1 beyond D_N: exact (unbiased) but every level-N VPL covers the screen"),
        "divergent_pass": Param(True, "tessellate divergent triangles (false: drop them)"),
    }

    # ------------------------------------------------------------------ setup (untimed)
    def prepare(self, gpu, scene, facts, params, view) -> None:
        self.params = params
        self.ctx = ctx = gpu.ctx
        self.levels = FlcLevels(scene_radius=facts.scene_radius, n_avg=float(params["n_avg"]), mu=params["mu"],
                                levels=params["levels"], dnear_factor=params["dnear_factor"],
                                last_level_unbounded=params["last_level_unbounded"])
        lv = self.levels
        self.eps = params["eps_rel"] * facts.scene_radius
        L = params["tiling_level"]
        self.tiles_per_axis = 1 << L
        self.tile_size = (-(-view.width // self.tiles_per_axis), -(-view.height // self.tiles_per_axis))
        radius = params["blur_radius"]
        self.blur_radius = (self.tiles_per_axis - 1) if radius < 0 else radius

        # Divergent triangles: how many, and the exact buffer they need (from the scene facts).
        threshold = lv.divergent_area
        n_divergent = facts.triangles_above(threshold * (1.0 - CPU_MARGIN))
        self.divergent_count = n_divergent
        self.run_divergent = bool(params["divergent_pass"]) and n_divergent > 0
        fmax = measure_fmax(ctx)
        self.tess_target = threshold * (1.0 - CPU_MARGIN)
        capacity = 0
        if self.run_divergent:
            areas = facts.sorted_areas_m2[len(facts.sorted_areas_m2) - n_divergent:]
            m = presplit_count(areas * (1.0 + CPU_MARGIN), fmax[-1], self.tess_target)
            capacity = int(3 * np.sum(m * m))
            if capacity * DIVERGENT_VERTEX_BYTES > MAX_DIVERGENT_BYTES:
                raise SkipRow(f"flc: scene '{scene.name}' has {n_divergent} divergent triangles needing "
                              f"{capacity} patch vertices (> {MAX_DIVERGENT_BYTES // DIVERGENT_VERTEX_BYTES}); "
                              f"lower n_avg or raise dnear_factor")
        self.divergent_capacity = capacity

        defines = dict(BINDINGS, **lv.defines(), DIVERGENT_APPEND=self.run_divergent,
                       DIVERGENT_CAPACITY=max(capacity, 1), TESS_MAX_LEVEL=MAX_TESS_LEVEL,
                       TESS_FMAX_TOP=float(fmax[-1]), TESS_TARGET_AREA=float(self.tess_target),
                       TESS_FMAX="float[%d](%s)" % (len(fmax), ", ".join(repr(float(v)) for v in fmax)),
                       NOISE_SIZE=NOISE_SIZE)
        self.regular = load_program(ctx, SHADERS / "splat_regular.glsl", defines)
        self.regular_vao = ctx.vertex_array(self.regular, [(gpu.vbo_position, "3f", "in_position"),
                                                           (gpu.vbo_random, "u", "in_vrand")],
                                            index_buffer=gpu.ibo, index_element_size=4)
        self.divergent_vertices = ctx.buffer(reserve=max(capacity, 1) * DIVERGENT_VERTEX_BYTES)
        self.command = ctx.buffer(RESET_COMMAND)
        self.divergent = self.divergent_vao = self.noise = None
        if self.run_divergent:
            self.divergent = load_program(ctx, SHADERS / "splat_divergent.glsl", defines)
            self.divergent_vao = ctx.vertex_array(self.divergent, [])
            rng = np.random.default_rng(np.random.SeedSequence([gpu.seed, 0x666C6374]))
            noise = rng.integers(0, 2**32, size=NOISE_SIZE * NOISE_SIZE, dtype=np.uint64).astype(np.uint32)
            self.noise = ctx.texture((NOISE_SIZE, NOISE_SIZE), 1, noise.tobytes(), dtype="u4")
            self.noise.filter = (moderngl.NEAREST, moderngl.NEAREST)

        self.resolve = load_program(ctx, SHADERS / "resolve.glsl")
        self.resolve_vao = ctx.vertex_array(self.resolve, [])
        tw, th = self.tile_size[0] * self.tiles_per_axis, self.tile_size[1] * self.tiles_per_axis
        self.accum = ctx.texture((tw, th), 4, dtype="f4")
        self.blurred = ctx.texture((view.width, view.height), 4, dtype="f4")
        self.indirect = ctx.texture((view.width, view.height), 4, dtype="f4")
        for t in (self.accum, self.blurred, self.indirect):
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.accum_fbo = ctx.framebuffer([self.accum])
        self.blurred_fbo = ctx.framebuffer([self.blurred])
        self.indirect_fbo = ctx.framebuffer([self.indirect])

    def describe(self) -> dict:
        """The derived constants of this setup (for the record and the tests)."""
        lv = self.levels
        return {"S0_m2": lv.s0, "S_bar_N_m2": lv.divergent_area, "D_N_m": float(lv.d[lv.levels]),
                "divergent_triangles": self.divergent_count, "divergent_patch_vertices": self.divergent_capacity}

    # ------------------------------------------------------------------ frame (timed)
    def _bind_splat(self, prog, frame, u_rand: int, unit0: int = 0) -> int:
        passes, gpu = frame.passes, frame.gpu
        unit = passes.gbuffer.bind(prog, unit0)
        unit = passes.shadows.bind(prog, unit)
        gpu.bind_scene_buffers()
        self.divergent_vertices.bind_to_storage_buffer(BINDINGS["BINDING_DIVERGENT_VERTICES"])
        self.command.bind_to_storage_buffer(BINDINGS["BINDING_DIVERGENT_COMMAND"])
        frames = self.params["progressive_frames"]
        set_uniforms(prog, u_view_proj=frame.view.view_proj, u_rand=u_rand, u_jitter=frames > 1,
                     u_screen=(frame.width, frame.height), u_tiles_per_axis=self.tiles_per_axis,
                     u_tile_size=self.tile_size, u_weight=float(self.tiles_per_axis ** 2) / frames,
                     u_eps=float(self.eps), u_light_count=gpu.light_count)
        return unit

    def _splat_state(self) -> None:
        ctx = self.ctx
        self.accum_fbo.use()
        ctx.viewport = (0, 0, self.accum.width, self.accum.height)
        ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        ctx.enable(moderngl.BLEND)
        ctx.blend_func = moderngl.ONE, moderngl.ONE

    def render(self, frame, prof) -> FrameOutput:
        ctx = self.ctx
        self.accum_fbo.use()
        ctx.viewport = (0, 0, self.accum.width, self.accum.height)
        self.accum_fbo.clear(0.0, 0.0, 0.0, 0.0)
        for j in range(self.params["progressive_frames"]):
            u_rand = frame.random_u32(j)
            with prof.stage("regular"):
                if self.run_divergent:
                    self.command.write(RESET_COMMAND)
                self._splat_state()
                self._bind_splat(self.regular, frame, u_rand)
                self.regular_vao.render(moderngl.TRIANGLES)
            if self.run_divergent:
                with prof.stage("divergent"):
                    ctx.memory_barrier()  # the appended patches and the command are read next
                    self._splat_state()
                    unit = self._bind_splat(self.divergent, frame, u_rand)
                    self.noise.use(unit)
                    self.divergent["u_noise"].value = unit
                    ctx.patch_vertices = 3
                    self.divergent_vao.render_indirect(self.command, mode=moderngl.PATCHES, count=1)
        ctx.disable(moderngl.BLEND)
        with prof.stage("upscale_blur"):
            self._resolve(frame)
        skipped = () if self.run_divergent else ("divergent",)
        return FrameOutput(direct=frame.passes.direct.radiance, indirect=self.indirect,
                           skipped_stages=skipped, extra=self.describe())

    def _resolve(self, frame) -> None:
        ctx, prog = self.ctx, self.resolve
        ctx.viewport = (0, 0, frame.width, frame.height)
        unit = frame.passes.gbuffer.bind(prog, 0)
        common = dict(u_tiles_per_axis=self.tiles_per_axis, u_tile_size=self.tile_size,
                      u_screen=(frame.width, frame.height), u_radius=self.blur_radius,
                      u_depth_threshold=float(self.params["blur_depth_threshold"]),
                      u_normal_threshold=float(self.params["blur_normal_threshold"]),
                      u_camera_pos=tuple(float(v) for v in frame.view.eye_local), u_source=unit)
        if self.blur_radius > 0:
            steps = ((self.accum, self.blurred_fbo, True, (1, 0), False),
                     (self.blurred, self.indirect_fbo, False, (0, 1), True))
        else:
            steps = ((self.accum, self.indirect_fbo, True, (1, 0), True),)
        for source, fbo, from_tiled, direction, albedo in steps:
            fbo.use()
            source.use(unit)
            set_uniforms(prog, u_from_tiled=from_tiled, u_direction=direction, u_apply_albedo=albedo, **common)
            self.resolve_vao.render(moderngl.TRIANGLES, vertices=3)

    def release(self) -> None:
        if getattr(self, "ctx", None) is None:
            return
        park(self.ctx)
        for name in ("accum_fbo", "blurred_fbo", "indirect_fbo", "accum", "blurred", "indirect", "resolve_vao",
                     "resolve", "noise", "divergent_vao", "divergent", "command", "divergent_vertices",
                     "regular_vao", "regular"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.release()
                setattr(self, name, None)
