"""`visibility_gates`: VPL indirect illumination whose visibility comes from the topology of the
empty space (Visibility Gates; paper: /work/shared/papers/visibility_gates.txt, "... a new method
based on virtual point lights and topological information about the scene ...").

Precomputation (`prepare`, untimed, CPU; see topology.py; cached per scene and knobs):
voxelization of the empty space light travels in (enclosed rooms; for open scenes the space
around the geometry, closed by the enlarged bounding box), its curvilinear skeleton, simplified
(spur pruning), maximal-ball radii measured to the triangles, segmentation of the skeleton
(topology, curvature and coverage nodes), greedy *visibility clusters* (quasi-convex parts of
the empty space: rooms, corridors), clusters joined by a wide gate merged, and one *visibility
gate* per segmented edge between two clusters: the opening of the empty space where the
skeleton line is narrowest, as a convex polygon (x `gate_radius_scale`); the voxel -> cluster
grid is cut along the gates, so the gates are the clusters' borders.

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
   ir_unshadowed (with its near field: each VPL's 1/d^2 bounded at the radius of the area it
   stands for, bench/gl/near_field.py); a VPL from another visibility cluster C counts only if the segment VPL ->
   pixel, leaving C through the first of C's gates it crosses, enters the pixel's cluster, or
   walks on, cluster to cluster through the first gate crossed each time, and enters it within
   `gate_hops` gates.

Visibility is therefore V = 1 inside a visibility cluster (quasi-convexity: no shadow test),
V = [the segment reaches the pixel's cluster through gates] otherwise. With the same VPLs the result is
<= `ir_unshadowed` at every pixel, equal where the scene is one cluster (a sphere seen from
inside: rho^2 I / (pi R^2)). The light assignment culls exactly: it never drops a VPL the final
segment test would accept (conservative cone/sphere test). Needs: gbuffer, shadow_map, direct,
rsm, precompute. The measured ratios per scene, the cluster and gate counts and what each
correction below fixed are in NOTES.md beside this file.

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
  straight line through the empty space is removed (skeleton.prune_spurs; one pass over the
  original branches, so a room behind a door, which has junctions of its own, is never pruned).
- Maximal balls (IV.A, "the radius of the maximal ball contained in the empty space"): the
  exact distance from the node to the nearest triangle (a k-d tree of surface samples gives
  candidates, trimesh's point-triangle distance the value; the closing box's walls count for
  open scenes), not the distance transform of the voxels, which measured to the thickened
  voxel surface and made the radii, hence the clusters, depend on voxel_resolution.
- Voxelization (IV.A, "a binary voxelization"): a voxel is occupied when its centre is within
  sqrt(3)/2 voxel of a triangle (exact distance; `occupancy=sphere`, the default). The thinning
  treats the empty space as 26-connected; a sampled voxelization (a voxel holding a point of a
  triangle) leaves 26-connected holes in a tilted wall, through which the skeleton passes.
  `occupancy=touch` is the paper's voxels touching a surface: occupied when the closed cube
  intersects a triangle (exact separating-axis test), a thinner shell that still closes every
  wall (the segment between two 26-adjacent centres lies in their two closed cubes). Measured at
  the defaults it is no default: see NOTES.md ("Touching voxels").
- Open scenes (the paper's own Sponza has an open roof): the empty space is the enclosed
  components plus the component around the geometry that holds a camera eye or a positional
  light ("the empty space, where light travels", III), closed by the scene's bounding box
  enlarged by two voxels. A scene whose cameras and lights are all outside that box and which
  encloses nothing is skipped (SkipRow).
- Merging (not in the paper; `merge_gate_fraction`): after the greedy clustering, two clusters
  joined by a gate whose radius (the paper's min of the two maximal balls) is at least
  `merge_gate_fraction` x the smaller cluster's largest maximal ball are merged, widest first,
  re-evaluated after each merge. Such a gate is no narrowing of the space, only a break in the
  voxel skeleton's radii (a corner of a room, the space beside a block; a door's own cluster
  beside its room), and light crossing it is barely occluded; a door between rooms (gate a
  third of the rooms' balls) stays a gate. With `merge_visible_fraction` > 0 (default 0.5; 0:
  no test) a merge must also keep the paper's own definition of a visibility cluster (IV.B: "the
  union of the maximal balls centered in these nodes is quasi-convex"): at least that fraction
  of the straight segments between the two clusters' skeleton nodes (32 of each, evenly spaced)
  must stay in the voxelised empty space, else the two stay apart, joined by their gate
  (re-tested when either grows by another merge). A nave beside its aisles behind a row of
  pillars, or two arms of an L, fail it; a door's own cluster beside its room passes.
- Gate shape and place (the paper's own improvement, VI.B: "use polygon instead of disks to
  better match the shape of separation between clusters"; its disk, at the middle of the
  segmented edge, sits half a room before a door with the door's half-width as radius): the gate
  lies at the narrowest node of the skeleton line the segmented edge replaces, in a plane
  through it: first the plane of the opening's frame (the area-weighted mean plane of the
  triangles near the node that face along the skeleton, within 30 degrees: a door's wall, a
  thick wall's mid-plane), then planes normal to the line (tangents over 8..1 nodes) or to the
  edge; the first whose bounded opening is within 5 % of the smallest is taken (a plane tilted
  against a thin wall measures a few % small). The opening (the plane's region farther than
  sqrt(3)/2 voxel from every triangle, rasterised) gives a convex polygon: its convex hull (at
  most 16 edges), each edge then placed where the opening ends by exact distances (marching
  outward: the region ends at s_f, the occluder's nearest approach beyond it is d_min, the
  border is sqrt(w^2 - d_min^2) past s_f): a door's rectangle exactly, in the wall's plane.
  Where no plane has a bounded opening within 4 maximal-ball radii (open space), the regular
  16-gon of that node's maximal-ball disk's area. (An ellipse with the opening's second moments
  sticks out of a door's sides and lintel and cuts its corners.)
- Clusters split at the gates (paper VII: the artefacts "would disappear if the visibility
  gates were perfect manifolds separating clusters"; IV.A gives each voxel its nearest skeleton
  node): the voxel -> cluster grid is flooded from the skeleton nodes through the empty space
  cut along the gates (each gate rasterised as a digital plane inside its polygon grown by a
  voxel); a cluster's nodes beyond one of its gates (a door's own nodes) seed nothing; in a
  gate's voxels and its wall's voxels in its plane (up to 3 gate radii away) the side of the
  gate's plane decides between its two clusters. (The nearest-node grid puts a door's
  neighbourhood of one room in the next room's cluster and splits the walls' voxels
  arbitrarily.)
- Gates over the clusters' whole borders (`border_gates`, opt-in, default off; paper VII: the
  artefacts "would disappear if the visibility gates were perfect manifolds separating
  clusters", VI.B: "A good improvement to the method would be to use polygon instead of disks to
  better match the shape of separation between clusters"): the flooding gives every empty voxel
  a cluster, so two clusters meet wherever their floods meet, while a skeleton edge's gate is
  one opening of that border (sponza's arcades open to the atrium through a row of arches, one
  skeleton edge, one arch's polygon). With `border_gates` the faces of every connected patch of
  the border between two clusters that lie outside the pair's gates get gates of their own: the
  patch split into pieces within a voxel of their mean plane, each piece's convex polygon
  (gates.border_gates; then no border face lies outside a gate). Measured (NOTES.md): the mean
  of the visible bounce on sponza 0.52 -> 0.66, lost_empire 0.69 -> 0.78, conference 1.08 ->
  1.13; relMSE -1% to +29% on the real scenes; the frame 1.5-6x slower (sibenik 2.6 -> 13 s).
  The light sponza lacks is lost at the thin clusters along its columns and arches, not at
  uncovered borders. Not the default.
- Which view samples a cone lights (`gate_hops`): the paper tests the cones "against view
  samples contained in other clusters" (V) while its Fig. 11 lights "the neighbor visibility
  cluster". Lighting any cluster behind a gate leaks through walls. Here the segment VPL ->
  pixel walks from cluster to cluster, each time through the first gate of the current cluster
  it crosses, and lights the pixel when it enters the pixel's cluster within `gate_hops` gates
  (default 4): the cones to "other clusters" narrowed to the light that passes every gate on its
  way. With gates that are the openings and clusters split at them, this is exact visibility on
  rooms, where light crosses two doors, which one hop (Fig. 11) loses.
- alpha: "add all neighbors of m ... for which radius of maximal balls does not differ more than
  alpha % of the maximal radius contained in the cluster" / "how similar two maximal balls must
  be": the two balls compared are the popped node m's and its neighbour k's, the tolerance is
  alpha % of the cluster's largest radius: |r_k - r_m| <= alpha/100 r_max(C) (alpha = 20 in the
  paper). Comparing r_k with r_max(C) itself (the earlier reading) cut every line whose radius
  shrinks gradually into many clusters.
- Voxel -> cluster: as the paper, geodesically nearest skeleton node, then the nearest extremum
  of its line, then that segmented node's cluster (not maximal-ball containment), with the
  flooding cut along the gates (above).
- Light lists: the paper stores (VPL, gate) pairs per geometry cluster; here a VPL bit mask,
  and the fragment walks the gates of the VPL's cluster (its first step is one of the cones
  the light assignment tested, so the culling stays conservative), never counting a VPL twice.
  llvmpipe's loop limit (bench.gl.context.LOOP_CHUNK) counts every VPL's walk (gate_hops x
  gates of a cluster x polygon edges): a gather draw sums whole words of 32 VPLs, or a range
  of one word's bits when a word's walks alone would pass it; a scene whose single VPL walk
  passes it is skipped (SkipRow).

Known behaviour (NOTES.md has the figures): with the same VPLs the result is ir_unshadowed's
wherever the scene is one visibility cluster (a box with blocks, hidden_bounce's room), and on
rooms the same VPLs summed with exact visibility; an open scene whose cameras and light are
outside its bounding box (lit_wall_corner) is skipped. The excess inside merged, not quite
convex clusters is the paper's own over-estimate (VI.B).

On the real scenes at 320x180 (NOTES.md) the relMSE against the visible reference is below that
of no indirect light on sponza, sibenik, conference, cornell_box and holodeck, and the image
mean lies between the visible and the unshadowed bounce on sibenik (1.04 of the visible),
conference (1.08), cornell_box (1.10) and holodeck (1.05). Sponza is darker (0.52 of the visible
bounce; the paper's own "slightly darker than the reference", VI.B: its atrium, arcades and
galleries are not quasi-convex with one another, light between them crosses few gates, and the
thin clusters along its columns and arches receive little), and lost_empire's topology at 64
voxels over-closes its caves (0.69, relMSE above no indirect; the thinner `occupancy=touch`
shell opens more of them and splits the lit cavern further: 0.60, relMSE 1.27, NOTES.md). A finer grid is no default: at
128 voxels (with a first `border_gates`, one polygon per patch) sponza reads 0.45 (mean 0.81) but sibenik 0.83, conference 2.2
(23 s a frame) and lost_empire 1.8.

Quality ladder (`gibench run`): vpl_count 256, 1024 (default), 2048 (4096 costs 5-7 s a frame on
the real scenes at 320 x 180): at 256 and 1024 a rung compares with the unshadowed VPLs and with
ir_shadowed at equal count. The default is 1024 for the reason ir_unshadowed's is (its manual: at 256 the VPLs
importance-sampled over sponza's lit surface leave the view to a handful; the gates' relMSE
there 4.7 at 256, 1.1 at 1024, NOTES.md). The gather and the light assignment cost
VPLs x gates, the topology (untimed) is shared by all rungs; voxel_resolution is not a rung (it
changes the untimed precomputation only, and at 32 closes rooms' second door).

Parameters:

<!-- parameters: generated from the Param declarations by `gibench manuals --write` -->
| parameter              | default   | range                          | meaning |
|------------------------|-----------|--------------------------------|---|
| vpl_count              | 1024      | 1 .. 65536                     | VPLs drawn from the RSM per frame (importance sampled by flux luminance, stratified) (quality knob; sweep 64, 256, 1024, 4096) |
| voxel_resolution       | 64        | 16 .. 256                      | voxels along the scene's longest bounding-box side (precomputation) (quality knob; sweep 32, 64, 128) |
| occupancy              | sphere    | touch, sphere                  | voxelization (precomputation): touch, a voxel is occupied when its cube meets a triangle; sphere, when its centre is within sqrt(3)/2 voxel of one (thicker) |
| alpha_percent          | 20.0      | 0.0 .. 1000.0                  | skeleton nodes join a visibility cluster when their maximal-ball radius is within alpha % of the cluster's largest |
| merge_gate_fraction    | 0.75      | 0.0 .. 2.0                     | clusters joined by a gate at least this fraction as wide as the smaller cluster's largest maximal ball are merged (above 1: never) |
| merge_visible_fraction | 0.5       | 0.0 .. 1.0                     | a merge also needs this fraction of the straight segments between the two clusters' skeleton nodes inside the empty space (the merged cluster stays quasi-convex; 0: no test) |
| border_gates           | false     | bool                           | every patch of the clusters' borders no skeleton gate covers gets gates of its own (false: the skeleton edges' gates only, the paper's) |
| gate_radius_scale      | 1.0       | 0.0 .. 8.0                     | gate size multiplier (1: the polygon of the opening, or the maximal-ball disk in open space; 0: no light crosses gates) |
| gate_hops              | 4         | 1 .. 16                        | gates a VPL's light may cross on its way to a pixel (1: into a neighbouring cluster only, paper Fig. 11) |
| use_gates              | true      | bool                           | false: indirect light stays inside visibility clusters (paper VI.B) |
| depth_slices           | 16        | 1 .. 256                       | clustered-shading depth slices, exponential in view depth |
| clamp_distance_rel     | 0.0001    | 1e-07 .. 1.0                   | distance clamp eps of max(eps, distance) relative to the scene radius (tames the 1/d^2 singularity) |
| near_field             | footprint | clamp, disc_element, footprint | how an emitter's 1/d^2 is bounded near it, d the emitter-receiver distance, A the area it stands for: clamp max(eps, d)^2; disc_element d^2 + A / pi (a disc's form factor); footprint max(d^2, s A / pi) (a clamp at the radius of s times the emitter's area); each at least eps^2 |
| near_field_scale       | 1.0       | 0.001 .. 100.0                 | s of near_field=footprint: the clamp's area as a fraction of the area the emitter stands for |
<!-- end of parameters -->

Example: `gibench run --scenes rooms --methods visibility_gates,ir_shadowed --res 128x96 --param
visibility_gates.gate_hops=1,4` (the paper's one hop into a neighbour against the default walk).

Scenes with no empty space at the chosen resolution (nothing enclosed, and no camera or
positional light in the space around the geometry) are skipped (SkipRow); so are topologies of
2^20 visibility clusters or more. `extra` of the frame output reports the precomputation time
(s, and per step), cluster counts (greedy, after merging), gate count and `closed_by_box`.

In motion (bench.run.sequence): The topology of empty space is kept when only cameras or lights
moved and every eye and positional light is still inside it (the GPU side is rebuilt); moved
geometry builds it again in that frame. Measured update per moved frame at 160x90, light
(rooms_light_sweep) 12 ms, camera (sponza_camera_walk) 10 ms, geometry (cornell_spot_moving_block)
488 ms (`python -m studies.motion_costs`, 2 cores shared with other work).

Stress limit params:voxel_resolution=256: the voxelisation's exact-distance index samples every triangle half a voxel apart (voxels.SurfaceIndex): conference (331k triangles, 256 voxels along its longest side) needs 21.5M samples (2.5M at the default 64), and with their k-d tree and the voxel arrays the voxelisation exceeds the stress suite's 6 GiB per-case memory cap (MemoryError allocating 403 MiB); sibenik, cornell_box and the procedural scenes pass at 256
"""
from __future__ import annotations

import time
from collections import OrderedDict
from pathlib import Path

import moderngl
import numpy as np

from bench.gl import load_compute, load_program, set_uniforms
from bench.gl.context import LOOP_CHUNK, loop_chunks, park
from bench.protocol.method import FrameOutput, MethodBase, Param, SkipRow
from bench.gl.vpl import CLAMP_DOC, VPL_COUNT_DOC
from bench.gl.near_field import (NEAR_FIELD_DEFAULT, NEAR_FIELD_DOC, NEAR_FIELDS, NEAR_SCALE_DEFAULT,
                                   NEAR_SCALE_DOC, NEAR_SCALE_RANGE, near_field_defines)
from bench.gl.vpl import VPL_DEFINES, RsmVplSampler

from .gates import MAX_GATE_EDGES
from .topology import Topology, TopologyError, build_topology
from .voxels import DEFAULT_OCCUPANCY, OCCUPANCIES

SHADERS = Path(__file__).parent / "shaders"
TILE = 16            # clustered-shading screen tile (pixels); TILE^2 = the local sort's size
CLUSTER_BITS = 20    # geometry-cluster key: depth slice << CLUSTER_BITS | visibility cluster
LA_GROUP = 64
SLICE_NEAR_REL = 1e-2  # view depth of the first slice boundary, relative to the scene radius
GATE_DEFINES = dict(VPL_DEFINES, BINDING_GATES=7, BINDING_ADJ_RANGES=8, BINDING_ADJ_ENTRIES=9,
                    BINDING_VPL_CLUSTER=10, BINDING_GEO_CLUSTERS=11, BINDING_PIXEL_CLUSTER=12,
                    BINDING_CLUSTER_COUNT=13, BINDING_LIGHT_MASKS=14, TILE=TILE,
                    CLUSTER_BITS=CLUSTER_BITS, LA_GROUP=LA_GROUP, MAX_GATE_EDGES=MAX_GATE_EDGES)

_TOPOLOGY_CACHE: OrderedDict = OrderedDict()
_CACHE_SIZE = 4


def topology_seeds(scene) -> np.ndarray:
    """Points of the space light travels in: every camera eye and positional light."""
    points = [c.eye for c in scene.cameras.values()]
    points += [l.position for l in scene.lights if hasattr(l, "position")]
    return np.array(points, float).reshape(-1, 3)


def topology_key(scene, resolution: int, alpha_percent: float, merge_fraction: float,
                 merge_visible: float = 0.0, border_gates: bool = False, occupancy: str = DEFAULT_OCCUPANCY) -> tuple:
    return (scene.content_hash(), int(resolution), float(alpha_percent), float(merge_fraction), float(merge_visible),
            bool(border_gates), str(occupancy))


def scene_topology(scene, resolution: int, alpha_percent: float, merge_fraction: float,
                   merge_visible: float = 0.0, border_gates: bool = False,
                   occupancy: str = DEFAULT_OCCUPANCY) -> tuple[Topology, bool]:
    """The scene's topology (built, or from the small in-process cache) and whether it was cached."""
    key = topology_key(scene, resolution, alpha_percent, merge_fraction, merge_visible, border_gates, occupancy)
    if key in _TOPOLOGY_CACHE:
        _TOPOLOGY_CACHE.move_to_end(key)
        return _TOPOLOGY_CACHE[key], True
    topo = build_topology(scene.vertices, scene.faces, resolution, alpha_percent, merge_fraction,
                          topology_seeds(scene), scene.name, merge_visible, border_gates, occupancy)
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
    summary = "VPLs with visibility from empty-space topology: quasi-convex clusters joined by gate polygons"
    stages = ("vpl_sample", "geometry_clusters", "light_assignment", "gather")
    needs = frozenset({"gbuffer", "shadow_map", "direct", "rsm", "precompute"})
    ladder = ({"vpl_count": 256}, {}, {"vpl_count": 2048})
    params = {
        "vpl_count": Param(1024, VPL_COUNT_DOC, 1, 65536, quality=True, sweep=(64, 256, 1024, 4096)),
        "voxel_resolution": Param(64, "voxels along the scene's longest bounding-box side (precomputation)",
                                  16, 256, quality=True, sweep=(32, 64, 128)),
        "occupancy": Param(DEFAULT_OCCUPANCY, "voxelization (precomputation): touch, a voxel is occupied when its "
                                              "cube meets a triangle; sphere, when its centre is within sqrt(3)/2 "
                                              "voxel of one (thicker)", choices=OCCUPANCIES),
        "alpha_percent": Param(20.0, "skeleton nodes join a visibility cluster when their maximal-ball radius "
                                     "is within alpha % of the cluster's largest", 0.0, 1000.0),
        "merge_gate_fraction": Param(0.75, "clusters joined by a gate at least this fraction as wide as the smaller "
                                          "cluster's largest maximal ball are merged (above 1: never)", 0.0, 2.0),
        "merge_visible_fraction": Param(0.5, "a merge also needs this fraction of the straight segments between "
                                             "the two clusters' skeleton nodes inside the empty space (the merged "
                                             "cluster stays quasi-convex; 0: no test)", 0.0, 1.0),
        "border_gates": Param(False, "every patch of the clusters' borders no skeleton gate covers gets gates of "
                                     "its own (false: the skeleton edges' gates only, the paper's)"),
        "gate_radius_scale": Param(1.0, "gate size multiplier (1: the polygon of the opening, or the maximal-ball "
                                        "disk in open space; 0: no light crosses gates)", 0.0, 8.0),
        "gate_hops": Param(4, "gates a VPL's light may cross on its way to a pixel (1: into a neighbouring "
                              "cluster only, paper Fig. 11)", 1, 16),
        "use_gates": Param(True, "false: indirect light stays inside visibility clusters (paper VI.B)"),
        "depth_slices": Param(16, "clustered-shading depth slices, exponential in view depth", 1, 256),
        "clamp_distance_rel": Param(1e-4, CLAMP_DOC, 1e-7, 1.0),
        "near_field": Param(NEAR_FIELD_DEFAULT, NEAR_FIELD_DOC, choices=NEAR_FIELDS),
        "near_field_scale": Param(NEAR_SCALE_DEFAULT, NEAR_SCALE_DOC, *NEAR_SCALE_RANGE),
    }

    @classmethod
    def cost_terms(cls, params, size):
        return {"pixel_vpls": size.pixels * params["vpl_count"],          # gated gather
                "voxels": params["voxel_resolution"] ** 3}                # the topology of empty space

    def update(self, gpu, scene, facts, params, view, changes) -> None:
        """A scene in motion (bench.run.sequence). The topology of empty space depends on the
        geometry, and on which empty space holds the eyes and lights (its seeds): it is kept when
        only cameras or lights moved and every eye and positional light is still inside one of its
        clusters (registered for the frame's scene, so preparing again finds it and rebuilds only
        the GPU side: the view's slices, the gate buffers); moved geometry, or a seed that left the
        empty space it describes, builds it again inside the frame (its cost is the frame's)."""
        if "geometry" not in changes and np.all(self.topology.cluster_of(topology_seeds(scene)) >= 0):
            key = topology_key(scene, params["voxel_resolution"], params["alpha_percent"],
                               params["merge_gate_fraction"], params["merge_visible_fraction"],
                               params["border_gates"], params["occupancy"])
            _TOPOLOGY_CACHE[key] = self.topology
        super().update(gpu, scene, facts, params, view, changes)

    def prepare(self, gpu, scene, facts, params, view) -> None:
        self.params = params
        t0 = time.perf_counter()
        try:
            topo, cached = scene_topology(scene, params["voxel_resolution"], params["alpha_percent"],
                                          params["merge_gate_fraction"], params["merge_visible_fraction"],
                                          params["border_gates"], params["occupancy"])
        except TopologyError as exc:
            raise SkipRow(str(exc)) from None
        if topo.cluster_count >= 1 << CLUSTER_BITS:
            raise SkipRow(f"scene '{scene.name}': {topo.cluster_count} visibility clusters, over the "
                          f"{1 << CLUSTER_BITS} the geometry-cluster key holds")
        self.topology = topo
        self.info = {"precompute_s": time.perf_counter() - t0, "precompute_cached": cached,
                     "visibility_clusters": topo.cluster_count, "gates": int(len(topo.gate_radius)),
                     "greedy_clusters": topo.greedy_cluster_count, "closed_by_box": topo.closed_by_box,
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
        gs = topo.gates
        g = len(gs.radius)
        gates = np.zeros((max(g, 1), 4 + MAX_GATE_EDGES, 4), np.float32)  # Gate of topology.glsl
        gates[:g, 0, :3] = gs.centre - gpu.origin
        gates[:g, 0, 3] = gs.radius
        gates[:g, 1, :3] = gs.normal
        gates[:g, 1, 3] = gs.count
        gates[:g, 2, :3] = gs.axis_u
        gates[:g, 3, :2] = gs.sides.astype(np.int32).view(np.float32)
        gates[:g, 4:, :3] = gs.halfplanes
        ranges, table = adjacency_arrays(topo)
        self.gates = ctx.buffer(gates.tobytes())
        self.adj_ranges = ctx.buffer(ranges.tobytes())
        self.adj_entries = ctx.buffer(table.tobytes())
        max_degree = int((ranges[:, 1] - ranges[:, 0]).max(initial=0))
        # llvmpipe's loop limit counts the gate walk of every VPL too, each gate's edge loop
        # included (bench.gl.context.LOOP_CHUNK): a draw sums whole words of 32 VPLs, or part of
        # one word when a word's walks alone would pass the limit
        per_vpl = 1 + params["gate_hops"] * (1 + max_degree * (1 + MAX_GATE_EDGES))
        if per_vpl > LOOP_CHUNK:
            raise SkipRow(f"scene '{scene.name}': gate_hops={params['gate_hops']} with clusters of {max_degree} "
                          f"gates needs {per_vpl} shader loop iterations per VPL, over {LOOP_CHUNK}")
        chunk_vpls = LOOP_CHUNK // per_vpl
        if chunk_vpls >= 32:
            self.draws = [(first, end, 0xFFFFFFFF) for first, end in loop_chunks(self.words, chunk_vpls // 32)]
        else:
            self.draws = [(w, w + 1, ((1 << end) - 1) & ~((1 << first) - 1))
                          for w in range(self.words) for first, end in loop_chunks(32, chunk_vpls)]

        tiles = ((self.width + TILE - 1) // TILE, (self.height + TILE - 1) // TILE)
        self.tiles = tiles
        capacity = tiles[0] * tiles[1] * TILE * TILE  # at most one geometry cluster per pixel
        self.vpl_cluster = ctx.buffer(reserve=self.vpl_count * 4)
        self.geo_clusters = ctx.buffer(reserve=capacity * 32)
        self.pixel_cluster = ctx.buffer(reserve=self.width * self.height * 4)
        self.cluster_count = ctx.buffer(reserve=16)
        self.light_masks = ctx.buffer(reserve=capacity * self.words * 4)

        defines = dict(GATE_DEFINES, DEPTH_SLICES=params["depth_slices"], GATE_HOPS=params["gate_hops"],
                       **near_field_defines(params["near_field"], params["near_field_scale"]))
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
            for first, end, bits in self.draws:
                set_uniforms(self.gather, u_word_first=first, u_word_end=end, u_bit_mask=bits)
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
