"""`val_clustered`'s VPLs and their clusters (paper Sec. 5, 6): the paper's Halton VPLs
(`vpl_sampling=halton`) and the k-means of the VPLs into virtual area lights by point scattering
on the GPU (stages `vpl_sample`, `val_clustering`; the manual is method.py's docstring).
"""
from __future__ import annotations

from pathlib import Path

import moderngl
import numpy as np

from bench.gl import load_compute, load_program, set_uniforms
from bench.gl.context import park
from bench.gl.vpl import VPL_DEFINES, RsmVplSampler

SHADERS = Path(__file__).parent / "shaders"
VAL_RECORD_BYTES = 4 * 16            # struct Val in val_records.glsl: four vec4
VAL_DEFINES = dict(VPL_DEFINES, BINDING_VALS=7, BINDING_VPL_CLUSTER=8, BINDING_VAL_COUNT=9, BINDING_MAP_POSITIONS=10,
                   BINDING_MAP_FACES=11, BINDING_MAP_PAIRS=12, BINDING_MAP_COMMANDS=13,
                   BINDING_ASSIGN_STATS=14)
LIFT_SCALE = 1e-4                    # VAL map centre above its surface / scene radius (as ir_shadowed)


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
    """k-means of the VPLs into M VALs by point scattering (paper Sec. 5, 6), and the split round
    (issue #23): the VPLs their VAL's map origin does not see, k-means'd again into S spare VALs
    (VALs M .. M + S - 1 of the same buffers)."""

    def __init__(self, gpu, vpl_count: int, cluster_count: int, weights: tuple, spare_count: int = 0,
                 origin_medoid: bool = False, split_reassign: bool = True, size_scale: float = 1.0):
        ctx = self.ctx = gpu.ctx
        self.gpu, self.vpl_count = gpu, int(vpl_count)
        self.main_count, self.spare_count = int(cluster_count), int(spare_count)
        self.cluster_count = self.main_count + self.spare_count      # VAL records (and maps) in all
        self.vals = ctx.buffer(bytes(self.cluster_count * VAL_RECORD_BYTES))   # spare VALs start empty
        self.vpl_cluster = ctx.buffer(reserve=self.vpl_count * 4)
        self.val_vpl_count = ctx.buffer(reserve=self.cluster_count * 4)
        self.assign_stats = ctx.buffer(reserve=2 * 4)        # (unused), orphan VPLs (val_assign.glsl)
        self.split_pass = load_compute(ctx, SHADERS / "val_assign.glsl",
                                       dict(VAL_DEFINES, RECOUNT=0, SPLIT_REASSIGN=int(split_reassign)))
        self.count_pass = load_compute(ctx, SHADERS / "val_assign.glsl", dict(VAL_DEFINES, RECOUNT=1))
        self.recount_pass = load_compute(ctx, SHADERS / "val_assign.glsl", dict(VAL_DEFINES, RECOUNT=2))
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
        self.finalize = load_compute(ctx, SHADERS / "kmeans_update.glsl",
                                     dict(VAL_DEFINES, FINALIZE=1, ORIGIN_MEDOID=int(origin_medoid)))
        self.scatter_vao = ctx.vertex_array(self.scatter, [])
        self.assign_vao = ctx.vertex_array(self.assign, [])
        box_min = np.asarray(gpu.scene.vertices.min(axis=0) - gpu.origin, np.float32)
        box_max = np.asarray(gpu.scene.vertices.max(axis=0) - gpu.origin, np.float32)
        self.common = dict(u_cluster_count=self.cluster_count, u_vpl_count=self.vpl_count,
                           u_weight_position=float(weights[0]), u_weight_angle=float(weights[1]),
                           u_inv_scene_radius=1.0 / gpu.radius, u_val_lift=LIFT_SCALE * gpu.radius,
                           u_box_min=tuple(float(v) for v in box_min), u_box_max=tuple(float(v) for v in box_max),
                           u_val_first=0, u_val_end=self.main_count, u_orphans_only=0,
                           u_size_scale=float(size_scale))

    def bind(self) -> None:
        self.vals.bind_to_storage_buffer(VAL_DEFINES["BINDING_VALS"])
        self.vpl_cluster.bind_to_storage_buffer(VAL_DEFINES["BINDING_VPL_CLUSTER"])
        self.val_vpl_count.bind_to_storage_buffer(VAL_DEFINES["BINDING_VAL_COUNT"])

    def run(self, sampler: RsmVplSampler, iterations: int, split_round: bool = False, spare: int = 0) -> None:
        """The paper's k-means into VALs [0, M), or (split_round) of the orphan VPLs into the
        spare VALs [M, M + spare)."""
        ctx = self.ctx
        first, end = (self.main_count, self.main_count + spare) if split_round else (0, self.main_count)
        groups = (end - first + 63) // 64
        sampler.bind()
        self.bind()
        for prog in (self.init_pass, self.scatter, self.assign, self.update, self.finalize):
            set_uniforms(prog, **self.common)
            set_uniforms(prog, u_val_first=first, u_val_end=end, u_orphans_only=int(split_round))
        ctx.memory_barrier()
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
        if not split_round:
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

    def split(self, sampler: RsmVplSampler, maps, normal_offset: float) -> None:
        """Marks the orphans: the VPLs their VAL's map origin does not see (val_assign.glsl)."""
        ctx = self.ctx
        sampler.bind()
        self.bind()
        self.assign_stats.write(bytes(8))
        self.assign_stats.bind_to_storage_buffer(VAL_DEFINES["BINDING_ASSIGN_STATS"])
        maps.atlas.use(0)
        prog = self.split_pass
        set_uniforms(prog, **self.common)
        set_uniforms(prog, u_depth_atlas=0, u_tiles_x=maps.tiles_x, u_resolution=maps.resolution,
                     u_normal_offset=float(normal_offset))
        prog.run(group_x=(self.vpl_count + 63) // 64)
        ctx.memory_barrier()

    def recount(self) -> None:
        """The VPL count of every VAL under the final mapping."""
        ctx = self.ctx
        self.bind()
        self.val_vpl_count.write(self.zero_counts)
        for prog, n in ((self.count_pass, self.vpl_count), (self.recount_pass, self.cluster_count)):
            set_uniforms(prog, **self.common)
            prog.run(group_x=(n + 63) // 64)
            ctx.memory_barrier()

    def read_split_stats(self) -> dict:
        moved, orphans = np.frombuffer(self.assign_stats.read(), np.uint32)
        return {"moved": int(moved), "orphans": int(orphans)}

    def read(self) -> dict:
        """VALs and the mapping as numpy (tests, diagnostics): positions re-centred."""
        rec = np.frombuffer(self.vals.read(), np.float32).reshape(self.cluster_count, 4, 4)
        return {"position": rec[:, 0, :3].copy(), "count": rec[:, 0, 3].copy(), "normal": rec[:, 1, :3].copy(),
                "size": rec[:, 1, 3].copy(), "flux": rec[:, 2, :3].copy(), "far": rec[:, 2, 3].copy(),
                "origin": rec[:, 3, :3].copy(),
                "mapping": np.frombuffer(self.vpl_cluster.read(), np.int32).copy()}

    def release(self) -> None:
        park(self.ctx)
        for obj in (self.sum_fbo, self.bounds_fbo, *self.sums, self.bounds, self.scatter_vao, self.assign_vao,
                    self.scatter, self.assign, self.init_pass, self.update, self.finalize, self.vals,
                    self.vpl_cluster, self.val_vpl_count, self.assign_stats, self.split_pass, self.count_pass,
                    self.recount_pass):
            obj.release()
