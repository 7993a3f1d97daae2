"""The scene cut into small clusters of nearby triangles, and the per-face culling that lets each
hemicube face draw only the clusters its frustum can see.

Drawing the whole scene into all 5 faces of every VPL's hemicube spent ~3/4 of the stage on
per-triangle work, mostly for triangles that clipping then threw away (sponza at 1024 VPLs,
160x90: 25.6 s of the 32.7 s `vpl_shadow_maps` stage remained with 8x8 faces). A face's frustum holds a fifth of the
directions around the VPL, so most clusters lie wholly outside it. The culling is conservative
(a bounding sphere wholly outside one of the four side planes) and only drops triangles that the
clip planes would drop whole: the atlas is the same (up to the order of equal-depth fragments
of coincident triangles).

Each frame, with no read-back: `cull_clusters.glsl` counts per cluster the hemicube faces
that keep it, `cluster_commands.glsl` turns the counts into one instanced DrawElementsIndirect
command per cluster (its faces' ids packed from `baseInstance` on, an exclusive prefix sum), the
culling pass runs again to scatter the ids there, and one multi-draw renders every cluster into
the faces that kept it (the id reaches the vertex shader as a per-instance attribute). The id
list has room for every cluster in every face (4 bytes each: 21 MB on sponza at 1024 VPLs,
106 MB on conference). One command per kept (cluster, face) pair took as long (sponza: 1.2 M
commands, 15-20 s against 14-17 s: what remains is the triangles the faces keep, not the
commands) with a list sized by a read-back; pulling each pair's corners in a single draw lost
the vertex reuse of indexed draws (rooms 1.4 s -> 4.8 s).

Layout: triangles sorted along a Morton curve of their centroids, `cluster_triangles` per cluster
(the last one may hold fewer), indexing the scene's own vertex buffer.
"""
from __future__ import annotations

from pathlib import Path

import moderngl
import numpy as np

from bench.gl import load_compute, set_uniforms

SHADERS = Path(__file__).parent / "shaders"
CLUSTER_TRIANGLES = 64   # triangles per cluster: finer culling against more (cluster, face) pairs
CULL_GROUP = 64          # local_size_x of cull_clusters.glsl
COMMAND_BYTES = 20       # DrawElementsIndirect: count, instanceCount, firstIndex, baseVertex, baseInstance
CULL_BINDINGS = {"BINDING_CLUSTERS": 7, "BINDING_CLUSTER_COUNTS": 8, "BINDING_CLUSTER_COMMANDS": 9,
                 "BINDING_CLUSTER_INSTANCES": 10}
SPHERE_PAD = 1e-5        # radius padding relative to the scene radius (float32 rounding of the test)


def cluster_defines(cluster_triangles: int) -> dict:
    """The #defines the culling pass and the shadow-map draw share."""
    return dict(CULL_BINDINGS, CULL_GROUP=CULL_GROUP, CLUSTER_TRIANGLES=int(cluster_triangles))


def morton_order(points: np.ndarray) -> np.ndarray:
    """Indices that sort `points` (n x 3) along a 3-D Morton (Z-order) curve, 10 bits an axis."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    q = ((points - lo) / np.maximum(hi - lo, 1e-30) * 1023.0).astype(np.uint64)
    code = np.zeros(len(points), dtype=np.uint64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return np.argsort(code, kind="stable")


def build_clusters(positions: np.ndarray, faces: np.ndarray, cluster_triangles: int, radius: float):
    """(faces in cluster order, cluster records) for the clustered draw. Records are std430
    `Cluster`s: sphere (centre, padded radius) and (triangle count, first triangle, 0, 0)."""
    faces = np.asarray(faces, dtype=np.int64)
    corners = positions[faces].astype(np.float64)
    order = morton_order(corners.mean(axis=1))
    faces, corners = faces[order], corners[order]
    n_tri = len(faces)
    first_tri = np.arange(0, n_tri, cluster_triangles)
    lo = np.minimum.reduceat(corners.min(axis=1), first_tri, axis=0)
    hi = np.maximum.reduceat(corners.max(axis=1), first_tri, axis=0)
    centre = 0.5 * (lo + hi)
    cluster_of_tri = np.arange(n_tri) // cluster_triangles
    reach = np.linalg.norm(corners - centre[cluster_of_tri][:, None, :], axis=2).max(axis=1)
    sphere_radius = np.maximum.reduceat(reach, first_tri) * (1.0 + 1e-6) + SPHERE_PAD * radius
    records = np.zeros((len(first_tri), 8), dtype=np.float32)
    records[:, :3] = centre
    records[:, 3] = sphere_radius
    info = records.view(np.uint32)
    info[:, 4] = np.minimum(first_tri + cluster_triangles, n_tri) - first_tri
    info[:, 5] = first_tri
    return faces.astype(np.uint32), records


class ClusteredScene:
    """The scene's triangles in cluster order, the per-(VPL, face) culling passes and the
    multi-draw of what survives, for `instances` hemicube faces."""

    def __init__(self, gpu, program, defines: dict, instances: int, cluster_triangles: int = CLUSTER_TRIANGLES):
        """`program`: the shadow-map draw's (inputs in_position and the per-instance in_instance)."""
        ctx = self.ctx = gpu.ctx
        self.gpu, self.instances = gpu, int(instances)
        faces, records = build_clusters(gpu.positions, gpu.faces, int(cluster_triangles), gpu.radius)
        self.cluster_count = len(records)
        self.faces = ctx.buffer(faces)
        self.clusters = ctx.buffer(records)
        self.cluster_counts = ctx.buffer(reserve=self.cluster_count * 8)   # (faces kept, next slot) a cluster
        self.commands = ctx.buffer(reserve=self.cluster_count * COMMAND_BYTES)
        self.instance_ids = ctx.buffer(reserve=self.cluster_count * self.instances * 4)   # room for all
        self.defines = dict(defines, **cluster_defines(cluster_triangles))
        self.cull_pass = load_compute(ctx, SHADERS / "cull_clusters.glsl", self.defines)
        self.command_pass = load_compute(ctx, SHADERS / "cluster_commands.glsl", self.defines)
        self.vao = ctx.vertex_array(program, [(gpu.vbo_position, "3f", "in_position"),
                                              (self.instance_ids, "u/i", "in_instance")],
                                    index_buffer=self.faces, index_element_size=4)

    def cull(self, set_common) -> None:
        """The clusters' commands and their faces' ids, for the VPLs bound (GPU only)."""
        ctx = self.ctx
        for name, buf in (("BINDING_CLUSTERS", self.clusters), ("BINDING_CLUSTER_COUNTS", self.cluster_counts),
                          ("BINDING_CLUSTER_COMMANDS", self.commands),
                          ("BINDING_CLUSTER_INSTANCES", self.instance_ids)):
            buf.bind_to_storage_buffer(CULL_BINDINGS[name])
        for prog in (self.cull_pass, self.command_pass):
            set_common(prog)
            set_uniforms(prog, u_cluster_count=self.cluster_count)
        self.cluster_counts.clear()
        groups = dict(group_x=(self.cluster_count + CULL_GROUP - 1) // CULL_GROUP, group_y=self.instances)
        set_uniforms(self.cull_pass, u_scatter=0)
        self.cull_pass.run(**groups)        # count the faces that keep each cluster
        ctx.memory_barrier()
        self.command_pass.run(group_x=1)    # commands, and where each cluster's ids start
        ctx.memory_barrier()
        set_uniforms(self.cull_pass, u_scatter=1)
        self.cull_pass.run(**groups)        # the same test again, writing the ids
        ctx.memory_barrier()

    def kept_pairs(self) -> int:
        """How many (cluster, face) pairs the last culling kept (a read-back: after the frame)."""
        counts = np.frombuffer(self.cluster_counts.read(), dtype=np.uint32).reshape(-1, 2)
        return int(counts[:, 0].sum())

    def draw(self) -> None:
        """Every cluster into the faces that see it: one multi-draw, a command per cluster."""
        self.vao.render_indirect(self.commands, mode=moderngl.TRIANGLES, count=self.cluster_count)

    def release(self) -> None:
        for obj in (self.vao, self.faces, self.clusters, self.cluster_counts, self.commands, self.instance_ids,
                    self.cull_pass, self.command_pass):
            obj.release()
