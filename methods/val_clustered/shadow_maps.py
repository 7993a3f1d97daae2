"""`val_clustered`'s paraboloid shadow maps (paper Sec. 6): one distance map per VAL in one
atlas, drawn by splatting the small (VAL, triangle) pairs in a compute pass and drawing the
large ones (tessellated where their edges must bend), and for CSSM the Fourier basis atlases
with their MIP maps (stage `val_shadow_maps`; the manual is method.py's docstring).
"""
from __future__ import annotations

import math

import moderngl
import numpy as np

from bench.gl import load_compute, load_program, set_uniforms
from bench.gl.context import loop_chunks, park
from bench.protocol.method import ParamError

from .clustering import SHADERS, VAL_DEFINES, ValClustering

TESS_SAGITTA_TEXELS = 0.5           # largest chord-to-arc distance of a tessellated edge piece in the map
TESS_MAX_LEVEL = 64                  # GL guarantees tessellation levels up to 64
NEAR_SCALE = 1e-5                    # smallest ignore radius / scene radius (ir_shadowed's near plane)
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


class ParaboloidShadowMaps:
    """One paraboloid distance map per VAL (tiles of an R32F atlas) and, for CSSM, the Fourier
    basis atlases (same tiling) with their MIP maps."""

    BASIS_NAMES = ("u_basis_sin", "u_basis_cos", "u_basis_zsin", "u_basis_zcos")

    def __init__(self, gpu, clustering: ValClustering, resolution: int, cssm: bool, term_groups: int,
                 near_ignore: float, depth_range: float = 1.0):
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
                            MAP_EMPTY=MAP_EMPTY, CSM_DEPTH_RANGE=float(depth_range))
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

    def render(self, first: int = 0, end: int | None = None, finish: bool = True) -> None:
        """The maps of VALs [first, end) (the atlas is cleared when first = 0); `finish`: then the
        far distances and basis atlases of every VAL."""
        ctx = self.ctx
        end = self.clustering.cluster_count if end is None else end
        self.fbo.use()
        ctx.viewport = (0, 0, self.atlas.width, self.atlas.height)
        ctx.scissor = None
        if first == 0:
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
        for prog in (self.split_pass, self.program, self.tess_program):
            set_uniforms(prog, **self.clustering.common)
            set_uniforms(prog, u_val_first=first, u_val_end=end)
            set_uniforms(prog, u_tiles_x=self.tiles_x, u_tiles_y=self.tiles_y, u_near_ignore=self.near_ignore,
                         u_resolution=self.resolution, u_near_min=NEAR_SCALE * gpu.radius,
                         u_pair_capacity=self.pair_capacity)
        ctx.patch_vertices = 3
        for start, stop in loop_chunks(gpu.triangle_count, self.chunk_triangles):
            ctx.copy_buffer(self.commands, self.commands_reset)
            for prog in (self.split_pass, self.program, self.tess_program):
                set_uniforms(prog, u_first_triangle=start, u_chunk_triangles=stop - start)
            self.split_pass.run(group_x=(stop - start + MAP_GROUP - 1) // MAP_GROUP, group_y=end - first)
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
        if self.cssm and finish:
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
