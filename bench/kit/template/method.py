"""`__method_name__`: the one-bounce ambient term of the scene (a starting point: replace it with your method).

The indirect radiance at every pixel x is the first bounce spread evenly over the scene:

    L(x) = rho_x / pi * Phi_r / A

where rho_x is the albedo at x (the shared GBuffer), Phi_r the total flux the lights' first
bounce reflects (the sum of the shared reflective shadow map's texels: each holds the flux its
surface patch reflects) and A the scene's total surface area. It is the first-bounce part of
the ambient term of progressive radiosity (Cohen, Chen, Wallace, Greenberg, SIGGRAPH 1988) and
exact where every point sees every other one with the same form factor: inside a closed diffuse
sphere it gives rho^2 I / (pi R^2), the analytic value the conformance suite checks on
`sphere_inside`. Elsewhere it ignores where the light lands, so it is flat where the reference is
not, and too bright in open scenes (light that escapes is counted as if it bounced back).

The direct component is the shared, shadow-mapped direct pass, returned unchanged.

Parameters:

<!-- parameters: generated from the Param declarations by `gibench manuals --write` -->
<!-- end of parameters -->

Quality ladder (fast -> accurate; `ladder`): flux_stride 4, 2, 1 (default): the RSM is summed
every flux_stride-th texel in each axis, each weighted flux_stride^2 (1/flux_stride^2 of the
reduction's work, a coarser estimate of Phi_r).

Example:

    gibench check-method __method_name__
    gibench run --scenes cornell_spot --methods direct,__method_name__ --res 128x96 --defaults-only

Stages: `flux_sum` (the RSM's rows, then their sum), `ambient` (one full-screen pass), after the
shared `gbuffer_shadow`, `direct_light` and `rsm`. Needs: gbuffer, shadow_map, direct, rsm.
Cost: the RSM's texels / flux_stride^2, plus one pass over the pixels.
"""
from __future__ import annotations

from pathlib import Path

import moderngl

from bench.gl import load_program, set_uniforms
from bench.gl.context import park
from bench.gl.passes import RSM_RESOLUTION
from bench.protocol.method import FrameOutput, MethodBase, Param

SHADERS = Path(__file__).parent / "shaders"


class __MethodClass__(MethodBase):
    name = "__method_name__"
    summary = "One-bounce ambient term: albedo x the first bounce's reflected flux over the scene's area"
    stages = ("flux_sum", "ambient")
    needs = frozenset({"gbuffer", "shadow_map", "direct", "rsm"})
    ladder = ({"flux_stride": 4}, {"flux_stride": 2}, {})
    params = {
        "flux_stride": Param(1, "sum the RSM every k-th texel in each axis, each weighted k^2", 1, 8,
                             quality=True, sweep=(1, 2, 4, 8)),
    }
    # The relative excess over the analytic one-bounce radiance on `sphere_inside` that the
    # conformance suite allows this method (the RSM's discretisation, the tessellated sphere).
    one_bounce_tolerance = 0.02

    @classmethod
    def frames_identical(cls, params: dict) -> bool:
        return True   # no per-frame random stream, no temporal state

    @classmethod
    def cost_terms(cls, params, size):
        # the reduction reads the RSM's texels (per light layer; layers are not among CostFacts)
        return {"rsm_texels": RSM_RESOLUTION * RSM_RESOLUTION / params["flux_stride"] ** 2}

    def prepare(self, gpu, scene, facts, params, view) -> None:
        self.params = params
        ctx = self.ctx = gpu.ctx
        self.inv_area_m2 = 1.0 / max(float(facts.total_area_m2), 1e-12)
        self.flux_sum = load_program(ctx, SHADERS / "flux_sum.glsl")
        self.shade = load_program(ctx, SHADERS / "ambient.glsl")
        self.flux_sum_vao = ctx.vertex_array(self.flux_sum, [])
        self.shade_vao = ctx.vertex_array(self.shade, [])
        self.indirect = ctx.texture((view.width, view.height), 4, dtype="f4")
        self.flux_total = ctx.texture((1, 1), 4, dtype="f4")
        for tex in (self.indirect, self.flux_total):
            tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.indirect_fbo = ctx.framebuffer([self.indirect])
        self.flux_total_fbo = ctx.framebuffer([self.flux_total])
        # one texel per summed RSM row: the atlas's height is known at the first frame, frame 0,
        # the untimed warm-up (render allocates it there, once)
        self.row_sums = self.row_sums_fbo = None

    def render(self, frame, prof) -> FrameOutput:
        ctx, passes = self.ctx, frame.passes
        stride = self.params["flux_stride"]
        ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
        flux = passes.rsm.flux   # read only: the shared passes are lent to every method of the view
        if self.row_sums is None:
            self.row_sums = ctx.texture((-(-flux.height // stride), 1), 4, dtype="f4")
            self.row_sums.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self.row_sums_fbo = ctx.framebuffer([self.row_sums])
        with prof.stage("flux_sum"):
            for source, fbo, row_step, column_step, weight in (
                    (flux, self.row_sums_fbo, stride, stride, float(stride * stride)),
                    (self.row_sums, self.flux_total_fbo, 1, 1, 1.0)):
                fbo.use()
                ctx.viewport = (0, 0, fbo.width, fbo.height)
                source.use(0)
                set_uniforms(self.flux_sum, u_input=0, u_row_step=row_step, u_column_step=column_step,
                             u_weight=weight)
                self.flux_sum_vao.render(moderngl.TRIANGLES, vertices=3)
        with prof.stage("ambient"):
            self.indirect_fbo.use()
            ctx.viewport = (0, 0, frame.width, frame.height)
            unit = passes.gbuffer.bind(self.shade)
            self.flux_total.use(unit)
            set_uniforms(self.shade, u_flux_total=unit, u_inv_area_m2=self.inv_area_m2)
            self.shade_vao.render(moderngl.TRIANGLES, vertices=3)
        return FrameOutput(direct=passes.direct.radiance, indirect=self.indirect)

    def release(self) -> None:
        if getattr(self, "ctx", None) is None:   # prepare() stopped before allocating anything
            return
        park(self.ctx)   # a framebuffer is never released while bound (bench.gl.context.park)
        for name in ("indirect_fbo", "flux_total_fbo", "row_sums_fbo", "indirect", "flux_total", "row_sums",
                     "flux_sum_vao", "shade_vao", "flux_sum", "shade"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.release()
