"""`ssdo`: the one-bounce indirect term of Screen-Space Directional Occlusion (Ritschel, Grosch,
Seidel, "Approximating dynamic global illumination in image space", I3D 2009, Sec. 3.2).

For each pixel x (position, shading normal n_x and albedo rho_x from the GBuffer), N points
s_i = x + r_max lambda_i w_i are drawn in the hemisphere of radius r_max around x as the paper
draws them: a direction w_i uniform on the hemisphere and a random step size lambda_i uniform
in [0, 1]. Each s_i is projected to the screen; if it lies behind the visible surface at that
pixel (farther from the camera than the GBuffer surface there: the paper's "below the
surface"), that direction is blocked and the visible surface point y_i acts as a small sender
patch carrying its direct radiance L_s(y_i) (the shared, shadow-mapped direct pass:
rho_y / pi E(y), exactly the radiance leaving y). A sample in front of the visible surface is
open; so is one that projects off screen or onto the background (nothing is known there). The
estimate is

    L(x) = rho_x / pi * sum_{blocked i} L_s(y_i) A_i <n_x, w_i>+ <n_y, -w_i>+ / max(d_clamp, d_i)^2

with w_i = (y_i - x) / d_i, d_i = |y_i - x| and n_y the GBuffer normal at y_i (it faces the
camera, so L_s is the radiance of the side the camera sees; senders whose visible side faces
away from x give nothing). The sender's colour is its own (rho_y inside L_s), the receiver's is
rho_x: a red wall tints a white floor red in the wall's proportions.
Units: A_i cos_s / d^2 is the solid angle of the patch seen from x, L_s times it times cos_r
is irradiance at x, rho_x/pi turns it into radiance: the paper's equation is consistent only
if L_pixel is the sender's outgoing radiance rho_y E_y / pi (its irradiance E_y or radiosity
rho_y E_y would be pi / rho_y or pi times too large).

The sender patch area A_i (the correction of issue #11). The paper sets every patch to
A_s = pi r_max^2 / N, "an initial value" for "a flat surface inside the hemisphere", and notes
that "depending on the slope distribution inside the hemisphere, the actual value can be
higher". The actual value is the area a blocked sample stands for: A_i = 1 / (N p(y_i)), where
p(y) is the density, per unit area of the sender, of a blocked sample landing behind y: every
point of the column behind y along the camera ray (unit direction u, from y to where the ray
leaves the ball of radius r_max around x or crosses x's tangent plane) is blocked at y, so

    p(y) = |<n_y, u>| / t_y^2 * integral_column t^2 p_V(e + t u) dt,   p_V(s) = 1 / (2 pi r_max |s - x|^2)

(t: distance from the eye e, t_y at y; p_V: the paper's sample density per volume; the column
integral by 3-point Gauss-Legendre, the column counted at least MIN_COLUMN_REL = 0.02 r_max
long, which caps A_i where the column grazes the ball's rim). With it, the sum estimates the
one-bounce light from every on-screen first-layer sender within r_max and above x's tangent
plane without bias: with many samples and a large r_max it converges to the screen-sender bound
(`studies/ssdo_screen_bound.py`). A_s is that area only in one configuration; elsewhere it
misweights by the blocked volume behind the sender: a sender seen at a grazing angle (small
|<n_y, u>|) or with a short column (near the ball's rim) stands for much more area than A_s
(big_floor's spot-lit floor patch, a compact sender seen at a grazing angle: NOTES.md).

Hemisphere radius (the default is derived from the view). With `radius_rel` = 0 (default), r_max
= `radius_view_rel` x the mean view depth of the covered pixels, computed on the GPU every frame
(stage `view_scale`: depth sums over blocks of pixels on a power-of-two grid, its mip chain of
exact 2 x 2 averages, the 1 x 1 level read by the sampling pass; no readback). `radius_rel` > 0
sets r_max = radius_rel x the scene radius instead. Why the view: SSDO only sees senders on
screen, and the scene radius is set by geometry that may not be. d_clamp = `clamp_distance_rel`
x r_max, so the whole estimate is independent of the unit of length. With unbiased patch areas
r_max is no longer a gain to calibrate but a reach: a larger one counts farther senders and
spreads the N samples over more volume (more noise); radius_view_rel = 1.5 by default.

Where this implementation differs from the paper:

- r_max is derived from the view by default (above); the distance clamp is `max(d_clamp, d)`
  with d_clamp relative to r_max (the paper clamps d to 1 scene unit, which is not scale
  invariant: in a 1 m Cornell box it clamps almost every pair); the same clamp bounds
  |s - x| in the column density;
- both cosines are clamped at 0 (the paper leaves it implicit);
- the patch area is the one each sample stands for (above), not the constant A_s.

Which scenes SSDO can see (and claims). `studies/ssdo_screen_bound.py` computes, in numpy, the
exact unshadowed bounce from every on-screen pixel (first layer) to every other: the most any
screen-space one-bounce method can return. SSDO claims the scenes whose bound is at least 0.85
of Mitsuba's reference, i.e. whose senders are on screen: `lit_wall_corner` (within [0.85, 1.15]
of the reference, and at least half of it on the floor near the corner). `big_floor` is not
claimed: a quarter of its bounce comes from the part of the spot-lit floor below the view, out
of any screen-space method's reach. `cornell_spot`: the spot lights the ceiling above and behind
the camera, and no pixel of the ceiling is on screen; the only directly lit surface on screen is
the top strip of the tall block's front face, whose light lands mostly off screen.
`hidden_bounce`: every lit surface is behind the camera by design. `rooms`: the lit room is
seen only through a door. That light is SSDO's documented blind spot, not a bug; its share of
the reference follows the bound on every default scene (NOTES.md has the figures).

Interleaved sampling: the frame's base set of N samples (from `frame.random_u32`, the same
for every pixel; cos(theta) stratified) is shifted by a Cranley-Patterson offset that depends
on the pixel's cell in its M x M block, so neighbouring pixels use M^2 different sets. A
separable geometry-aware blur then averages the M^2 sets: a neighbour is kept only if its
distance from the centre's tangent plane is <= `blur_depth_threshold` x the centre's view
depth and its normal's cosine with the centre's is >= `blur_normal_threshold`. The window is
centred on the pixel, an odd number of taps, so it never shifts the image: an odd `blur_size`
is a plain box of that many taps; an even one (default 4) has blur_size + 1 taps whose two end
taps weigh 1/2. With blur_size a multiple of M every set enters each pixel of a flat region
with the same weight. Same seed and frame -> same image.

Direct light: SSDO's directional occlusion replaces shadowing of *distant* (environment) light
by a screen-space visibility test. The scene model has no environment light; point, spot and
directional lights are handled exactly by the shared shadow-mapped direct pass, which this
method returns unchanged as its direct component (no SSDO occlusion is applied to it).

Parameters:

<!-- parameters: generated from the Param declarations by `gibench manuals --write` -->
| parameter             | default | range          | meaning |
|-----------------------|---------|----------------|---|
| sample_count          | 32      | 1 .. 1024      | N, hemisphere samples per pixel (quality knob; sweep 4, 8, 16, 32, 64) |
| radius_rel            | 0.0     | 0.0 .. 4.0     | hemisphere radius r_max relative to the scene radius; 0: derived from the view (radius_view_rel x the mean view depth of the covered pixels) |
| radius_view_rel       | 1.5     | 0.0001 .. 10.0 | r_max relative to the mean view depth of the covered pixels, used when radius_rel = 0 |
| pattern_size          | 4       | 1 .. 16        | M: interleaved sample pattern of M x M pixels (M^2 sample sets) |
| blur_size             | 4       | 1 .. 32        | effective width of the centred, separable geometry-aware blur (1: no blur) |
| blur_depth_threshold  | 0.05    | 0.0 .. 10.0    | max distance of a blur neighbour from the centre's tangent plane, relative to the centre's view depth |
| blur_normal_threshold | 0.8     | -1.0 .. 1.0    | min cosine between a blur neighbour's normal and the centre's |
| clamp_distance_rel    | 0.02    | 1e-06 .. 1.0   | distance clamp d_clamp of max(d_clamp, d), relative to r_max |
<!-- end of parameters -->

Resolution: r_max and d_clamp are world lengths (resolution independent); M and blur_size are
in pixels and keep their meaning at any resolution (the blur averages the M^2 sets).

Quality ladder (fast -> accurate; `ladder`): sample_count 8, 16, 32 (default), 64, 128: N is the
knob that trades time for noise (the estimator's mean does not depend on N; its cost is
O(pixels x N)); r_max is a reach, set from the view, not a quality setting.

Example:

    gibench run --scenes lit_wall_corner --methods ssdo --res 128x96 --defaults-only
    gibench run --scenes lit_wall_corner --methods ssdo --res 128x96 --param ssdo.sample_count=8,128

Stages: `view_scale` (one full-screen pass + mipmaps), `indirect_samples` (full screen), `blur`
(two full-screen passes), after the shared `gbuffer_shadow` and `direct_light`. Needs: gbuffer,
shadow_map, direct. Cost: O(pixels x N), independent of the triangle count.

Measurements: NOTES.md beside this file holds the figures (the screen-sender bound per scene,
the radius comparison, the ladder's relMSE, the cost of the column density) and the history of
the defaults; `python -m studies.ssdo_screen_bound RUN_DIR` tabulates SSDO's and the bound's
share of the reference for a `gibench run` folder.

In motion (bench.run.sequence): It keeps nothing between states (screen space): a frame where
anything moved prepares it again (programs, sample patterns). Measured update per moved frame at
160x90, light (rooms_light_sweep) 7 ms, camera (sponza_camera_walk) 7 ms, geometry
(cornell_spot_moving_block) 6 ms (`python -m studies.motion_costs`, 2 cores shared with other work).
"""
from __future__ import annotations

from pathlib import Path

import moderngl
import numpy as np

from bench.gl import load_program, set_uniforms
from bench.gl.context import park
from bench.protocol.method import FrameOutput, MethodBase, Param

SHADERS = Path(__file__).parent / "shaders"
# A sample counts as behind the visible surface only if farther by this relative view depth
# (float32 reconstruction noise of a sample lying on the surface itself).
# A blocked sample's column behind its sender counts as at least this x r_max long: caps the
# area a sample stands for where the column grazes the ball's rim or x's tangent plane (the
# variance of 1 / p diverges logarithmically there); 0.005 .. 0.02 change no figure of the manual.
SSDO_DEFINES = {"DEPTH_BIAS_REL": 1e-4, "MIN_COLUMN_REL": 0.02}
RADIUS_VIEW_REL = 1.5


class ScreenSpaceDirectionalOcclusion(MethodBase):
    name = "ssdo"
    summary = "SSDO one-bounce indirect from screen-space hemisphere samples (Ritschel et al. 2009)"
    stages = ("view_scale", "indirect_samples", "blur")
    needs = frozenset({"gbuffer", "shadow_map", "direct"})
    ladder = ({"sample_count": 8}, {"sample_count": 16}, {}, {"sample_count": 64}, {"sample_count": 128})
    params = {
        "sample_count": Param(32, "N, hemisphere samples per pixel", 1, 1024,
                              quality=True, sweep=(4, 8, 16, 32, 64)),
        "radius_rel": Param(0.0, "hemisphere radius r_max relative to the scene radius; 0: derived from the view "
                            "(radius_view_rel x the mean view depth of the covered pixels)", 0.0, 4.0),
        "radius_view_rel": Param(RADIUS_VIEW_REL, "r_max relative to the mean view depth of the covered pixels, "
                                 "used when radius_rel = 0", 1e-4, 10.0),
        "pattern_size": Param(4, "M: interleaved sample pattern of M x M pixels (M^2 sample sets)", 1, 16),
        "blur_size": Param(4, "effective width of the centred, separable geometry-aware blur (1: no blur)", 1, 32),
        "blur_depth_threshold": Param(0.05, "max distance of a blur neighbour from the centre's tangent plane, "
                                      "relative to the centre's view depth", 0.0, 10.0),
        "blur_normal_threshold": Param(0.8, "min cosine between a blur neighbour's normal and the centre's",
                                       -1.0, 1.0),
        "clamp_distance_rel": Param(0.02, "distance clamp d_clamp of max(d_clamp, d), relative to r_max",
                                    1e-6, 1.0),
    }

    @classmethod
    def cost_terms(cls, params, size):
        return {"pixel_samples": size.pixels * params["sample_count"]}   # screen-space samples per pixel

    def prepare(self, gpu, scene, facts, params, view) -> None:
        self.params = params
        ctx = self.ctx = gpu.ctx
        self.radius_m = params["radius_rel"] * gpu.radius   # 0: the shader derives r_max from the view
        self.samples = load_program(ctx, SHADERS / "indirect_samples.glsl", SSDO_DEFINES)
        self.blur = load_program(ctx, SHADERS / "geometry_blur.glsl")
        self.depth_prog = load_program(ctx, SHADERS / "view_depth.glsl")
        self.samples_vao = ctx.vertex_array(self.samples, [])
        self.blur_vao = ctx.vertex_array(self.blur, [])
        self.depth_vao = ctx.vertex_array(self.depth_prog, [])
        size = (view.width, view.height)
        self.raw = ctx.texture(size, 4, dtype="f4")
        self.half = ctx.texture(size, 4, dtype="f4")
        self.indirect = ctx.texture(size, 4, dtype="f4")
        for tex in (self.raw, self.half, self.indirect):
            tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        # The mean view depth is reduced on a power-of-two grid (each texel sums a block of 1 or 2
        # pixels per axis), whose mip levels are exact 2 x 2 averages: GL's box filter skips
        # texels on odd-sized levels (up to 8% off at 96x72), and padding the view to a square
        # power of two would cost up to 4x its memory.
        self.view_grid = tuple(1 << int(np.floor(np.log2(n))) for n in size)
        self.view_depth = ctx.texture(self.view_grid, 2, dtype="f4")
        self.view_depth_level = int(np.log2(max(self.view_grid)))   # the 1 x 1 level of the mip chain
        self.raw_fbo = ctx.framebuffer([self.raw])
        self.half_fbo = ctx.framebuffer([self.half])
        self.out_fbo = ctx.framebuffer([self.indirect])
        self.depth_fbo = ctx.framebuffer([self.view_depth])

    def render(self, frame, prof) -> FrameOutput:
        ctx, passes, p = self.ctx, frame.passes, self.params
        viewport = (0, 0, frame.width, frame.height)
        ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
        with prof.stage("view_scale"):
            self.depth_fbo.use()
            ctx.viewport = (0, 0, *self.view_grid)
            passes.gbuffer.bind(self.depth_prog)
            set_uniforms(self.depth_prog, u_view_proj=frame.view.view_proj, u_grid=self.view_grid)
            self.depth_vao.render(moderngl.TRIANGLES, vertices=3)
            self.view_depth.build_mipmaps()
        with prof.stage("indirect_samples"):
            self.raw_fbo.use()
            ctx.viewport = viewport
            unit = passes.gbuffer.bind(self.samples)
            passes.direct.radiance.use(unit)
            self.samples["u_direct_radiance"].value = unit
            self.view_depth.use(unit + 1)
            self.samples["u_view_depth"].value = unit + 1
            set_uniforms(self.samples, u_view_proj=frame.view.view_proj, u_sample_count=p["sample_count"],
                         u_radius_m=self.radius_m, u_radius_rel=p["radius_view_rel"], u_clamp_rel=p["clamp_distance_rel"],
                         u_view_depth_level=self.view_depth_level,
                         u_pattern_size=p["pattern_size"], u_rand=frame.random_u32(0),
                         u_eye=tuple(float(v) for v in frame.view.eye_local))
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
        for name in ("raw_fbo", "half_fbo", "out_fbo", "depth_fbo", "raw", "half", "indirect", "view_depth",
                     "samples_vao", "blur_vao", "depth_vao", "samples", "blur", "depth_prog"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.release()
                setattr(self, name, None)
        self.ctx = None
