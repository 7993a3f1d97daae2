"""`visibility_gates`: VPL indirect illumination whose visibility comes from the topology of the
empty space (Visibility Gates; paper: /work/shared/papers/visibility_gates.txt, "... a new method
based on virtual point lights and topological information about the scene ...").

Precomputation (`prepare`, untimed, CPU; see topology.py; cached per scene and knobs):
voxelization of the enclosed empty space, its curvilinear skeleton with maximal-ball radii,
simplified (spur pruning), segmentation of the skeleton (topology, curvature and coverage
nodes), greedy *visibility clusters* (quasi-convex parts of the empty space: rooms, corridors, door openings) and one
*visibility gate* per segmented edge between two clusters: a disk at the middle of the edge,
orthogonal to it, of radius min(maxball(n1), maxball(n2)) x `gate_radius_scale`.

Per frame (stages, after the shared `gbuffer_shadow`, `direct_light`, `rsm`):

1. `vpl_sample`: N VPLs importance-sampled from the RSM, exactly `ir_unshadowed`'s (same code,
   same random numbers: for one seed and frame all three VPL methods use identical VPLs).
2. `geometry_clusters` (paper: IUGC): each view sample gets its visibility cluster (the voxel
   grid, looked up one voxel off the surface along the normal) and a clustered-shading key
   (16x16 screen tile, exponential depth slice, visibility cluster); unique keys per tile are
   found by a local bitonic sort in shared memory, compacted, and given a bounding box.
3. `light_assignment` (LA): each VPL's visibility cluster; then per geometry cluster a bit mask
   of the VPLs that may light it: the VPLs of its own visibility cluster, and VPLs of another
   cluster C whose cone through one of C's gates meets the cluster's bounding sphere (brute
   force over VPLs, as in the paper; indirect dispatch over the clusters found).
4. `gather` (IL): each pixel sums its cluster's VPLs with the Lambertian VPL term of
   ir_unshadowed; a VPL from another visibility cluster C counts only if the pixel is in its
   cone through one of C's gates: the segment VPL -> pixel crosses that gate's disk.

Visibility is therefore V = 1 inside a visibility cluster (quasi-convexity: no shadow test),
V = [segment crosses a gate of the VPL's cluster] otherwise. With the same VPLs the result is
<= `ir_unshadowed` at every pixel, equal where the scene is one cluster (a sphere seen from
inside: rho^2 I / (pi R^2)). The light assignment culls exactly: it never drops a VPL the final
segment test would accept (conservative cone/sphere test).

Paper formula corrections and readings (checked against the invariant each must satisfy):
- Gather: the paper writes L(P->V) = sum f_r G V L(P_i) with L(P_i) "the intensity of the VPL".
  Energy conservation of a Lambertian VPL carrying flux Phi needs its normal intensity
  Phi/pi: L = rho/pi sum Phi_i/pi cos_x cos_i / d^2 (the cosine at the VPL belongs to the VPL's
  intensity, the one at x to G); with that the sphere test gives rho^2 I/(pi R^2) exactly.
- Curvature nodes: the text (curv = dist(n, L1Lk)/maxball(n) > 1: the chord misses the ball)
  and the caption of its Fig. 4 ("distance ... shorter than the radius") contradict each other;
  the text's test is the one consistent with its own reasoning and is used. For a closed loop
  (L1 = Lk) the distance to the chord is the distance to L1.
- Which node is cut: the most curved node first (recursively); for coverage, the first
  uncovered node walking from L1 (so the part before it is covered by L1's ball).
- Skeleton simplification (not spelled out in the paper, which takes a *filtered* curvilinear
  skeleton from cubical-complex thinning [20]): scikit-image's thinning keeps end points, so it
  grows a spur towards every convex corner and edge of a room; with maximal balls shrinking
  along it, each spur became its own small visibility cluster reachable only through a small
  gate. Before segmentation every terminal branch all of whose nodes its junction sees in a
  straight line through the empty space is removed (topology.prune_spurs; one pass over the
  original branches, so a room behind a door, which has junctions of its own, is never pruned).
- alpha: "add all neighbors of m ... for which radius of maximal balls does not differ more than
  alpha % of the maximal radius contained in the cluster" / "how similar two maximal balls must
  be": the two balls compared are the popped node m's and its neighbour k's, the tolerance is
  alpha % of the cluster's largest radius: |r_k - r_m| <= alpha/100 r_max(C) (alpha = 20 in the
  paper). Comparing r_k with r_max(C) itself (the earlier reading) cut every line whose radius
  shrinks gradually into many clusters.
- Which view samples a cone lights: the paper tests the cones "against view samples contained
  in other clusters" (V) and "against all cones created from the combination of the VPL and a
  visibility gate" (V.C); the gates combined with a VPL of cluster C are those separating C from
  its neighbours. So a view sample of any cluster D != C is lit when it lies in such a cone
  (beyond the gate: the segment crosses the disk), not only when D is the neighbour across that
  gate (the earlier reading, from Fig. 11's caption, which shows one example; with it a door
  that forms its own cluster blocked all light between two rooms). A cone may continue through
  a wall behind the neighbour; the light assignment and gather accept that approximation, as
  the paper does (measured on `rooms`: the room two offset doors away stays darker than
  ir_shadowed).
- Voxel -> cluster: as the paper, geodesically nearest skeleton node, then the nearest extremum
  of its line, then that segmented node's cluster (not maximal-ball containment).
- Light lists: the paper stores (VPL, gate) pairs per geometry cluster; here a VPL bit mask,
  and the fragment tests every gate of the VPL's cluster, which accepts exactly the pairs
  whose segment crosses one of them and never counts a VPL twice when its segment crosses
  two gates.

Known behaviour (the paper's "results slightly darker than the reference ... since gates are
only disks, we still miss a lot of VPLs"): narrow spaces beside objects (between a block and a
wall) become clusters of their own, reached from the main one only through disks of the
narrow space's maximal-ball radius. With the same VPLs at 128x96 and default settings, mean
indirect / ir_shadowed's: cornell_spot 0.64, rooms 0.59, hidden_bounce 0.60 (cornell_spot at
voxel_resolution 32, one room cluster: 1.02). The cluster count, hence the darkening, depends
on voxel_resolution through the voxel skeleton's shape.

| parameter          | default | range        | meaning                                                    |
|--------------------|---------|--------------|------------------------------------------------------------|
| vpl_count          | 256     | 1 .. 65536   | VPLs per frame (quality; sweep 16, 64, 256, 1024)          |
| voxel_resolution   | 64      | 16 .. 256    | voxels along the scene's longest side (quality; 32 64 128) |
| alpha_percent      | 20      | 0 .. 1000    | radius similarity of clustered skeleton nodes (%)          |
| gate_radius_scale  | 1.0     | 0 .. 8       | gate disk radius multiplier (0: no light through gates)    |
| use_gates          | true    | bool         | false: light stays inside visibility clusters (paper VI.B) |
| depth_slices       | 16      | 1 .. 256     | clustered-shading depth slices (exponential in depth)      |
| clamp_distance_rel | 1e-4    | 1e-7 .. 1    | eps of max(eps, d), relative to the scene radius           |

Scenes with no enclosed empty space at the chosen resolution (open scenes) are skipped
(SkipRow); so are topologies of 2^20 visibility clusters or more. `extra` of the frame output
reports the precomputation time (s), cluster and gate counts.
"""
from __future__ import annotations

import time
from collections import OrderedDict
from pathlib import Path

import moderngl
import numpy as np

from bench.gl import load_compute, load_program, set_uniforms
from bench.gl.context import LOOP_CHUNK, loop_chunks, park
from bench.method import FrameOutput, MethodBase, Param, SkipRow
from methods.ir_unshadowed.method import CLAMP_DOC, VPL_COUNT_DOC
from methods.ir_unshadowed.vpl_sampling import VPL_DEFINES, RsmVplSampler

from .topology import Topology, TopologyError, build_topology

SHADERS = Path(__file__).parent / "shaders"
TILE = 16            # clustered-shading screen tile (pixels); TILE^2 = the local sort's size
CLUSTER_BITS = 20    # geometry-cluster key: depth slice << CLUSTER_BITS | visibility cluster
LA_GROUP = 64
SLICE_NEAR_REL = 1e-2  # view depth of the first slice boundary, relative to the scene radius
GATE_DEFINES = dict(VPL_DEFINES, BINDING_GATES=7, BINDING_ADJ_RANGES=8, BINDING_ADJ_ENTRIES=9,
                    BINDING_VPL_CLUSTER=10, BINDING_GEO_CLUSTERS=11, BINDING_PIXEL_CLUSTER=12,
                    BINDING_CLUSTER_COUNT=13, BINDING_LIGHT_MASKS=14, TILE=TILE,
                    CLUSTER_BITS=CLUSTER_BITS, LA_GROUP=LA_GROUP)

_TOPOLOGY_CACHE: OrderedDict = OrderedDict()
_CACHE_SIZE = 4


def scene_topology(scene, resolution: int, alpha_percent: float) -> tuple[Topology, bool]:
    """The scene's topology (built, or from the small in-process cache) and whether it was cached."""
    key = (scene.content_hash(), int(resolution), float(alpha_percent))
    if key in _TOPOLOGY_CACHE:
        _TOPOLOGY_CACHE.move_to_end(key)
        return _TOPOLOGY_CACHE[key], True
    topo = build_topology(scene.vertices, scene.faces, resolution, alpha_percent, scene.name)
    _TOPOLOGY_CACHE[key] = topo
    while len(_TOPOLOGY_CACHE) > _CACHE_SIZE:
        _TOPOLOGY_CACHE.popitem(last=False)
    return topo, False


def adjacency_arrays(topo: Topology) -> tuple[np.ndarray, np.ndarray]:
    """Per cluster C the range of its entries (D, gate) in one array (both directions of each gate)."""
    entries = []
    for g, (a, b) in enumerate(topo.gate_clusters):
        entries.append((int(a), int(b), g))
        entries.append((int(b), int(a), g))
    entries.sort()
    ranges = np.zeros((topo.cluster_count, 2), np.int32)
    table = np.zeros((max(len(entries), 1), 2), np.int32)
    for i, (c, d, g) in enumerate(entries):
        table[i] = (d, g)
    counts = np.bincount([e[0] for e in entries], minlength=topo.cluster_count) if entries else \
        np.zeros(topo.cluster_count, np.int64)
    ends = np.cumsum(counts)
    ranges[:, 0] = ends - counts
    ranges[:, 1] = ends
    return ranges, table


class VisibilityGates(MethodBase):
    name = "visibility_gates"
    summary = "VPLs with visibility from empty-space topology: quasi-convex clusters joined by gate disks"
    stages = ("vpl_sample", "geometry_clusters", "light_assignment", "gather")
    needs = frozenset({"gbuffer", "shadow_map", "direct", "rsm", "precompute"})
    params = {
        "vpl_count": Param(256, VPL_COUNT_DOC, 1, 65536, quality=True, sweep=(16, 64, 256, 1024)),
        "voxel_resolution": Param(64, "voxels along the scene's longest bounding-box side (precomputation)",
                                  16, 256, quality=True, sweep=(32, 64, 128)),
        "alpha_percent": Param(20.0, "skeleton nodes join a visibility cluster when their maximal-ball radius "
                                     "is within alpha % of the cluster's largest", 0.0, 1000.0),
        "gate_radius_scale": Param(1.0, "gate disk radius multiplier (1: min of the two maximal balls; "
                                        "0: no light crosses gates)", 0.0, 8.0),
        "use_gates": Param(True, "false: indirect light stays inside visibility clusters"),
        "depth_slices": Param(16, "clustered-shading depth slices, exponential in view depth", 1, 256),
        "clamp_distance_rel": Param(1e-4, CLAMP_DOC, 1e-7, 1.0),
    }

    def prepare(self, gpu, scene, facts, params, view) -> None:
        self.params = params
        t0 = time.perf_counter()
        try:
            topo, cached = scene_topology(scene, params["voxel_resolution"], params["alpha_percent"])
        except TopologyError as exc:
            raise SkipRow(str(exc)) from None
        if topo.cluster_count >= 1 << CLUSTER_BITS:
            raise SkipRow(f"scene '{scene.name}': {topo.cluster_count} visibility clusters, over the "
                          f"{1 << CLUSTER_BITS} the geometry-cluster key holds")
        self.topology = topo
        self.info = {"precompute_s": time.perf_counter() - t0, "precompute_cached": cached,
                     "visibility_clusters": topo.cluster_count, "gates": int(len(topo.gate_radius)),
                     "skeleton_nodes": int(len(topo.node_position)),
                     **{f"precompute_{k}_s": v for k, v in topo.timings_s.items()}}
        ctx = self.ctx = gpu.ctx
        self.width, self.height = view.width, view.height
        self.eps = params["clamp_distance_rel"] * gpu.radius
        self.vpl_count = params["vpl_count"]
        self.words = (self.vpl_count + 31) // 32
        self.eye = np.asarray(view.eye_local, np.float32)
        fwd = np.asarray(view.camera.target, float) - np.asarray(view.camera.eye, float)
        self.forward = (fwd / np.linalg.norm(fwd)).astype(np.float32)
        self.slice_near = SLICE_NEAR_REL * gpu.radius
        self.slice_log_scale = params["depth_slices"] / np.log(max(view.far / self.slice_near, 1.0 + 1e-6))

        grid = np.ascontiguousarray(topo.cluster_grid.transpose(2, 1, 0), dtype=np.int32)  # x fastest
        self.grid_tex = ctx.texture3d(topo.dims, 1, grid.tobytes(), dtype="i4")
        self.grid_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.grid_origin = tuple(float(v) for v in topo.origin - gpu.origin)
        gates = np.zeros((max(len(topo.gate_radius), 1), 2, 4), np.float32)
        gates[:len(topo.gate_radius), 0, :3] = topo.gate_centre - gpu.origin
        gates[:len(topo.gate_radius), 0, 3] = topo.gate_radius
        gates[:len(topo.gate_radius), 1, :3] = topo.gate_normal
        ranges, table = adjacency_arrays(topo)
        self.gates = ctx.buffer(gates.tobytes())
        self.adj_ranges = ctx.buffer(ranges.tobytes())
        self.adj_entries = ctx.buffer(table.tobytes())
        max_degree = int((ranges[:, 1] - ranges[:, 0]).max(initial=0))
        # llvmpipe's loop limit counts the gate loop of every VPL too (bench.gl.context.LOOP_CHUNK)
        self.chunk_words = max(1, LOOP_CHUNK // (32 * (1 + max_degree)))

        tiles = ((self.width + TILE - 1) // TILE, (self.height + TILE - 1) // TILE)
        self.tiles = tiles
        capacity = tiles[0] * tiles[1] * TILE * TILE  # at most one geometry cluster per pixel
        self.vpl_cluster = ctx.buffer(reserve=self.vpl_count * 4)
        self.geo_clusters = ctx.buffer(reserve=capacity * 32)
        self.pixel_cluster = ctx.buffer(reserve=self.width * self.height * 4)
        self.cluster_count = ctx.buffer(reserve=16)
        self.light_masks = ctx.buffer(reserve=capacity * self.words * 4)

        defines = dict(GATE_DEFINES, DEPTH_SLICES=params["depth_slices"])
        self.vpl_cluster_pass = load_compute(ctx, SHADERS / "vpl_clusters.glsl", defines)
        self.cluster_pass = load_compute(ctx, SHADERS / "geometry_clusters.glsl", defines)
        self.dispatch_pass = load_compute(ctx, SHADERS / "dispatch_args.glsl", defines)
        self.assign_pass = load_compute(ctx, SHADERS / "light_assignment.glsl", defines)
        self.gather = load_program(ctx, SHADERS / "gather.glsl", defines)
        self.gather_vao = ctx.vertex_array(self.gather, [])
        self.indirect = ctx.texture((self.width, self.height), 4, dtype="f4")
        self.indirect.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.fbo = ctx.framebuffer([self.indirect])
        self.sampler = RsmVplSampler(ctx, self.vpl_count)

    def _bind_topology(self, program) -> None:
        for buf, binding in ((self.gates, "BINDING_GATES"), (self.adj_ranges, "BINDING_ADJ_RANGES"),
                             (self.adj_entries, "BINDING_ADJ_ENTRIES"), (self.vpl_cluster, "BINDING_VPL_CLUSTER"),
                             (self.geo_clusters, "BINDING_GEO_CLUSTERS"),
                             (self.pixel_cluster, "BINDING_PIXEL_CLUSTER"),
                             (self.cluster_count, "BINDING_CLUSTER_COUNT"),
                             (self.light_masks, "BINDING_LIGHT_MASKS")):
            buf.bind_to_storage_buffer(GATE_DEFINES[binding])
        self.sampler.bind()
        self.grid_tex.use(7)
        set_uniforms(program, u_cluster_grid=7, u_grid_origin=self.grid_origin,
                     u_grid_pitch=float(self.topology.pitch), u_grid_dims=tuple(self.topology.dims),
                     u_gate_scale=float(self.params["gate_radius_scale"]))

    def render(self, frame, prof) -> FrameOutput:
        ctx, passes = self.ctx, frame.passes
        gbuffer = passes.gbuffer
        with prof.stage("vpl_sample"):
            self.sampler.sample(passes.rsm, frame.random_u32(0))
        with prof.stage("geometry_clusters"):
            self.cluster_count.write(np.zeros(4, np.uint32).tobytes())
            self._bind_topology(self.cluster_pass)
            gbuffer.bind(self.cluster_pass)
            set_uniforms(self.cluster_pass, u_size=(self.width, self.height), u_eye=tuple(self.eye),
                         u_forward=tuple(self.forward), u_slice_near=float(self.slice_near),
                         u_slice_log_scale=float(self.slice_log_scale))
            self.cluster_pass.run(group_x=self.tiles[0], group_y=self.tiles[1])
            ctx.memory_barrier()
        with prof.stage("light_assignment"):
            self._bind_topology(self.vpl_cluster_pass)
            set_uniforms(self.vpl_cluster_pass, u_vpl_count=self.vpl_count)
            self.vpl_cluster_pass.run(group_x=(self.vpl_count + 63) // 64)
            set_uniforms(self.dispatch_pass, u_words=self.words)
            self.dispatch_pass.run(group_x=1)
            ctx.memory_barrier()
            self._bind_topology(self.assign_pass)
            set_uniforms(self.assign_pass, u_vpl_count=self.vpl_count, u_words=self.words,
                         u_use_gates=bool(self.params["use_gates"]))
            self.assign_pass.run_indirect(self.cluster_count, offset=4)
            ctx.memory_barrier()
        with prof.stage("gather"):
            self.fbo.use()
            ctx.viewport = (0, 0, self.width, self.height)
            self.fbo.clear(0.0, 0.0, 0.0, 0.0)
            ctx.disable(moderngl.DEPTH_TEST)
            ctx.enable(moderngl.BLEND)  # additive: each draw sums the VPLs of a range of words
            ctx.blend_func = moderngl.ONE, moderngl.ONE
            gbuffer.bind(self.gather)
            self._bind_topology(self.gather)
            set_uniforms(self.gather, u_width=self.width, u_vpl_count=self.vpl_count, u_words=self.words,
                         u_eps=float(self.eps))
            for first, end in loop_chunks(self.words, self.chunk_words):
                set_uniforms(self.gather, u_word_first=first, u_word_end=end)
                self.gather_vao.render(moderngl.TRIANGLES, vertices=3)
            ctx.disable(moderngl.BLEND)
        return FrameOutput(direct=passes.direct.radiance, indirect=self.indirect, extra=dict(self.info))

    def release(self) -> None:
        if getattr(self, "ctx", None) is None:  # prepare() stopped before allocating anything
            return
        park(self.ctx)
        for name in ("fbo", "indirect", "gather_vao", "gather", "assign_pass", "dispatch_pass", "cluster_pass",
                     "vpl_cluster_pass", "light_masks", "cluster_count", "pixel_cluster", "geo_clusters",
                     "vpl_cluster", "adj_entries", "adj_ranges", "gates", "grid_tex", "sampler"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.release()
                setattr(self, name, None)
        self.ctx = None
