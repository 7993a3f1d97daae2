"""`pbgi`: real-time point-based global illumination in texture space.

Paper: "Real time Point Based Global Illumination" (blog article, University of Luminy school
project; ../shared/papers/pbgi_texture_space.txt), after Bunnell, "Dynamic Ambient Occlusion
and Indirect Lighting", GPU Gems 2 ch. 14 (2005). Every texel of a lightmap is a surfel (a
small disk); light is transferred between all pairs of texels, then the camera view reads the
lightmap. Stages, each a GL pass:

1. `lightmap_gbuffer`: the scene rasterised at its lightmap coordinates (conservatively: the
   article's fix for faces smaller than a texel) into position, normal, face normal and
   albedo textures of `lightmap_resolution`^2 texels. Each fragment clips its texel square to
   its triangle and adds the piece's area and area-weighted attributes (additive blending):
   a texel's surfel is the mean of the surface inside it, its area the exact area inside it.
   The UV unwrap (unwrap.py, in prepare()) is the article's: planar projection on the dominant
   normal axis, charts packed into the texture (shelf packing, one texel density for all
   charts); a chart that folds over itself in projection is split into per-triangle charts.
2. `lightmap_direct`: per covered texel, the shadowed direct irradiance of the scene lights on
   each side (bench/gl/shaders/direct_lighting.glsl, shared shadow maps), stored as a surfel:
   position, normal, world area, radiosity B = rho E of each side.
3. `emitter_clusters` (only with `emitter_level` L > 0, else recorded as skipped): the
   article's closing suggestion against O(n^2): the surfels of each 2^L x 2^L texel block of a
   chart merged into one disk (summed area, area-weighted position, normal and radiosity).
4. `gather`: every receiver texel sums every emitter with Bunnell's disk-to-point transfer
   a |cos_e| |cos_r| / (pi d^2 + a), into the irradiance of the side facing the emitter
   (no visibility: like the article, and like `manylights`). Split in draws of
   bench.gl.context.LOOP_CHUNK emitters with additive blending (llvmpipe's loop cap). Bounce
   k > 1 (`bounces`) re-emits B = rho E_{k-1} from the previous bounce's irradiance.
5. `resolve`: each camera pixel maps its position through its triangle's chart map to the
   lightmap, interpolates the summed irradiance of the side it shows bilinearly over covered
   texels, and outputs L = rho / pi * E.

Corrections to the article's formulas (each checked against the invariant it must satisfy):

- Emitter area: the article passes a = 1/128 for every texel. The transfer is the point-to-
  disk form factor (exact on axis: F = r^2 / (h^2 + r^2) = a / (pi h^2 + a)), so `a` must be
  the texel's world area: here the exact area of the surface inside the texel square (the
  squares partition the chart plane, so the texel areas sum to the surface area: tested).
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
lightmap resolution grows it converges to `manylights` with `emission=lambert` (the continuous
unshadowed one-bounce integral); the error at a fixed resolution is largest in concave
corners, where near-field texels see each other at distances comparable to their size.
The gather costs O(texels x emitters) per bounce: about (0.6 R^2)^2 / 4^L pair evaluations.

| parameter           | default | range      | meaning                                                        |
|---------------------|---------|------------|----------------------------------------------------------------|
| lightmap_resolution | 128     | 16 .. 512  | lightmap side in texels (quality; sweep 32, 64, 128, 256)      |
| emitter_level       | 0       | 0 .. 4     | emitters are 2^L x 2^L texel blocks (quality; sweep 0, 1, 2)   |
| bounces             | 1       | 1 .. 8     | light bounces summed (the benchmark compares one bounce)       |

A scene whose charts cannot be packed into the lightmap (too many separate charts for the
resolution) is skipped with a message naming `lightmap_resolution`.
"""
from __future__ import annotations

from pathlib import Path

import moderngl
import numpy as np

from bench.gl import load_compute, load_program, set_uniforms
from bench.gl.context import check_gl, loop_chunks, park
from bench.method import FrameOutput, MethodBase, Param, SkipRow

from .unwrap import LightmapTooSmall, chart_image, find_charts, unwrap

SHADERS = Path(__file__).parent / "shaders"
PBGI_DEFINES = {"BINDING_PBGI_TRIANGLES": 3, "BINDING_PBGI_TEXELS": 4, "BINDING_PBGI_SURFELS": 5,
                "BINDING_PBGI_EMITTERS": 6, "BINDING_PBGI_CLUSTER_RANGES": 7}
WELD_TOLERANCE_REL = 1e-6   # vertices closer than this (times the scene radius) share chart edges
SURFEL_BYTES = 64           # struct Surfel: 4 vec4


class TextureSpacePBGI(MethodBase):
    name = "pbgi"
    summary = "Texture-space point-based GI: lightmap texels as surfels, all-pairs disk transfer (Bunnell)"
    stages = ("lightmap_gbuffer", "lightmap_direct", "emitter_clusters", "gather", "resolve")
    needs = frozenset({"gbuffer", "shadow_map", "direct"})
    params = {
        "lightmap_resolution": Param(128, "lightmap side in texels", 16, 512, quality=True,
                                     sweep=(32, 64, 128, 256)),
        "emitter_level": Param(0, "emitters are 2^L x 2^L texel blocks of a chart (0: every texel)", 0, 4,
                               quality=True, sweep=(0, 1, 2)),
        "bounces": Param(1, "light bounces summed in the lightmap", 1, 8),
    }

    # ------------------------------------------------------------------ prepare (untimed)
    def prepare(self, gpu, scene, facts, params, view) -> None:
        self.params = params
        self.ctx = ctx = gpu.ctx
        res = params["lightmap_resolution"]
        if gpu.triangle_count >= 2 ** 24:  # triangle ids travel as float32 in the lightmap normal's w
            raise SkipRow(f"scene '{scene.name}' has {gpu.triangle_count} triangles; pbgi handles < 2^24")
        if res > ctx.info["GL_MAX_TEXTURE_SIZE"]:
            raise SkipRow(f"lightmap_resolution={res} exceeds GL_MAX_TEXTURE_SIZE {ctx.info['GL_MAX_TEXTURE_SIZE']}")
        self.resolution = res
        self.triangles = ctx.buffer(reserve=gpu.triangle_count * 48)
        self._unwrap_without_overlaps(gpu, scene)

        self.lm_position, self.lm_normal, self.lm_face_normal, self.lm_albedo = (
            self._texture((res, res)) for _ in range(4))
        self.lm_fbo = ctx.framebuffer([self.lm_position, self.lm_normal, self.lm_face_normal, self.lm_albedo])
        self.lm_program = load_program(ctx, SHADERS / "lightmap_gbuffer.glsl", PBGI_DEFINES)
        self.lm_vao = self._scene_vao(gpu, self.lm_program)

        # The chart layout is static: which texels are covered (and by which triangle) is read
        # back once; the per-frame passes recompute their content.
        self._render_lightmap_gbuffer(gpu)
        check_gl(ctx, "pbgi lightmap gbuffer")
        area_image = np.frombuffer(self.lm_position.read(), dtype=np.float32).reshape(res, res, 4)[..., 3]
        ys, xs = np.nonzero(area_image > 0)
        chart = chart_image(self.unwrap)[ys, xs]
        if np.any(chart < 0):
            raise RuntimeError(f"pbgi: {int((chart < 0).sum())} lightmap texel(s) covered outside every chart box")
        level = params["emitter_level"]
        order = np.lexsort((xs, ys, xs >> level, ys >> level, chart))
        xs, ys, chart = xs[order], ys[order], chart[order]
        self.texel_xy = np.column_stack([xs, ys])
        self.texel_chart = chart
        self.texel_count = len(xs)
        self.texels = ctx.buffer(self.texel_xy.astype(np.int32).tobytes())
        self.surfels = ctx.buffer(reserve=self.texel_count * SURFEL_BYTES)

        self.clusters = self.cluster_ranges = None
        self.emitter_count = self.texel_count
        if level > 0:
            key = np.column_stack([chart, ys >> level, xs >> level])
            starts = np.flatnonzero(np.r_[True, np.any(key[1:] != key[:-1], axis=1)])
            counts = np.diff(np.r_[starts, self.texel_count])
            ranges = np.zeros((len(starts), 4), dtype=np.int32)
            ranges[:, 0], ranges[:, 1] = starts, counts
            self.emitter_count = len(starts)
            self.cluster_ranges = ctx.buffer(ranges.tobytes())
            self.clusters = ctx.buffer(reserve=self.emitter_count * SURFEL_BYTES)
            self.cluster_program = load_compute(ctx, SHADERS / "emitter_clusters.glsl", PBGI_DEFINES)

        self.surfel_program = load_compute(ctx, SHADERS / "surfel_radiosity.glsl", PBGI_DEFINES)
        self.bounce_front, self.bounce_back, self.total_front, self.total_back = (
            self._texture((res, res)) for _ in range(4))
        self.gather_fbo = ctx.framebuffer([self.bounce_front, self.bounce_back, self.total_front, self.total_back])
        self.bounce_fbo = ctx.framebuffer([self.bounce_front, self.bounce_back])
        self.total_fbo = ctx.framebuffer([self.total_front, self.total_back])
        self.gather_program = load_program(ctx, SHADERS / "gather.glsl", PBGI_DEFINES)
        self.gather_vao = ctx.vertex_array(self.gather_program, [])
        self.resolve_program = load_program(ctx, SHADERS / "resolve.glsl", PBGI_DEFINES)
        self.resolve_vao = ctx.vertex_array(self.resolve_program, [])
        self.indirect = self._texture((view.width, view.height))
        self.indirect_fbo = ctx.framebuffer([self.indirect])

    def _unwrap_without_overlaps(self, gpu, scene) -> None:
        """Unwrap; charts that fold over themselves in projection (found by counting triangles
        per texel centre on the GL) are split into one chart per triangle and packed again."""
        ctx, res = self.ctx, self.resolution
        split: set = set()
        count_tex = self._texture((res, res))
        count_fbo = ctx.framebuffer([count_tex])
        program = load_program(ctx, SHADERS / "lightmap_overlap.glsl", PBGI_DEFINES)
        vao = self._scene_vao(gpu, program)
        try:
            for attempt in range(3):
                try:
                    uw = unwrap(gpu.positions.astype(np.float64), gpu.faces.astype(np.int64), res,
                                WELD_TOLERANCE_REL * gpu.radius, split=split)
                except LightmapTooSmall as exc:
                    raise SkipRow(f"scene '{scene.name}': {exc}") from None
                records = np.zeros((gpu.triangle_count, 3, 4), dtype=np.float32)
                records[:, :2] = uw.rows
                records[:, 2, :3] = uw.face_normal
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
                split |= set(self._base_charts(gpu, tri))
            raise SkipRow(f"scene '{scene.name}': lightmap charts still overlap after splitting folded charts")
        finally:
            park(ctx)
            for obj in (vao, count_fbo, count_tex, program):
                obj.release()

    @staticmethod
    def _base_charts(gpu, triangles) -> np.ndarray:
        chart = find_charts(gpu.positions.astype(np.float64), gpu.faces.astype(np.int64),
                            WELD_TOLERANCE_REL * gpu.radius)[0]
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
    def _build_surfels(self, gpu, passes, from_direct: bool) -> None:
        prog = self.surfel_program
        unit = self._bind_textures(prog, u_irradiance_front=self.bounce_front, u_irradiance_back=self.bounce_back,
                                   **self._lightmap_textures())
        passes.shadows.bind(prog, unit)
        gpu.bind_scene_buffers()
        self.triangles.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_TRIANGLES"])
        self.texels.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_TEXELS"])
        self.surfels.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_SURFELS"])
        set_uniforms(prog, u_texel_count=self.texel_count, u_from_direct=from_direct,
                     u_light_count=gpu.light_count)
        prog.run(group_x=(self.texel_count + 63) // 64)
        self.ctx.memory_barrier()

    def _build_clusters(self) -> None:
        self.cluster_ranges.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_CLUSTER_RANGES"])
        self.surfels.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_SURFELS"])
        self.clusters.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_EMITTERS"])
        set_uniforms(self.cluster_program, u_cluster_count=self.emitter_count)
        self.cluster_program.run(group_x=(self.emitter_count + 63) // 64)
        self.ctx.memory_barrier()

    def _gather(self) -> None:
        ctx = self.ctx
        self.bounce_fbo.use()
        ctx.viewport = (0, 0, self.resolution, self.resolution)
        self.bounce_fbo.clear(0.0, 0.0, 0.0, 0.0)
        self.gather_fbo.use()
        ctx.viewport = (0, 0, self.resolution, self.resolution)
        ctx.disable(moderngl.DEPTH_TEST)
        ctx.enable(moderngl.BLEND)
        ctx.blend_func = moderngl.ONE, moderngl.ONE
        self._bind_textures(self.gather_program, **self._lightmap_textures())
        emitters = self.clusters if self.clusters is not None else self.surfels
        emitters.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_EMITTERS"])
        for first, end in loop_chunks(self.emitter_count):  # additive: partial sums add up
            set_uniforms(self.gather_program, u_emitter_first=first, u_emitter_end=end)
            self.gather_vao.render(moderngl.TRIANGLES, vertices=3)
        ctx.disable(moderngl.BLEND)
        ctx.memory_barrier()

    def render(self, frame, prof) -> FrameOutput:
        ctx, gpu, passes = self.ctx, frame.gpu, frame.passes
        with prof.stage("lightmap_gbuffer"):
            self._render_lightmap_gbuffer(gpu)
        with prof.stage("lightmap_direct"):
            self._build_surfels(gpu, passes, from_direct=True)
        self.total_fbo.use()
        self.total_fbo.clear(0.0, 0.0, 0.0, 0.0)
        for bounce in range(self.params["bounces"]):
            if bounce > 0:
                with prof.stage("gather"):  # re-emission of the previous bounce: part of the bounce loop
                    self._build_surfels(gpu, passes, from_direct=False)
            if self.clusters is not None:
                with prof.stage("emitter_clusters"):
                    self._build_clusters()
            with prof.stage("gather"):
                self._gather()
        with prof.stage("resolve"):
            self.indirect_fbo.use()
            ctx.viewport = (0, 0, frame.width, frame.height)
            ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
            g = passes.gbuffer
            self._bind_textures(self.resolve_program, u_gbuffer_position=g.position,
                                u_gbuffer_geo_normal=g.geo_normal, u_gbuffer_albedo=g.albedo,
                                u_total_front=self.total_front, u_total_back=self.total_back,
                                **self._lightmap_textures())
            self.triangles.bind_to_storage_buffer(PBGI_DEFINES["BINDING_PBGI_TRIANGLES"])
            set_uniforms(self.resolve_program, u_lightmap_size=self.resolution)
            self.resolve_vao.render(moderngl.TRIANGLES, vertices=3)
        skipped = () if self.clusters is not None else ("emitter_clusters",)
        return FrameOutput(direct=passes.direct.radiance, indirect=self.indirect, skipped_stages=skipped,
                           extra={"texels": self.texel_count, "emitters": self.emitter_count,
                                  "charts": self.unwrap.chart_count, "texels_per_m": self.unwrap.scale})

    # ------------------------------------------------------------------ diagnostics and release
    def read_lightmap(self) -> dict:
        """The lightmap textures as numpy arrays indexed [y, x] (GL rows, not flipped). The
        texture-space G-buffer holds area-weighted sums: position = (sum a p, sum a), normal =
        (sum a n, 0), face_normal, albedo likewise; total_front/back = summed irradiance."""
        def rd(tex):
            return np.frombuffer(tex.read(), dtype=np.float32).reshape(self.resolution, self.resolution, 4).copy()
        return {"position": rd(self.lm_position), "normal": rd(self.lm_normal), "face_normal": rd(self.lm_face_normal),
                "albedo": rd(self.lm_albedo),
                "total_front": rd(self.total_front), "total_back": rd(self.total_back)}

    def release(self) -> None:
        if getattr(self, "ctx", None) is None:
            return
        park(self.ctx)
        for name in ("indirect_fbo", "indirect", "resolve_vao", "resolve_program", "gather_vao", "gather_program",
                     "gather_fbo", "bounce_fbo", "total_fbo", "bounce_front", "bounce_back", "total_front",
                     "total_back", "surfel_program", "cluster_program", "clusters", "cluster_ranges", "surfels",
                     "texels", "lm_vao", "lm_program", "lm_fbo", "lm_position", "lm_normal", "lm_face_normal", "lm_albedo", "triangles"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.release()
                setattr(self, name, None)
