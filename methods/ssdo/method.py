"""`ssdo`: the one-bounce indirect term of Screen-Space Directional Occlusion (Ritschel, Grosch,
Seidel, "Approximating dynamic global illumination in image space", I3D 2009, Sec. 3.2).

For each pixel x (position, shading normal n_x and albedo rho_x from the GBuffer), N points s_i
are drawn in the hemisphere of radius r_max around x, uniformly in its volume (direction
uniform on the hemisphere, distance r_max u^(1/3)). Each s_i is projected to the screen; if it
lies behind the visible surface at that pixel (farther from the camera than the GBuffer
surface there), that direction is blocked and the visible surface point y_i acts as a small
sender patch of area A_s = pi r_max^2 / N carrying its direct radiance L_s(y_i) (the shared,
shadow-mapped direct pass: rho_y / pi E(y), exactly the radiance leaving y). The estimate is

    L(x) = rho_x / pi * sum_{blocked i} L_s(y_i) A_s <n_x, w_i>+ <n_y, -w_i>+ / max(d_clamp, d_i)^2

with w_i = (y_i - x) / d_i, d_i = |y_i - x| and n_y the GBuffer normal at y_i (it faces the
camera, so L_s is the radiance of the side the camera sees; senders whose visible side faces
away from x give nothing). Samples that project off screen or onto the background are open.
Units: A_s cos_s / d^2 is the solid angle of the patch seen from x, L_s times it times cos_r
is irradiance at x, rho_x/pi turns it into radiance: the paper's equation is consistent only
if L_pixel is the sender's outgoing radiance rho_y E_y / pi (its irradiance E_y or radiosity
rho_y E_y would be pi / rho_y or pi times too large). Where this implementation differs:

- the distance clamp is `max(d_clamp, d)` with d_clamp relative to the scene radius (the paper
  clamps d to 1 scene unit, which is not scale invariant: in a 1 m Cornell box it clamps almost
  every pair);
- both cosines are clamped at 0 (the paper leaves it implicit);
- samples are uniform in the hemisphere's *volume* (the paper draws a random step size
  lambda in [0, 1] and puts the sample at distance r_max lambda, crowding samples near x).
  The paper justifies A_s = pi r_max^2 / N by a flat sender through x filling half the
  hemisphere: N/2 blocked samples stand for the half disc of area pi r_max^2 / 2. Uniform
  volume density keeps that total and spreads the weight over the sender as
  3/2 sqrt(1 - t^2 / r_max^2) per unit area (t: distance from x's foot), where lambda-uniform
  concentrates it as 1/t near x, i.e. on the senders whose 1/d^2 is largest.

SSDO is an approximation, not a consistent estimator of the one-bounce integral: senders are
limited to what the camera sees (first depth layer, on screen, within r_max of x), and even
for a visible flat sender its area weighting is exact only for a plane through x. Expect it
to miss light from hidden or distant senders (`hidden_bounce`, `cornell_spot`) and to come
near the exact sum (`manylights`) only near corners of visible lit surfaces, seen steeply
(senders slide along camera rays by depth x cot(elevation)).

Interleaved sampling: the frame's base set of N samples (from `frame.random_u32`, the same
for every pixel; cos(theta) stratified) is shifted by a Cranley-Patterson offset that depends
on the pixel's cell in its M x M block, so neighbouring pixels use M^2 different sets. A
separable geometry-aware box blur (`blur_size` taps per axis; a neighbour is kept only if
its distance from the centre's tangent plane is <= `blur_depth_threshold` x the centre's view
depth and its normal's cosine with the centre's is >= `blur_normal_threshold`) then averages the M^2 sets; with blur_size a multiple of M every set
enters each pixel of a flat region equally often. Same seed and frame -> same image.

Direct light: SSDO's directional occlusion replaces shadowing of *distant* (environment) light
by a screen-space visibility test. The scene model has no environment light; point, spot and
directional lights are handled exactly by the shared shadow-mapped direct pass, which this
method returns unchanged as its direct component (no SSDO occlusion is applied to it).

| parameter             | default | range        | meaning                                                        |
|-----------------------|---------|--------------|----------------------------------------------------------------|
| sample_count          | 16      | 1 .. 1024    | N, hemisphere samples per pixel (quality; sweep 4 .. 64)       |
| radius_rel            | 0.5     | 1e-4 .. 4    | r_max relative to the scene radius                             |
| pattern_size          | 4       | 1 .. 16      | M: interleaved pattern of M x M pixels (M^2 sample sets)       |
| blur_size             | 4       | 1 .. 32      | taps per axis of the geometry-aware blur (1: no blur)          |
| blur_depth_threshold  | 0.05    | 0 .. 10      | max tangent-plane distance of a blur neighbour / view depth    |
| blur_normal_threshold | 0.8     | -1 .. 1      | min cosine between the normals of a blur neighbour and centre  |
| clamp_distance_rel    | 0.02    | 1e-6 .. 1    | d_clamp of max(d_clamp, d), relative to the scene radius       |

Stages: `indirect_samples` (full screen), `blur` (two full-screen passes), after the shared
`gbuffer_shadow` and `direct_light`. Cost: O(pixels x N), independent of the triangle count.
"""
from __future__ import annotations

from pathlib import Path

import moderngl
import numpy as np

from bench.gl import load_program, set_uniforms
from bench.gl.context import park
from bench.method import FrameOutput, MethodBase, Param

SHADERS = Path(__file__).parent / "shaders"
# A sample counts as behind the visible surface only if farther by this relative view depth
# (float32 reconstruction noise of a sample lying on the surface itself).
SSDO_DEFINES = {"DEPTH_BIAS_REL": 1e-4}


class ScreenSpaceDirectionalOcclusion(MethodBase):
    name = "ssdo"
    summary = "SSDO one-bounce indirect from screen-space hemisphere samples (Ritschel et al. 2009)"
    stages = ("indirect_samples", "blur")
    needs = frozenset({"gbuffer", "shadow_map", "direct"})
    params = {
        "sample_count": Param(16, "N, hemisphere samples per pixel", 1, 1024,
                              quality=True, sweep=(4, 8, 16, 32, 64)),
        "radius_rel": Param(0.5, "hemisphere radius r_max relative to the scene radius", 1e-4, 4.0),
        "pattern_size": Param(4, "M: interleaved sample pattern of M x M pixels (M^2 sample sets)", 1, 16),
        "blur_size": Param(4, "taps per axis of the separable geometry-aware blur (1: no blur)", 1, 32),
        "blur_depth_threshold": Param(0.05, "max distance of a blur neighbour from the centre's tangent plane, "
                                      "relative to the centre's view depth", 0.0, 10.0),
        "blur_normal_threshold": Param(0.8, "min cosine between a blur neighbour's normal and the centre's",
                                       -1.0, 1.0),
        "clamp_distance_rel": Param(0.02, "distance clamp d_clamp of max(d_clamp, d), relative to the scene radius",
                                    1e-6, 1.0),
    }

    def prepare(self, gpu, scene, facts, params, view) -> None:
        self.params = params
        ctx = self.ctx = gpu.ctx
        self.r_max = params["radius_rel"] * gpu.radius
        self.sender_area = np.pi * self.r_max ** 2 / params["sample_count"]
        self.d_clamp = params["clamp_distance_rel"] * gpu.radius
        self.samples = load_program(ctx, SHADERS / "indirect_samples.glsl", SSDO_DEFINES)
        self.blur = load_program(ctx, SHADERS / "geometry_blur.glsl")
        self.samples_vao = ctx.vertex_array(self.samples, [])
        self.blur_vao = ctx.vertex_array(self.blur, [])
        size = (view.width, view.height)
        self.raw = ctx.texture(size, 4, dtype="f4")
        self.half = ctx.texture(size, 4, dtype="f4")
        self.indirect = ctx.texture(size, 4, dtype="f4")
        for tex in (self.raw, self.half, self.indirect):
            tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.raw_fbo = ctx.framebuffer([self.raw])
        self.half_fbo = ctx.framebuffer([self.half])
        self.out_fbo = ctx.framebuffer([self.indirect])

    def render(self, frame, prof) -> FrameOutput:
        ctx, passes, p = self.ctx, frame.passes, self.params
        viewport = (0, 0, frame.width, frame.height)
        with prof.stage("indirect_samples"):
            self.raw_fbo.use()
            ctx.viewport = viewport
            ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
            unit = passes.gbuffer.bind(self.samples)
            passes.direct.radiance.use(unit)
            self.samples["u_direct_radiance"].value = unit
            set_uniforms(self.samples, u_view_proj=frame.view.view_proj, u_sample_count=p["sample_count"],
                         u_r_max=self.r_max, u_sender_area=self.sender_area, u_clamp=self.d_clamp,
                         u_pattern_size=p["pattern_size"], u_rand=frame.random_u32(0))
            self.samples_vao.render(moderngl.TRIANGLES, vertices=3)
        with prof.stage("blur"):
            set_uniforms(self.blur, u_blur_size=p["blur_size"], u_depth_threshold=p["blur_depth_threshold"],
                         u_normal_threshold=p["blur_normal_threshold"])
            for source, target, axis in ((self.raw, self.half_fbo, (1, 0)), (self.half, self.out_fbo, (0, 1))):
                target.use()
                ctx.viewport = viewport
                unit = passes.gbuffer.bind(self.blur)
                source.use(unit)
                self.blur["u_input"].value = unit
                set_uniforms(self.blur, u_axis=axis)
                self.blur_vao.render(moderngl.TRIANGLES, vertices=3)
        return FrameOutput(direct=passes.direct.radiance, indirect=self.indirect)

    def release(self) -> None:
        if getattr(self, "ctx", None) is None:  # prepare() stopped before allocating anything
            return
        park(self.ctx)
        for name in ("raw_fbo", "half_fbo", "out_fbo", "raw", "half", "indirect", "samples_vao", "blur_vao",
                     "samples", "blur"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.release()
                setattr(self, name, None)
        self.ctx = None
