"""`manylights`: the one-bounce unshadowed many-lights sum over centroid VPLs (eq. 4 of the FLC paper).

Every triangle t is a VPL at y_t (its centroid, or a uniformly jittered point when
`jitter_frames` > 1) carrying the shadowed direct radiosity B = rho_t E(y_t). Each pixel x sums

    L(x) = rho_x / pi * sum_t L_t(y_t -> x) <n_x, xy>+ |<n_t, yx>| A(t) / max(eps, |x - y_t|)^2

with no indirect visibility. It computes eq. 4's sum exactly, which is exact *for its VPL model*
(one VPL at each triangle's centroid), not the continuous integral Mitsuba's unshadowed
reference computes: the centroid rule's discretisation error is large on big triangles. On
big_floor (floor and wall of 2 huge triangles, a spot lighting a disc no centroid lies in) the
centroid sum is 0 (`test_centroid_vpls_miss_a_small_spot_and_jitter_converges`; NOTES.md has
issue #11's user scene). With `jitter_frames` J > 1 each frame puts every VPL at an independent
uniform point of its triangle and the J frames are averaged inside one render: an unbiased
estimate of the continuous integral, converging to it as J grows (noise ~ 1/sqrt(J), large
where a small lit region lies on a big triangle). Compare both with the Mitsuba reference
before trusting either on a scene of large triangles.

Emitter convention (Mitsuba's `twosided` diffuse with shading normals): E(y_t) takes its
cosine against the shading normal at y_t (the vertex normals interpolated there, normalised),
the VPL emits towards x the B of the side of that shading normal x is on, and the geometric
term's |<n_t, yx>| uses the face normal n_t; the receiver's <n_x, xy>+ uses its shading normal
(the GBuffer's). The shadow-map offset follows the face normal. The `flc` lobe's cosine is the
face normal's (FLC eq. 6 has no shading frame).

The VPL's emission model is a parameter:

| emission | L_t(w)                          | what estimates it without bias             |
|----------|---------------------------------|--------------------------------------------|
| lambert  | rho_t E / pi                    | Mitsuba's unshadowed one-bounce reference  |
| flc      | rho_t E 3/(2 pi) <n_t, w>+      | Forward Light Cuts (eq. 6)                 |

Both conserve energy: the cosine-weighted integral of L_t over the hemisphere is rho_t E.
Surfaces are two-sided (as Mitsuba's `twosided` diffuse): a VPL emits on each side the light
that side receives. The cost is O(pixels x triangles x J): a yardstick baseline, slow. The
gather is split into draws of 16k VPLs (llvmpipe's per-invocation loop cap).

Parameters:

<!-- parameters: generated from the Param declarations by `gibench manuals --write` -->
| parameter     | default | range          | meaning |
|---------------|---------|----------------|---|
| emission      | lambert | lambert, flc   | VPL emission lobe: lambert rho E / pi (Mitsuba's), flc rho E 3/(2 pi) <n_t, w>+ (FLC eq. 6) |
| jitter_frames | 1       | 1 .. 4096      | VPL position samples per triangle (1: centroid, eq. 4's VPL model; > 1: uniform jitter, converges to the continuous integral) (quality knob; sweep 1, 4, 16, 64) |
| eps_rel       | 0.0001  | 1e-07 .. 1.0   | distance clamp eps relative to the scene radius |
| max_triangles | 2000000 | 1 .. 100000000 | skip (recorded as skipped) a scene with more triangles: the cost is pixels x triangles |
<!-- end of parameters -->

Example (the centroid sum, then the jittered one, unbiased for Mitsuba's reference):

    gibench run --scenes big_floor --methods manylights --res 64x48 --defaults-only
    gibench run --scenes big_floor --methods manylights --res 64x48 --param manylights.jitter_frames=16

Stages: `vpl_irradiance` (compute: every triangle's VPL and its shadowed radiosity), `gather`
(full screen, every VPL at every pixel). Needs: gbuffer, shadow_map, direct. NOTES.md holds the
measurements.

In motion (bench.run.sequence): It keeps nothing between states: a frame where anything moved
prepares it again (the per-triangle emitter records). Measured update per moved frame at 160x90,
light (rooms_light_sweep) 7 ms, camera (sponza_camera_walk) skipped, geometry
(cornell_spot_moving_block) 5 ms (`python -m studies.motion_costs`, 2 cores shared with other work).

Stress limit params:jitter_frames=4096: 4096 jittered VPL sets summed in one frame by design (the converged reference of the jittered sum), 4096 x the default frame's work: minutes per frame on llvmpipe, over the stress case timeout (hidden_bounce 64x48: over 300 s; big_floor, sphere_inside: over 120 s).
Stress limit coplanar: a second triangle coincident with part of another is a second emitter in the sum over triangles (eq. 4 of the FLC paper, this method's definition) while Mitsuba's rays see one surface: that area emits twice (cornell_box 64x48: mean +7.8%, indirect +20%).
Stress limit t_junction: the sum puts one VPL at each triangle's centroid (jittered only with jitter_frames > 1), so re-triangulating a surface moves VPLs; next to corners the 1/d^2 term turns that into visible changes (cornell_box 64x48: indirect 8.7%, mean -2.2%; conference 64x48, whose 32 split hosts are drawn by area, i.e. its largest walls and ceiling triangles, each one VPL: indirect 45%, mean +7.9%). It is a different discretisation of the same surface, not an error of the sum.
"""
from __future__ import annotations

from pathlib import Path

import moderngl
import numpy as np

from bench.gl import load_compute, load_program, set_uniforms
from bench.gl.context import loop_chunks
from bench.protocol.method import FrameOutput, MethodBase, Param, SkipRow

SHADERS = Path(__file__).parent / "shaders"
VPL_DEFINES = {"BINDING_VPL_TRIANGLES": 3, "BINDING_VPLS": 4}
VPL_BYTES = 5 * 16  # std430 Vpl (vpl_triangles.glsl): five vec4


def triangle_records(gpu) -> np.ndarray:
    """std430 TriangleRecord per triangle: v0 (w = area), v1, v2 in re-centred float32, then the
    three vertex shading normals."""
    faces = gpu.faces.astype(np.int64)
    tri = gpu.positions[faces]  # (T, 3, 3)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    rec = np.zeros((len(tri), 6, 4), dtype=np.float32)
    rec[:, :3, :3] = tri
    rec[:, 0, 3] = area
    rec[:, 3:, :3] = gpu.normals[faces]
    return rec


class ManyLights(MethodBase):
    name = "manylights"
    summary = "FLC eq. 4 sum over centroid VPLs (one per triangle), unshadowed; jitter_frames > 1 converges to the integral"
    stages = ("vpl_irradiance", "gather")
    needs = frozenset({"gbuffer", "shadow_map", "direct"})
    params = {
        "emission": Param("lambert", "VPL emission lobe: lambert rho E / pi (Mitsuba's), flc rho E 3/(2 pi) <n_t, w>+ "
                                     "(FLC eq. 6)", choices=("lambert", "flc")),
        "jitter_frames": Param(1, "VPL position samples per triangle (1: centroid, eq. 4's VPL model; "
                               "> 1: uniform jitter, converges to the continuous integral)", 1, 4096,
                               quality=True, sweep=(1, 4, 16, 64)),
        "eps_rel": Param(1e-4, "distance clamp eps relative to the scene radius", 1e-7, 1.0),
        "max_triangles": Param(2_000_000, "skip (recorded as skipped) a scene with more triangles: the cost is "
                                          "pixels x triangles", 1, 100_000_000),
    }

    @classmethod
    def frames_identical(cls, params: dict) -> bool:
        return params["jitter_frames"] == 1   # centroid VPLs: no random stream; jittered ones draw anew each frame

    @classmethod
    def cost_terms(cls, params, size):
        if size.triangles > params["max_triangles"]:
            return None   # prepare skips the row (its guard)
        return {"pixel_triangles": size.pixels * size.triangles}   # every pixel sums every triangle

    def prepare(self, gpu, scene, facts, params, view) -> None:
        self.params = params
        if gpu.triangle_count > params["max_triangles"]:
            raise SkipRow(f"scene '{scene.name}' has {gpu.triangle_count} triangles, "
                             f"more than max_triangles={params['max_triangles']}")
        ctx = gpu.ctx
        defines = dict(VPL_DEFINES, EMISSION_FLC=params["emission"] == "flc")
        self.triangles = ctx.buffer(triangle_records(gpu).tobytes())
        self.vpls = ctx.buffer(reserve=gpu.triangle_count * VPL_BYTES)
        self.irradiance = load_compute(ctx, SHADERS / "vpl_irradiance.glsl", defines)
        self.gather = load_program(ctx, SHADERS / "gather.glsl", defines)
        self.gather_vao = ctx.vertex_array(self.gather, [])
        self.indirect = ctx.texture((view.width, view.height), 4, dtype="f4")
        self.fbo = ctx.framebuffer([self.indirect])
        self.ctx = ctx
        self.eps = params["eps_rel"] * gpu.radius

    def render(self, frame, prof) -> FrameOutput:
        ctx, gpu, passes = self.ctx, frame.gpu, frame.passes
        jitter_frames = self.params["jitter_frames"]
        self.fbo.use()
        ctx.viewport = (0, 0, frame.width, frame.height)
        self.fbo.clear(0.0, 0.0, 0.0, 0.0)
        for j in range(jitter_frames):
            with prof.stage("vpl_irradiance"):
                gpu.bind_scene_buffers()
                self.triangles.bind_to_storage_buffer(VPL_DEFINES["BINDING_VPL_TRIANGLES"])
                self.vpls.bind_to_storage_buffer(VPL_DEFINES["BINDING_VPLS"])
                passes.shadows.bind(self.irradiance, 0)
                set_uniforms(self.irradiance, u_triangle_count=gpu.triangle_count, u_light_count=gpu.light_count,
                             u_rand=frame.random_u32(j), u_jitter=jitter_frames > 1)
                self.irradiance.run(group_x=(gpu.triangle_count + 63) // 64)
                ctx.memory_barrier()
            with prof.stage("gather"):
                self.fbo.use()
                ctx.viewport = (0, 0, frame.width, frame.height)
                ctx.disable(moderngl.DEPTH_TEST)
                ctx.enable(moderngl.BLEND)
                ctx.blend_func = moderngl.ONE, moderngl.ONE
                passes.gbuffer.bind(self.gather)
                self.vpls.bind_to_storage_buffer(VPL_DEFINES["BINDING_VPLS"])
                gpu.bind_scene_buffers()
                set_uniforms(self.gather, u_eps=self.eps, u_weight=1.0 / jitter_frames)
                for first, end in loop_chunks(gpu.triangle_count):  # additive: partial sums add up
                    set_uniforms(self.gather, u_vpl_first=first, u_vpl_end=end)
                    self.gather_vao.render(moderngl.TRIANGLES, vertices=3)
                ctx.disable(moderngl.BLEND)
        return FrameOutput(direct=passes.direct.radiance, indirect=self.indirect)

    def release(self) -> None:
        from bench.gl.context import park
        if getattr(self, "ctx", None) is None:  # prepare() stopped before allocating anything
            return
        park(self.ctx)
        for name in ("fbo", "indirect", "gather_vao", "gather", "irradiance", "vpls", "triangles"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.release()
