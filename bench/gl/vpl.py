"""VPL sampling from the shared reflective shadow map, and the VPL gather: the GPU parts that
`ir_unshadowed` and `ir_shadowed` share.

`RsmVplSampler.sample()` builds, per frame, a CDF over every RSM texel on the GPU (compute
passes, integer weights so the prefix sums are exact) and draws N VPLs from it, importance
sampled by flux luminance and stratified. `VplGather.render()` sums the VPLs at every pixel.
"""
from __future__ import annotations

from pathlib import Path

import moderngl
import numpy as np

from .context import loop_chunks, park
from .shaders import load_compute, load_program, set_uniforms

SHADERS = Path(__file__).parent / "shaders"
# Param docs shared by the VPL methods (ir_unshadowed, ir_shadowed, val_clustered, visibility_gates)
VPL_COUNT_DOC = "VPLs drawn from the RSM per frame (importance sampled by flux luminance, stratified)"
CLAMP_DOC = "distance clamp eps of max(eps, distance) relative to the scene radius (tames the 1/d^2 singularity)"

# SSBO binding points (>= 3: 0..2 belong to the GL core) and the scan block size.
VPL_DEFINES = {"BINDING_RSM_MAX": 3, "BINDING_RSM_CDF": 4, "BINDING_RSM_BLOCK_CDF": 5, "BINDING_VPLS": 6,
               "CDF_BLOCK": 256}
VPL_RECORD_BYTES = 3 * 16  # struct Vpl in vpl_records.glsl: three vec4
_SAMPLE_GROUP = 64         # local_size_x of vpl_sample.glsl
# Integer CDF: (padded texel count) x (levels per texel) must stay below 2^32; at least 256
# levels keep the weights close to proportional to the flux.
_UINT_RANGE = 2**32 - 1
MAX_RSM_TEXELS = 2**24


class RsmVplSampler:
    """Draws `vpl_count` VPLs per frame from an RSM into the `vpls` SSBO (binding BINDING_VPLS)."""

    def __init__(self, ctx: moderngl.Context, vpl_count: int):
        self.ctx = ctx
        self.vpl_count = int(vpl_count)
        self.vpls = ctx.buffer(reserve=self.vpl_count * VPL_RECORD_BYTES)
        self.flux_max = ctx.buffer(reserve=4)
        self.flux_max_pass = load_compute(ctx, SHADERS / "rsm_flux_max.glsl", VPL_DEFINES)
        self.blocks_pass = load_compute(ctx, SHADERS / "rsm_cdf_blocks.glsl", VPL_DEFINES)
        self.totals_pass = load_compute(ctx, SHADERS / "rsm_cdf_totals.glsl", VPL_DEFINES)
        self.sample_pass = load_compute(ctx, SHADERS / "vpl_sample.glsl", VPL_DEFINES)
        self.texel_cdf = None
        self.block_cdf = None
        self._texels = -1

    def _allocate(self, texels: int) -> None:
        """CDF buffers for an RSM of `texels` texels (first frame; the RSM's size is fixed then)."""
        if texels > MAX_RSM_TEXELS:
            raise ValueError(f"RSM of {texels} texels is over the {MAX_RSM_TEXELS} the uint32 VPL CDF supports")
        block = VPL_DEFINES["CDF_BLOCK"]
        self.block_count = (texels + block - 1) // block
        self.levels = _UINT_RANGE // (self.block_count * block)
        for buf in (self.texel_cdf, self.block_cdf):
            if buf is not None:
                buf.release()
        self.texel_cdf = self.ctx.buffer(reserve=self.block_count * block * 4)
        self.block_cdf = self.ctx.buffer(reserve=self.block_count * 4)
        self._texels = texels

    def sample(self, rsm, rand_u32: int) -> None:
        """Build the CDF of `rsm`'s texel flux and draw the VPLs with the frame's random value."""
        texels = rsm.texel_count
        if texels != self._texels:
            self._allocate(texels)
        ctx = self.ctx
        self.flux_max.write(np.zeros(1, np.uint32).tobytes())
        self.flux_max.bind_to_storage_buffer(VPL_DEFINES["BINDING_RSM_MAX"])
        self.texel_cdf.bind_to_storage_buffer(VPL_DEFINES["BINDING_RSM_CDF"])
        self.block_cdf.bind_to_storage_buffer(VPL_DEFINES["BINDING_RSM_BLOCK_CDF"])
        self.vpls.bind_to_storage_buffer(VPL_DEFINES["BINDING_VPLS"])

        rsm.bind(self.flux_max_pass, 0)
        self.flux_max_pass.run(group_x=self.block_count)
        ctx.memory_barrier()
        rsm.bind(self.blocks_pass, 0)
        set_uniforms(self.blocks_pass, u_levels=self.levels)
        self.blocks_pass.run(group_x=self.block_count)
        ctx.memory_barrier()
        set_uniforms(self.totals_pass, u_block_count=self.block_count)
        self.totals_pass.run(group_x=1)
        ctx.memory_barrier()
        rsm.bind(self.sample_pass, 0)
        set_uniforms(self.sample_pass, u_block_count=self.block_count, u_vpl_count=self.vpl_count,
                     u_rand=int(rand_u32))
        self.sample_pass.run(group_x=(self.vpl_count + _SAMPLE_GROUP - 1) // _SAMPLE_GROUP)
        ctx.memory_barrier()

    def read_vpls(self) -> dict:
        """The current VPLs as numpy arrays (tests, diagnostics): position, normal, flux (N x 3)
        and area (N: the surface area each stands for)."""
        rec = np.frombuffer(self.vpls.read(), dtype=np.float32).reshape(self.vpl_count, 3, 4)
        return {"position": rec[:, 0, :3].copy(), "normal": rec[:, 1, :3].copy(), "flux": rec[:, 2, :3].copy(),
                "area": rec[:, 0, 3].copy()}

    def bind(self) -> None:
        self.vpls.bind_to_storage_buffer(VPL_DEFINES["BINDING_VPLS"])

    def release(self) -> None:
        for obj in (self.vpls, self.flux_max, self.texel_cdf, self.block_cdf, self.flux_max_pass,
                    self.blocks_pass, self.totals_pass, self.sample_pass):
            if obj is not None:
                obj.release()


class VplGather:
    """Full-screen pass summing every VPL at every GBuffer pixel into an RGBA32F texture.

    `program_path` is ir_unshadowed's gather.glsl, or a file that defines vpl_visibility() and
    includes it (ir_shadowed) with `VPL_SHADOWS=1` in `defines`.
    """

    def __init__(self, ctx: moderngl.Context, width: int, height: int, program_path=None,
                 defines: dict | None = None):
        self.ctx = ctx
        merged = dict(VPL_DEFINES, VPL_SHADOWS=0)
        merged.update(defines or {})
        self.program = load_program(ctx, program_path or SHADERS / "vpl_gather.glsl", merged)
        self.vao = ctx.vertex_array(self.program, [])
        self.indirect = ctx.texture((width, height), 4, dtype="f4")
        self.indirect.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.fbo = ctx.framebuffer([self.indirect])
        self.width, self.height = width, height

    def render(self, gbuffer, sampler: RsmVplSampler, eps: float, bind_extra=None) -> None:
        """Draw the gather. `bind_extra(program, first_free_unit)` binds what the including
        shader needs besides the GBuffer and the VPLs (ir_shadowed: the hemicube atlas)."""
        ctx = self.ctx
        self.fbo.use()
        ctx.viewport = (0, 0, self.width, self.height)
        self.fbo.clear(0.0, 0.0, 0.0, 0.0)
        ctx.disable(moderngl.DEPTH_TEST)
        ctx.enable(moderngl.BLEND)  # additive: each draw sums one chunk of the VPLs
        ctx.blend_func = moderngl.ONE, moderngl.ONE
        unit = gbuffer.bind(self.program)
        if bind_extra is not None:
            bind_extra(self.program, unit)
        sampler.bind()
        set_uniforms(self.program, u_eps=float(eps))
        for first, end in loop_chunks(sampler.vpl_count):
            set_uniforms(self.program, u_vpl_first=first, u_vpl_end=end)
            self.vao.render(moderngl.TRIANGLES, vertices=3)
        ctx.disable(moderngl.BLEND)

    def release(self) -> None:
        park(self.ctx)
        for obj in (self.fbo, self.indirect, self.vao, self.program):
            obj.release()
