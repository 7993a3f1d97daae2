"""`ir_shadowed`: instant radiosity with indirect visibility (Keller 1997): the VPLs of
`ir_unshadowed` (drawn from the reflective shadow map, Dachsbacher & Stamminger 2005), each
with a low-resolution hemicube shadow map.

Per frame:

1. `vpl_sample`: the same N VPLs as `ir_unshadowed` (same code, `bench/gl/vpl.py`, same random
   numbers: for a given seed and frame both methods use identical VPLs), importance sampled by
   flux luminance from the RSM with an exact integer CDF (see `ir_unshadowed`'s manual).
2. `vpl_shadow_maps`: every VPL's hemicube (5 faces of a cube aligned with the VPL normal:
   front and four sides; the VPL emits nothing behind its plane) into one atlas of
   `shadow_resolution`^2 tiles, N x 5 faces. The scene is cut into clusters of 64 nearby
   triangles (Morton order); a compute pass keeps, for each face, the clusters whose bounding
   sphere is not wholly outside its frustum, and one multi-draw renders each cluster instanced
   into the faces that kept it (clusters.py: the clip planes would drop the others' triangles
   whole, so the atlas is the one drawing every triangle into every face gives). The vertex
   shader projects with the face's 90-degree frustum, clips to it with gl_ClipDistance and
   maps clip space affinely into the tile; each texel keeps its nearest fragment's distance to
   the VPL and plane (RGBA32F, by a depth test on distance / far; `shadow_test=distance`: the
   smallest distance alone, MIN blending into R32F with no depth buffer).
   The hemicube's centre is lifted 1e-4 scene radii off the VPL's surface along its normal,
   so that surface (flat, or curving away) lands strictly below the side faces' horizon.
3. `gather`: `ir_unshadowed`'s sum (with its near field: each VPL's 1/d^2 bounded at the radius
   of the area it stands for, bench/gl/near_field.py; see ir_unshadowed's manual), each VPL
   term multiplied by its visibility: the receiver
   is offset along its geometric normal by `normal_offset` texel footprints (more at grazing
   angles) and compared with the stored distance plus one texel footprint, and (default
   `shadow_test=plane`) with the stored blocker's plane: blocked when the segment from the
   hemicube's centre crosses that plane before the receiver (no nearer than the stored point
   minus a texel footprint, so only the texel's own surface counts).

The gather is the unshadowed one compiled with the visibility test, term for term, so for the
same seed `ir_shadowed` <= `ir_unshadowed` at every pixel, and equal where nothing occludes
any VPL (an open box, the inside of a sphere). Visibility is resolved at hemicube resolution:
receivers within about a texel of a concave corner seen at a grazing angle from a VPL can lose
that VPL, and the normal offset lets light past an occluder's edge in a band about
`normal_offset` texels wide (it shrinks with the resolution). The hemicube pass draws each
triangle into the faces that may see it: its cost is proportional to N x triangles (on sponza
at 1024 VPLs 23% of the (cluster, face) pairs survive the culling).

Zero-thickness walls (`shadow_test`, issue #23): a shadow map's tolerance (here one texel
footprint, 3% of the distance at 64 texels) lets a receiver just past a zero-thickness wall pass
the distance test: the rooms scene's walls meet floor and ceiling edge to edge, and with the
distance test alone (`shadow_test=distance`, the earlier default) bands along those seams and the
door jambs received light the wall blocks, the error of this method where occlusion decides the
bounce (rooms/far, a room lit only through a door: relMSE 4.40 against the visible reference at
320 x 180, no indirect 0.59; rooms/main 3.06, no indirect 0.49). Each texel therefore also keeps
its nearest fragment's plane (the hemicube pass takes a depth test on distance instead of MIN
blending, so the record is one fragment's), and a receiver behind that plane is blocked: a
receiver past a wall whose texel holds the wall is behind the wall's plane however close it is.
The receiver's own surface never blocks it (the normal offset puts it on the VPL's side of its
own plane, exactly, where the distance test needs its tolerance). Measured at the defaults
(NOTES.md): rooms/far 4.40 -> 0.30, rooms/main 3.06 -> 0.079, holodeck 0.034 -> 0.029, the other
procedural views and cornell_box within 1%.

Defaults on the real scenes (issue #23; NOTES.md "1024 VPLs and a quarter-texel offset"):
`vpl_count` 1024 (was 256; ir_unshadowed's count, so that at the defaults the two methods sum
the same VPLs): on sponza 256 VPLs are the worst rung over six seeds (relMSE against the visible
reference 1.05 at 64, 2.23 at 256, 0.34 at 1024: at 64 the near-field bound of the few large VPLs
darkens the bounce, mean 0.70, and hides their splotches; at 256 the bound no longer darkens, mean
0.98, but a few VPLs still light whole arches). `normal_offset` 0.25 texels (was 0.5): the offset
receiver sees past an occluder's edge in a band that wide (rooms' door jambs: leaked light 0.113
-> 0.084 of the truly visible light at 96 x 72), and 0.25 is lower or equal on every view measured
(rooms/far -1/3 over three seeds, holodeck 0.029 -> 0.013), while 0.1 and 0 bring back acne. The
shadow-map pass discards fragments outside their own tile: a huge triangle through a VPL's
position, clipped near the hemicube's centre where float rounding of x / w reaches a texel, could
land its tiny distances in the neighbouring tile's border row or column, a false blocker (an
open box at 1024 VPLs lost 0.13% of its light in 13% of its pixels; now 0.005%).

Parameters:

<!-- parameters: generated from the Param declarations by `gibench manuals --write` -->
| parameter          | default   | range                          | meaning |
|--------------------|-----------|--------------------------------|---|
| vpl_count          | 1024      | 1 .. 8192                      | VPLs drawn from the RSM per frame (importance sampled by flux luminance, stratified) (quality knob; sweep 64, 256, 1024, 4096) |
| shadow_resolution  | 64        | 8 .. 512                       | hemicube face resolution of each VPL's shadow map (texels) (quality knob; sweep 32, 64, 128) |
| normal_offset      | 0.25      | 0.0 .. 16.0                    | receiver offset along its geometric normal for the VPL shadow test, in hemicube texel footprints at the receiver |
| shadow_test        | plane     | distance, plane                | VPL shadow test: distance, the receiver's distance against the stored one plus a texel footprint; plane, also blocked behind the stored blocker's plane (a zero-thickness wall within a footprint) |
| clamp_distance_rel | 0.0001    | 1e-07 .. 1.0                   | distance clamp eps of max(eps, distance) relative to the scene radius (tames the 1/d^2 singularity) |
| near_field         | footprint | clamp, disc_element, footprint | how an emitter's 1/d^2 is bounded near it, d the emitter-receiver distance, A the area it stands for: clamp max(eps, d)^2; disc_element d^2 + A / pi (a disc's form factor); footprint max(d^2, s A / pi) (a clamp at the radius of s times the emitter's area); each at least eps^2 |
| near_field_scale   | 1.0       | 0.001 .. 100.0                 | s of near_field=footprint: the clamp's area as a fraction of the area the emitter stands for |
| max_triangle_draws | 400000000 | 1 .. 10000000000               | skip the row when vpl_count x triangles exceeds this (the hemicubes draw the scene once per VPL every frame) |
<!-- end of parameters -->

The atlas holds vpl_count x 5 tiles of shadow_resolution^2 texels (RGBA32F and a 32-bit depth
buffer with `shadow_test=plane`, 20 bytes a texel: 420 MB at the defaults, 1.7 GB at 4096 VPLs;
R32F with `distance`); a combination larger than the GL's maximum texture size is refused with an
error naming both parameters.

Quality ladder (`gibench run`): vpl_count 256, 1024 (default), 4096, `ir_unshadowed`'s, so that
on every rung the two methods sum the same VPLs; one shadow map per VPL makes the cost linear in
the count. Cost guard: every frame draws the scene into every VPL's hemicube, vpl_count x
triangles triangle draws (before the culling); a row above `max_triangle_draws` (default 4e8,
about a minute a frame on the 2-core llvmpipe host: at 1024 VPLs sponza's 66k triangles take
15-20 s a frame, conference's 331k 47-55 s, lost_empire's 225k 61 s; the 4096 rung runs on sponza and
sibenik, not on conference and lost_empire) is skipped with that figure rather than run for
minutes.

Example:

    gibench run --scenes rooms --methods ir_shadowed --res 160x120 --defaults-only
    gibench run --scenes rooms --methods ir_shadowed --param ir_shadowed.shadow_resolution=64,128

Stages: `vpl_sample`, `vpl_shadow_maps`, `gather` (after the shared `gbuffer_shadow`,
`direct_light`, `rsm`). Needs: gbuffer, shadow_map, direct, rsm.

In motion (bench.run.sequence): It keeps nothing between states: a frame where anything moved
prepares it again (programs, the hemicube atlas); the VPL shadow maps are drawn every frame anyway.
Measured update per moved frame at 160x90, light (rooms_light_sweep) 21 ms, camera
(sponza_camera_walk) skipped, geometry (cornell_spot_moving_block) 42 ms (`python -m
studies.motion_costs`, 2 cores shared with other work; measured at the earlier defaults, 256 VPLs
and a guard of 1e7).

Stress limit params:shadow_resolution=512: 1024 VPLs x 5 hemicube faces of 512^2 need a 36864^2 atlas, larger than GL_MAX_TEXTURE_SIZE (16384 on llvmpipe); prepare() refuses it with one line naming both parameters.
"""
from __future__ import annotations

import math
from pathlib import Path

import moderngl

from bench.gl import load_program, set_uniforms
from bench.gl.context import park
from bench.protocol.method import FrameOutput, MethodBase, Param, ParamError, SkipRow
from bench.gl.vpl import CLAMP_DOC, VPL_COUNT_DOC
from bench.gl.near_field import (NEAR_FIELD_DEFAULT, NEAR_FIELD_DOC, NEAR_FIELDS, NEAR_SCALE_DEFAULT,
                                   NEAR_SCALE_DOC, NEAR_SCALE_RANGE, near_field_defines)
from bench.gl.vpl import VPL_DEFINES, RsmVplSampler, VplGather
from .clusters import CLUSTER_TRIANGLES, ClusteredScene

SHADERS = Path(__file__).parent / "shaders"
HEMICUBE_FACES = 5  # front + 4 sides; injected into the shaders as a #define
SHADOW_DEFINES = dict(VPL_DEFINES, HEMICUBE_FACES=HEMICUBE_FACES)
GL_CLIP_DISTANCE0 = 0x3000
FAR_SCALE = 2.02     # hemicube far plane / scene radius: no two scene points are further apart than 2R
NEAR_SCALE = 1e-5    # near plane / scene radius
LIFT_SCALE = 1e-4    # hemicube centre above the VPL's surface / scene radius (>> float32 rounding)
PLANE_TOLERANCE = 1e-4  # shadow_test=plane: a receiver blocks behind a plane by more than this share of its distance
SHADOW_TESTS = ("distance", "plane")


class HemicubeAtlas:
    """Hemicube shadow maps of all VPLs: one R32F atlas (with `plane`, an RGBA32F atlas of
    (distance, blocker plane) and a depth buffer on distance / far), rendered in one multi-draw of
    the scene's triangle clusters, each instanced into the faces whose frustum it may reach
    (clusters.py)."""

    def __init__(self, gpu, vpl_count: int, resolution: int, plane: bool = False,
                 cluster_triangles: int = CLUSTER_TRIANGLES):
        ctx = gpu.ctx
        self.gpu, self.vpl_count, self.resolution = gpu, int(vpl_count), int(resolution)
        tiles = self.vpl_count * HEMICUBE_FACES
        self.tiles_x = math.ceil(math.sqrt(tiles))
        self.tiles_y = math.ceil(tiles / self.tiles_x)
        size = (self.tiles_x * self.resolution, self.tiles_y * self.resolution)
        max_size = int(ctx.info["GL_MAX_TEXTURE_SIZE"])
        if max(size) > max_size:
            raise ParamError(f"method 'ir_shadowed': vpl_count={vpl_count} x shadow_resolution={resolution} "
                             f"needs a {size[0]}x{size[1]} hemicube atlas, over GL_MAX_TEXTURE_SIZE={max_size}")
        self.plane = bool(plane)
        self.atlas = ctx.texture(size, 4 if self.plane else 1, dtype="f4")
        self.atlas.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.depth = ctx.depth_texture(size) if self.plane else None
        self.fbo = ctx.framebuffer([self.atlas], self.depth)
        self.defines = dict(SHADOW_DEFINES, PLANE_TEST=int(self.plane), PLANE_TOLERANCE=PLANE_TOLERANCE)
        self.program = load_program(ctx, SHADERS / "vpl_shadow_maps.glsl", self.defines)
        self.scene = ClusteredScene(gpu, self.program, self.defines, self.vpl_count * HEMICUBE_FACES,
                                    cluster_triangles)
        self.near, self.far = NEAR_SCALE * gpu.radius, FAR_SCALE * gpu.radius
        self.lift = LIFT_SCALE * gpu.radius

    def render(self, sampler: RsmVplSampler) -> None:
        ctx = self.gpu.ctx
        sampler.bind()
        self.scene.cull(self.set_uniforms)   # clusters wholly outside a face's frustum skip that face
        self.fbo.use()
        ctx.viewport = (0, 0, self.atlas.width, self.atlas.height)
        ctx.scissor = None
        self.fbo.clear(3.0e38, 0.0, 0.0, 0.0, depth=1.0)
        if self.plane:   # the nearest fragment's whole record: a depth test, not per-channel MIN
            ctx.enable_only(moderngl.DEPTH_TEST)
            ctx.depth_func = "<"
        else:
            ctx.enable_only(moderngl.BLEND)
            ctx.blend_equation = moderngl.MIN
        for i in range(4):
            ctx.enable_direct(GL_CLIP_DISTANCE0 + i)
        self.set_uniforms(self.program)
        set_uniforms(self.program, u_near=self.near, u_far=self.far)
        self.scene.draw()
        for i in range(4):
            ctx.disable_direct(GL_CLIP_DISTANCE0 + i)
        ctx.blend_equation = moderngl.FUNC_ADD
        ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST)

    def set_uniforms(self, program) -> None:
        set_uniforms(program, u_hemicube_tiles_x=self.tiles_x, u_hemicube_tiles_y=self.tiles_y,
                     u_hemicube_resolution=self.resolution, u_hemicube_lift=self.lift)

    def bind(self, program, unit: int) -> int:
        self.atlas.use(unit)
        set_uniforms(program, u_hemicube_atlas=unit)
        self.set_uniforms(program)
        return unit + 1

    def release(self) -> None:
        park(self.gpu.ctx)
        for obj in (self.fbo, self.atlas, self.depth, self.program, self.scene):
            if obj is not None:
                obj.release()


class InstantRadiosityShadowed(MethodBase):
    name = "ir_shadowed"
    summary = "Instant radiosity, RSM-sampled VPLs with hemicube shadow maps (indirect visibility)"
    ladder = ({"vpl_count": 256}, {}, {"vpl_count": 4096})   # ir_unshadowed's: the same VPLs on every rung
    stages = ("vpl_sample", "vpl_shadow_maps", "gather")
    needs = frozenset({"gbuffer", "shadow_map", "direct", "rsm"})
    params = {
        "vpl_count": Param(1024, VPL_COUNT_DOC, 1, 8192, quality=True, sweep=(64, 256, 1024, 4096)),
        "shadow_resolution": Param(64, "hemicube face resolution of each VPL's shadow map (texels)", 8, 512,
                                   quality=True, sweep=(32, 64, 128)),
        "normal_offset": Param(0.25, "receiver offset along its geometric normal for the VPL shadow test, "
                                    "in hemicube texel footprints at the receiver", 0.0, 16.0),
        "shadow_test": Param("plane", "VPL shadow test: distance, the receiver's distance against the "
                                         "stored one plus a texel footprint; plane, also blocked behind the "
                                         "stored blocker's plane (a zero-thickness wall within a footprint)",
                             choices=SHADOW_TESTS),
        "clamp_distance_rel": Param(1e-4, CLAMP_DOC, 1e-7, 1.0),
        "near_field": Param(NEAR_FIELD_DEFAULT, NEAR_FIELD_DOC, choices=NEAR_FIELDS),
        "near_field_scale": Param(NEAR_SCALE_DEFAULT, NEAR_SCALE_DOC, *NEAR_SCALE_RANGE),
        "max_triangle_draws": Param(400_000_000, "skip the row when vpl_count x triangles exceeds this (the "
                                                "hemicubes draw the scene once per VPL every frame)",
                                    1, 10_000_000_000),
    }

    @classmethod
    def cost_terms(cls, params, size):
        vpls = params["vpl_count"]
        if vpls * size.triangles > params["max_triangle_draws"]:
            return None   # prepare skips the row (its guard)
        return {"pixel_vpls": size.pixels * vpls,                              # the gather
                "vpl_triangles": vpls * size.triangles,                       # a hemicube of the scene per VPL
                "vpl_shadow_texels": vpls * params["shadow_resolution"] ** 2}  # and its texels

    def prepare(self, gpu, scene, facts, params, view) -> None:
        self.params = params
        draws = int(params["vpl_count"]) * int(gpu.triangle_count)
        if draws > params["max_triangle_draws"]:
            raise SkipRow(f"scene '{scene.name}': {params['vpl_count']} VPL shadow maps x {gpu.triangle_count} "
                          f"triangles = {draws:,d} triangle draws per frame, over max_triangle_draws="
                          f"{params['max_triangle_draws']:,d}")
        self.ctx = gpu.ctx
        self.eps = params["clamp_distance_rel"] * gpu.radius
        self.hemicubes = HemicubeAtlas(gpu, params["vpl_count"], params["shadow_resolution"],
                                       plane=params["shadow_test"] == "plane")
        self.sampler = RsmVplSampler(gpu.ctx, params["vpl_count"])
        self.gather = VplGather(gpu.ctx, view.width, view.height, SHADERS / "gather.glsl",
                                 dict(self.hemicubes.defines, VPL_SHADOWS=1,
                                      **near_field_defines(params["near_field"], params["near_field_scale"])))

    def _bind_visibility(self, program, unit: int) -> int:
        set_uniforms(program, u_normal_offset=float(self.params["normal_offset"]))
        return self.hemicubes.bind(program, unit)

    def render(self, frame, prof) -> FrameOutput:
        passes = frame.passes
        with prof.stage("vpl_sample"):
            self.sampler.sample(passes.rsm, frame.random_u32(0))
        with prof.stage("vpl_shadow_maps"):
            self.hemicubes.render(self.sampler)
        with prof.stage("gather"):
            self.gather.render(passes.gbuffer, self.sampler, self.eps, bind_extra=self._bind_visibility)
        return FrameOutput(direct=passes.direct.radiance, indirect=self.gather.indirect)

    def release(self) -> None:
        for name in ("gather", "sampler", "hemicubes"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.release()
                setattr(self, name, None)
