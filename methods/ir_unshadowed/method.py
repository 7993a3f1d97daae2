"""`ir_unshadowed`: instant radiosity without indirect visibility (Keller 1997), with its
virtual point lights (VPLs) drawn from the reflective shadow map (Dachsbacher & Stamminger 2005).

Each RSM texel i is a small patch of the first surface the light sees, holding its position
y_i, its normal n_i (facing the light) and the flux it reflects
Phi_i = rho_i Phi_in,i |<n_s,i, l>| / |<n_g,i, l>| (Phi_in,i is the flux through the texel's
patch; the cosine ratio takes the incident cosine at the shading normal n_s, as Mitsuba does,
where the texel's footprint is measured with the geometric normal n_g). Summed
over all texels, Lambertian patches give the unshadowed one-bounce radiance at x:

    L(x) = rho_x / pi * sum_i Phi_i / pi * <n_x, w>+ <n_i, -w>+ / max(eps, |y_i - x|)^2,
    w = (y_i - x) / |y_i - x|

(a VPL emits only on the side its normal faces, the lit side; intensity I(w) = Phi cos / pi).
Every frame this method estimates that sum with N VPLs, without bias:

1. `vpl_sample` (compute): integer weight q_i = ceil(luminance(Phi_i) / max luminance * levels)
   per texel, >= 1 wherever Phi_i != 0; exact uint32 prefix sums (per block of 256 texels,
   then over the blocks); N stratified draws u_k in [k, k+1)/N, texel = CDF^-1(u_k). VPL k
   carries Phi_i Q / (N q_i) (Q = sum q). Importance sampling by flux luminance puts no VPL on
   unlit texels (most of a point light's cube faces), and the integer CDF keeps each lit
   texel's probability exactly q_i / Q, so E[sum_k VPL_k] = sum_i texel_i. The random numbers
   come from `frame.random_u32` (same seed and frame -> same VPLs).
2. `gather` (full screen): every pixel sums the N VPLs with the formula above, no visibility.

The sampling and the gather live in `bench/gl/vpl.py` and `bench/gl/shaders/vpl_*.glsl`: the
same VPLs and transfer term serve `ir_shadowed`, `val_clustered` and `visibility_gates`.

The RSM samples the surfaces the light sees, i.e. exactly the shadowed-lit surfaces, so with
many VPLs the result converges to `manylights` (emission lambert) up to the RSM's
discretisation (texel-centre positions, 128^2 texels per light layer).

Near field (bench/gl/near_field.py, shared by every VPL method and DSS). The point term's
1/d^2 is unbounded: a VPL a few millimetres from a receiver lit it thousands of times over (the
old default, a clamp max(eps, d) with eps = 1e-4 of the scene radius, gave relMSE 6.0 on sponza
and 8.4 on lost_empire at 256 VPLs, 60-86% of the squared error in 20 pixels). Each VPL stands
for the area A_k of lit surface its RSM texel covers divided by N pdf (rsm.glsl's flux.a times
Q / (N q_i)); the default bound `near_field=footprint` clamps the distance at the radius of that
area, d^2 >= s A_k / pi with s = `near_field_scale` = 1: a VPL then never lights a receiver more
than the exitance Phi_k / A_k of the surface it samples, which is scale-invariant (A_k scales
with the scene) and vanishes as N grows (A_k ~ 1/N: the estimator stays consistent). It was
chosen from a sweep over the corpus (studies/vpl_near_field.py; NOTES.md has the table): it
removes the spikes like the disc element (d^2 + A_k / pi, which darkens every receiver within a
few disc radii: sponza's bounce at 0.82, sphere_inside at 0.98) with the best relMSE on the real
scenes but sponza, and darkens less. `clamp` and `disc_element` remain options.

Operating point. Importance sampling by flux spreads the VPLs over every lit surface, not over
the view: on sponza at 256 VPLs the arcade beside the camera is lit by a handful of VPLs, each
1/256 of the sun's bounce (relMSE 0.76 mean over 3 seeds, 0.23 to 1.64 by seed, i.e. at best the
error of no indirect at all), at 1024 by four times as many (0.15, every seed). The default is
1024 VPLs (the count of the VAL paper's instant radiosity), the ladder 256, 1024, 4096.

Parameters:

<!-- parameters: generated from the Param declarations by `gibench manuals --write` -->
| parameter          | default   | range                          | meaning |
|--------------------|-----------|--------------------------------|---|
| vpl_count          | 1024      | 1 .. 65536                     | VPLs drawn from the RSM per frame (importance sampled by flux luminance, stratified) (quality knob; sweep 16, 64, 256, 1024, 4096) |
| clamp_distance_rel | 0.0001    | 1e-07 .. 1.0                   | distance clamp eps of max(eps, distance) relative to the scene radius (tames the 1/d^2 singularity) |
| near_field         | footprint | clamp, disc_element, footprint | how an emitter's 1/d^2 is bounded near it, d the emitter-receiver distance, A the area it stands for: clamp max(eps, d)^2; disc_element d^2 + A / pi (a disc's form factor); footprint max(d^2, s A / pi) (a clamp at the radius of s times the emitter's area); each at least eps^2 |
| near_field_scale   | 1.0       | 0.001 .. 100.0                 | s of near_field=footprint: the clamp's area as a fraction of the area the emitter stands for |
<!-- end of parameters -->

Quality ladder (`gibench run`): vpl_count 256, 1024 (default), 4096: the gather costs VPLs x
pixels and the variance falls as 1 / VPLs, so the count is the knob a user turns. Fewer than 256
darken the bounce (the footprint bound grows as 1 / N: sponza's mean at 64 VPLs is 0.71), which
lowers relMSE on the views where variance dominates: a rung below 256 would buy error with
more VPLs.

Example:

    gibench run --scenes cornell_box --methods ir_unshadowed --res 128x96 --defaults-only
    gibench run --scenes cornell_box --methods ir_unshadowed --param ir_unshadowed.vpl_count=64,1024

Stages: `vpl_sample` (CDF + sampling, 4 compute dispatches), `gather` (after the shared
`gbuffer_shadow`, `direct_light`, `rsm`). Needs: gbuffer, shadow_map, direct, rsm.

In motion (bench.run.sequence): It keeps nothing between states: a frame where anything moved
prepares it again (its programs and VPL buffers; the VPLs themselves are drawn from each frame's
RSM). Measured update per moved frame at 160x90, light (rooms_light_sweep) 12 ms, camera
(sponza_camera_walk) 16 ms, geometry (cornell_spot_moving_block) 13 ms (`python -m
studies.motion_costs`, 2 cores shared with other work).
"""
from __future__ import annotations

from bench.protocol.method import FrameOutput, MethodBase, Param

from bench.gl.vpl import CLAMP_DOC, VPL_COUNT_DOC, RsmVplSampler, VplGather
from bench.gl.near_field import (NEAR_FIELD_DEFAULT, NEAR_FIELD_DOC, NEAR_FIELDS, NEAR_SCALE_DEFAULT,
                                   NEAR_SCALE_DOC, NEAR_SCALE_RANGE, near_field_defines)

class InstantRadiosityUnshadowed(MethodBase):
    name = "ir_unshadowed"
    summary = "Instant radiosity, VPLs importance-sampled from the RSM, no indirect visibility"
    ladder = ({"vpl_count": 256}, {}, {"vpl_count": 4096})
    stages = ("vpl_sample", "gather")
    needs = frozenset({"gbuffer", "shadow_map", "direct", "rsm"})
    params = {
        "vpl_count": Param(1024, VPL_COUNT_DOC, 1, 65536, quality=True, sweep=(16, 64, 256, 1024, 4096)),
        "clamp_distance_rel": Param(1e-4, CLAMP_DOC, 1e-7, 1.0),
        "near_field": Param(NEAR_FIELD_DEFAULT, NEAR_FIELD_DOC, choices=NEAR_FIELDS),
        "near_field_scale": Param(NEAR_SCALE_DEFAULT, NEAR_SCALE_DOC, *NEAR_SCALE_RANGE),
    }

    @classmethod
    def cost_terms(cls, params, size):
        return {"pixel_vpls": size.pixels * params["vpl_count"]}   # every pixel gathers every VPL

    def prepare(self, gpu, scene, facts, params, view) -> None:
        self.params = params
        self.ctx = gpu.ctx
        self.eps = params["clamp_distance_rel"] * gpu.radius
        self.sampler = RsmVplSampler(gpu.ctx, params["vpl_count"])
        self.gather = VplGather(gpu.ctx, view.width, view.height, 
                               defines=near_field_defines(params["near_field"], params["near_field_scale"]))

    def render(self, frame, prof) -> FrameOutput:
        passes = frame.passes
        with prof.stage("vpl_sample"):
            self.sampler.sample(passes.rsm, frame.random_u32(0))
        with prof.stage("gather"):
            self.gather.render(passes.gbuffer, self.sampler, self.eps)
        return FrameOutput(direct=passes.direct.radiance, indirect=self.gather.indirect)

    def release(self) -> None:
        for name in ("gather", "sampler"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.release()
                setattr(self, name, None)
