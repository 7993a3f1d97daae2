"""`ssdo`: the one-bounce indirect term of Screen-Space Directional Occlusion (Ritschel, Grosch,
Seidel, "Approximating dynamic global illumination in image space", I3D 2009, Sec. 3.2).

For each pixel x (position, shading normal n_x and albedo rho_x from the GBuffer), N points s_i
are drawn in the hemisphere of radius r_max around x, uniformly in its volume (direction
uniform on the hemisphere, distance r_max u^(1/3)). Each s_i is projected to the screen; if it
lies behind the visible surface at that pixel (farther from the camera than the GBuffer
surface there: the paper's "below the surface"), that direction is blocked and the visible
surface point y_i acts as a small sender patch of area A_s = pi r_max^2 / N carrying its direct
radiance L_s(y_i) (the shared, shadow-mapped direct pass: rho_y / pi E(y), exactly the radiance
leaving y). A sample in front of the visible surface is open; so is one that projects off
screen or onto the background (nothing is known there). The estimate is

    L(x) = rho_x / pi * sum_{blocked i} L_s(y_i) A_s <n_x, w_i>+ <n_y, -w_i>+ / max(d_clamp, d_i)^2

with w_i = (y_i - x) / d_i, d_i = |y_i - x| and n_y the GBuffer normal at y_i (it faces the
camera, so L_s is the radiance of the side the camera sees; senders whose visible side faces
away from x give nothing). The sender's colour is its own (rho_y inside L_s), the receiver's is
rho_x: a red wall tints a white floor red in the wall's proportions.
Units: A_s cos_s / d^2 is the solid angle of the patch seen from x, L_s times it times cos_r
is irradiance at x, rho_x/pi turns it into radiance: the paper's equation is consistent only
if L_pixel is the sender's outgoing radiance rho_y E_y / pi (its irradiance E_y or radiosity
rho_y E_y would be pi / rho_y or pi times too large).

Hemisphere radius (the default is derived from the view). With `radius_rel` = 0 (default), r_max
= `radius_view_rel` x the mean view depth of the covered pixels, computed on the GPU every frame
(stage `view_scale`: depth sums over blocks of pixels on a power-of-two grid, its mip chain of
exact 2 x 2 averages, the 1 x 1 level read by the sampling pass; no readback). `radius_rel` > 0
sets r_max = radius_rel x the scene radius instead (the previous default was 0.5 of it). Why the
view: SSDO only sees senders on screen, and the scene radius is set by geometry that may not be:
big_floor's 40 m floor made r_max 14 m and d_clamp 0.57 m around a 1.6 m blob, and its bounce
came out at 0.29 of the reference. d_clamp = `clamp_distance_rel` x r_max, so the whole estimate
is independent of the unit of length. radius_view_rel = 1.15 is the calibrated operating point:
the value at which the image mean of SSDO's bounce on `lit_wall_corner` (lit wall, unlit floor,
every sender on screen) equals Mitsuba's unshadowed one-bounce reference (mean over seeds 0..4
at 128x96: 0.83 at 1.0, 1.00 at 1.15, 1.09 at 1.25 with N = 16; 0.97 at 1.15 with N = 32).
Smaller r_max misses the farther senders, larger r_max over-weights the near ones (see "sample
density" below). N = 32 (was 16): A_s grows as r_max^2, and at N = 16 the per-pixel noise of the
larger r_max made SSDO worse than no indirect light at all on one of three seeds of
`cornell_floor_spot` (relMSE 0.84 .. 1.10 against manylights; 0.82 .. 0.89 at N = 32).

Where this implementation differs from the paper:

- r_max is derived from the view by default (above); the distance clamp is `max(d_clamp, d)`
  with d_clamp relative to r_max (the paper clamps d to 1 scene unit, which is not scale
  invariant: in a 1 m Cornell box it clamps almost every pair);
- both cosines are clamped at 0 (the paper leaves it implicit);
- samples are uniform in the hemisphere's *volume* (the paper draws a random step size
  lambda in [0, 1] and puts the sample at distance r_max lambda, crowding samples near x).
  The paper justifies A_s = pi r_max^2 / N by a flat sender through x filling half the
  hemisphere: N/2 blocked samples stand for the half disc of area pi r_max^2 / 2. Uniform
  volume density keeps that total and spreads the weight over the sender as
  3/2 sqrt(1 - t^2 / r_max^2) per unit area (t: distance from x's foot), where lambda-uniform
  concentrates it as 1/t near x, i.e. on the senders whose 1/d^2 is largest (its expectation
  diverges without the clamp).

Sample density and calibration. SSDO is an approximation, not a consistent estimator of the
one-bounce integral: senders are limited to what the camera sees (first depth layer, on screen,
within r_max of x), and the area weight A_s is exact only for a plane through x. On
`lit_wall_corner` (128x96, default, seeds 0..2) the floor's bounce is 0.35 .. 0.5x the reference
in the first 0.1 m from the wall (a sender slides away from x along the camera ray by its depth
behind the wall x the tangent of the view angle, and d_clamp cuts the nearest pairs), 0.9 ..
1.2x at 0.2 .. 0.4 m, 1.15 .. 1.35x at 0.4 .. 1 m (the 3/2 weight near x) and 0.5 .. 0.6x at
1.5 .. 2 m (beyond r_max = 2.75 m for part of the wall). A compact sender seen at a grazing
angle (big_floor's spot-lit floor patch in front of the blob) blocks a region of bounded
volume, so its weight falls as 1 / r_max once r_max exceeds its distance: there the default
(r_max 6.5 m: the far back wall raises the mean depth to 5.65 m) gives about 0.3 of the
reference (0.22 .. 0.47 over seeds 0..4) and radius_rel = 0.1 (r_max 2.9 m) about 0.5
(0.44 .. 0.62), against a screen-space bound of 0.76.

Which scenes SSDO can see. `methods/ssdo/screen_bound.py` computes, in numpy, the exact
unshadowed bounce from every on-screen pixel (first layer) to every other: the most any
screen-space one-bounce method can return. Its share of Mitsuba's reference (128x96, `main`):
lit_wall_corner 0.995, big_floor 0.76, rooms 0.086, cornell_spot 0.003, hidden_bounce 0.000. The
scenes whose senders are on screen are therefore `lit_wall_corner` (the target: SSDO within
[0.85, 1.15] of the reference) and, for three quarters of its bounce, `big_floor` (the compact
patch above). `cornell_spot`: the spot lights the ceiling above and behind the camera, and no
pixel of the ceiling is on screen (the camera looks 3 degrees down with a 30 degree half field
of view: 0 of 12288 pixels at 128x96); the only directly lit surface on screen is the top strip
of the tall block's front face (730 pixels), whose light lands mostly off screen.
`hidden_bounce`: every lit surface is behind the camera by design. `rooms`: the lit room is seen
only through a door. That light is SSDO's documented blind spot, not a bug; the same near-zero
figures for its ratio follow.

Interleaved sampling: the frame's base set of N samples (from `frame.random_u32`, the same
for every pixel; cos(theta) stratified) is shifted by a Cranley-Patterson offset that depends
on the pixel's cell in its M x M block, so neighbouring pixels use M^2 different sets. A
separable geometry-aware blur then averages the M^2 sets: a neighbour is kept only if its
distance from the centre's tangent plane is <= `blur_depth_threshold` x the centre's view
depth and its normal's cosine with the centre's is >= `blur_normal_threshold`. The window is
centred on the pixel, an odd number of taps, so it never shifts the image: an odd `blur_size`
is a plain box of that many taps; an even one (default 4) has blur_size + 1 taps whose two end
taps weigh 1/2 (the former box of taps -size/2 .. size/2 - 1 moved the image half a pixel
towards the lower-left). With blur_size a multiple of M every set enters each pixel of a flat
region with the same weight. Same seed and frame -> same image.

Direct light: SSDO's directional occlusion replaces shadowing of *distant* (environment) light
by a screen-space visibility test. The scene model has no environment light; point, spot and
directional lights are handled exactly by the shared shadow-mapped direct pass, which this
method returns unchanged as its direct component (no SSDO occlusion is applied to it).

| parameter             | default | range        | meaning                                                        |
|-----------------------|---------|--------------|----------------------------------------------------------------|
| sample_count          | 32      | 1 .. 1024    | N, hemisphere samples per pixel (quality; sweep 4 .. 64)       |
| radius_rel            | 0.0     | 0 .. 4       | r_max relative to the scene radius; 0: from the view           |
| radius_view_rel       | 1.15    | 1e-4 .. 10   | r_max / mean view depth of the covered pixels (radius_rel = 0) |
| pattern_size          | 4       | 1 .. 16      | M: interleaved pattern of M x M pixels (M^2 sample sets)       |
| blur_size             | 4       | 1 .. 32      | effective width of the centred blur window (1: no blur)        |
| blur_depth_threshold  | 0.05    | 0 .. 10      | max tangent-plane distance of a blur neighbour / view depth    |
| blur_normal_threshold | 0.8     | -1 .. 1      | min cosine between the normals of a blur neighbour and centre  |
| clamp_distance_rel    | 0.02    | 1e-6 .. 1    | d_clamp of max(d_clamp, d), relative to r_max                  |

Resolution: r_max and d_clamp are world lengths (resolution independent); M and blur_size are
in pixels and keep their meaning at any resolution (the blur averages the M^2 sets).

Stages: `view_scale` (one full-screen pass + mipmaps), `indirect_samples` (full screen), `blur`
(two full-screen passes), after the shared `gbuffer_shadow` and `direct_light`. Cost:
O(pixels x N), independent of the triangle count.
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
RADIUS_VIEW_REL = 1.15


class ScreenSpaceDirectionalOcclusion(MethodBase):
    name = "ssdo"
    summary = "SSDO one-bounce indirect from screen-space hemisphere samples (Ritschel et al. 2009)"
    stages = ("view_scale", "indirect_samples", "blur")
    needs = frozenset({"gbuffer", "shadow_map", "direct"})
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
        for name in ("raw_fbo", "half_fbo", "out_fbo", "depth_fbo", "raw", "half", "indirect", "view_depth",
                     "samples_vao", "blur_vao", "depth_vao", "samples", "blur", "depth_prog"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.release()
                setattr(self, name, None)
        self.ctx = None
