"""`ir_shadowed`: instant radiosity with indirect visibility (Keller 1997): the VPLs of
`ir_unshadowed` (drawn from the reflective shadow map, Dachsbacher & Stamminger 2005), each
with a low-resolution hemicube shadow map.

Per frame:

1. `vpl_sample`: the same N VPLs as `ir_unshadowed` (same code, `bench/gl/vpl.py`, same random
   numbers: for a given seed and frame both methods use identical VPLs), importance sampled by
   flux luminance from the RSM with an exact integer CDF (see `ir_unshadowed`'s manual).
2. `vpl_shadow_maps`: every VPL's hemicube (5 faces of a cube aligned with the VPL normal:
   front and four sides; the VPL emits nothing behind its plane) in one instanced draw of the
   scene, N x 5 instances into one R32F atlas of `shadow_resolution`^2 tiles. The vertex
   shader projects with the face's 90-degree frustum, clips to it with gl_ClipDistance and
   maps clip space affinely into the tile; each texel keeps the smallest distance to the VPL
   (MIN blending, no depth buffer, so the test does not depend on depth-buffer precision).
   The hemicube's centre is lifted 1e-4 scene radii off the VPL's surface along its normal,
   so that surface (flat, or curving away) lands strictly below the side faces' horizon.
3. `gather`: `ir_unshadowed`'s sum (with its near field: each VPL's 1/d^2 bounded at the radius
   of the area it stands for, bench/gl/near_field.py; see ir_unshadowed's manual), each VPL
   term multiplied by its visibility: the receiver
   is offset along its geometric normal by `normal_offset` texel footprints (more at grazing
   angles) and compared with the stored distance plus one texel footprint.

The gather is the unshadowed one compiled with the visibility test, term for term, so for the
same seed `ir_shadowed` <= `ir_unshadowed` at every pixel, and equal where nothing occludes
any VPL (an open box, the inside of a sphere). Visibility is resolved at hemicube resolution:
receivers within about a texel of a concave corner seen at a grazing angle from a VPL can lose
that VPL, and the normal offset lets light past an occluder's edge in a band about
`normal_offset` texels wide (it shrinks with the resolution). The hemicube pass draws the scene
N x 5 times: its cost is proportional to N x triangles.

Leaks at the seams of thin walls: a receiver just past a zero-thickness wall (the rooms scene's
walls meet floor and ceiling edge to edge) is within one texel footprint of the wall in the
VPL's hemicube and passes the test, so bands along those seams and door jambs receive light
the wall blocks. It is the error of this method where occlusion decides the bounce (rooms/far,
a room lit only through a door); it falls as `shadow_resolution` grows, for a frame that costs
more. The default stays at 64 (the error per millisecond is better at 64 wherever no thin wall
decides the bounce); `--param ir_shadowed.shadow_resolution=128` lowers the seam error (NOTES.md
has the measurements).

Parameters:

<!-- parameters: generated from the Param declarations by `gibench manuals --write` -->
| parameter          | default   | range                          | meaning |
|--------------------|-----------|--------------------------------|---|
| vpl_count          | 256       | 1 .. 8192                      | VPLs drawn from the RSM per frame (importance sampled by flux luminance, stratified) (quality knob; sweep 16, 64, 256, 1024) |
| shadow_resolution  | 64        | 8 .. 512                       | hemicube face resolution of each VPL's shadow map (texels) (quality knob; sweep 32, 64, 128) |
| normal_offset      | 0.5       | 0.0 .. 16.0                    | receiver offset along its geometric normal for the VPL shadow test, in hemicube texel footprints at the receiver |
| clamp_distance_rel | 0.0001    | 1e-07 .. 1.0                   | distance clamp eps of max(eps, distance) relative to the scene radius (tames the 1/d^2 singularity) |
| near_field         | footprint | clamp, disc_element, footprint | how an emitter's 1/d^2 is bounded near it, d the emitter-receiver distance, A the area it stands for: clamp max(eps, d)^2; disc_element d^2 + A / pi (a disc's form factor); footprint max(d^2, s A / pi) (a clamp at the radius of s times the emitter's area); each at least eps^2 |
| near_field_scale   | 1.0       | 0.001 .. 100.0                 | s of near_field=footprint: the clamp's area as a fraction of the area the emitter stands for |
| max_triangle_draws | 10000000  | 1 .. 10000000000               | skip the row when vpl_count x triangles exceeds this (the hemicubes draw the whole scene once per VPL every frame) |
<!-- end of parameters -->

The atlas holds vpl_count x 5 tiles of shadow_resolution^2 texels; a combination larger than
the GL's maximum texture size is refused with an error naming both parameters.

Quality ladder (`gibench run`): vpl_count 64, 256 (default), 1024 (VAL's VPL count); one shadow map
per VPL makes the cost linear in the count, so 4096 (seconds per frame here) is left to `--param`.
Cost guard: every frame draws the whole scene into every VPL's hemicube, vpl_count x triangles
triangle draws; a row above `max_triangle_draws` (default 1e7) is skipped with that figure
rather than run for minutes.

Example:

    gibench run --scenes rooms --methods ir_shadowed --res 160x120 --defaults-only
    gibench run --scenes rooms --methods ir_shadowed --param ir_shadowed.shadow_resolution=64,128

Stages: `vpl_sample`, `vpl_shadow_maps`, `gather` (after the shared `gbuffer_shadow`,
`direct_light`, `rsm`). Needs: gbuffer, shadow_map, direct, rsm.

In motion (bench.run.sequence): It keeps nothing between states: a frame where anything moved
prepares it again (programs, the hemicube atlas); the VPL shadow maps are drawn every frame anyway.
Measured update per moved frame at 160x90, light (rooms_light_sweep) 21 ms, camera
(sponza_camera_walk) skipped, geometry (cornell_spot_moving_block) 42 ms (`python -m
studies.motion_costs`, 2 cores shared with other work).

Stress limit params:shadow_resolution=512: 256 VPLs x 5 hemicube faces of 512^2 need an 18432^2 atlas, larger than GL_MAX_TEXTURE_SIZE (16384 on llvmpipe); prepare() refuses it with one line naming both parameters.
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

SHADERS = Path(__file__).parent / "shaders"
HEMICUBE_FACES = 5  # front + 4 sides; injected into the shaders as a #define
SHADOW_DEFINES = dict(VPL_DEFINES, HEMICUBE_FACES=HEMICUBE_FACES)
GL_CLIP_DISTANCE0 = 0x3000
FAR_SCALE = 2.02     # hemicube far plane / scene radius: no two scene points are further apart than 2R
NEAR_SCALE = 1e-5    # near plane / scene radius
LIFT_SCALE = 1e-4    # hemicube centre above the VPL's surface / scene radius (>> float32 rounding)


class HemicubeAtlas:
    """Hemicube shadow maps of all VPLs: one R32F atlas, rendered in one instanced draw."""

    def __init__(self, gpu, vpl_count: int, resolution: int):
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
        self.atlas = ctx.texture(size, 1, dtype="f4")
        self.atlas.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.fbo = ctx.framebuffer([self.atlas])
        self.program = load_program(ctx, SHADERS / "vpl_shadow_maps.glsl", SHADOW_DEFINES)
        self.vao = gpu.vertex_array(self.program)
        self.near, self.far = NEAR_SCALE * gpu.radius, FAR_SCALE * gpu.radius
        self.lift = LIFT_SCALE * gpu.radius

    def render(self, sampler: RsmVplSampler) -> None:
        ctx = self.gpu.ctx
        self.fbo.use()
        ctx.viewport = (0, 0, self.atlas.width, self.atlas.height)
        ctx.scissor = None
        self.fbo.clear(3.0e38, 0.0, 0.0, 0.0)
        ctx.enable_only(moderngl.BLEND)
        ctx.blend_equation = moderngl.MIN
        for i in range(4):
            ctx.enable_direct(GL_CLIP_DISTANCE0 + i)
        sampler.bind()
        self.set_uniforms(self.program)
        set_uniforms(self.program, u_near=self.near, u_far=self.far)
        self.vao.render(moderngl.TRIANGLES, instances=self.vpl_count * HEMICUBE_FACES)
        for i in range(4):
            ctx.disable_direct(GL_CLIP_DISTANCE0 + i)
        ctx.blend_equation = moderngl.FUNC_ADD
        ctx.disable(moderngl.BLEND)

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
        for obj in (self.fbo, self.atlas, self.program):
            obj.release()


class InstantRadiosityShadowed(MethodBase):
    name = "ir_shadowed"
    summary = "Instant radiosity, RSM-sampled VPLs with hemicube shadow maps (indirect visibility)"
    ladder = ({"vpl_count": 64}, {}, {"vpl_count": 1024})
    stages = ("vpl_sample", "vpl_shadow_maps", "gather")
    needs = frozenset({"gbuffer", "shadow_map", "direct", "rsm"})
    params = {
        "vpl_count": Param(256, VPL_COUNT_DOC, 1, 8192, quality=True, sweep=(16, 64, 256, 1024)),
        "shadow_resolution": Param(64, "hemicube face resolution of each VPL's shadow map (texels)", 8, 512,
                                   quality=True, sweep=(32, 64, 128)),
        "normal_offset": Param(0.5, "receiver offset along its geometric normal for the VPL shadow test, "
                                    "in hemicube texel footprints at the receiver", 0.0, 16.0),
        "clamp_distance_rel": Param(1e-4, CLAMP_DOC, 1e-7, 1.0),
        "near_field": Param(NEAR_FIELD_DEFAULT, NEAR_FIELD_DOC, choices=NEAR_FIELDS),
        "near_field_scale": Param(NEAR_SCALE_DEFAULT, NEAR_SCALE_DOC, *NEAR_SCALE_RANGE),
        "max_triangle_draws": Param(10_000_000, "skip the row when vpl_count x triangles exceeds this (the "
                                                "hemicubes draw the whole scene once per VPL every frame)",
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
        self.hemicubes = HemicubeAtlas(gpu, params["vpl_count"], params["shadow_resolution"])
        self.sampler = RsmVplSampler(gpu.ctx, params["vpl_count"])
        self.gather = VplGather(gpu.ctx, view.width, view.height, SHADERS / "gather.glsl",
                                 dict(SHADOW_DEFINES, VPL_SHADOWS=1,
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
