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
discretisation (texel-centre positions, 128^2 texels per light layer). The clamp eps tames the
1/d^2 singularity of VPLs close to the receiver (bright splotches at low N) at the price of a
bias near corners; the default is tiny, i.e. almost unbiased and noisy there: a few VPLs within
centimetres of a receiver carry most of the relMSE on the real scenes. `near_field =
disc_element` replaces the clamp by the form factor of a disc of the area A_k the VPL stands for
(its RSM texel's footprint on the surface, rsm.glsl's flux.a, times Q / (N q_i)): d^2 =
|y_k - x|^2 + A_k / pi (Bunnell 2005, as FLC's disc element). It takes the spikes out, but
each VPL stands for 1/N of the lit surface, and the disc's near field darkens the bounce. The
same VPLs and term make the spikes of `ir_shadowed`, `val_clustered` and `visibility_gates`;
which near field the VPL family should use by default is open, the default stays the
almost-unbiased clamp (NOTES.md has the measurements).

Parameters:

<!-- parameters: generated from the Param declarations by `gibench manuals --write` -->
| parameter          | default | range               | meaning |
|--------------------|---------|---------------------|---|
| vpl_count          | 256     | 1 .. 65536          | VPLs drawn from the RSM per frame (importance sampled by flux luminance, stratified) (quality knob; sweep 16, 64, 256, 1024, 4096) |
| clamp_distance_rel | 0.0001  | 1e-07 .. 1.0        | distance clamp eps of max(eps, distance) relative to the scene radius (tames the 1/d^2 singularity) |
| near_field         | clamp   | disc_element, clamp | the squared distance d^2 of a VPL's transfer, d the VPL-receiver distance: disc_element d^2 + A / pi (at least eps^2), A the area the VPL stands for (its RSM texel's footprint / (N pdf)); clamp max(eps, d)^2 only |
<!-- end of parameters -->

Quality ladder (`gibench run`): vpl_count 16, 64, 256 (default), 1024: the gather costs VPLs x
pixels and the variance falls as 1 / VPLs, so the count is the knob a user turns.

Example:

    gibench run --scenes cornell_box --methods ir_unshadowed --res 128x96 --defaults-only
    gibench run --scenes cornell_box --methods ir_unshadowed --param ir_unshadowed.vpl_count=64,1024

Stages: `vpl_sample` (CDF + sampling, 4 compute dispatches), `gather` (after the shared
`gbuffer_shadow`, `direct_light`, `rsm`). Needs: gbuffer, shadow_map, direct, rsm.
"""
from __future__ import annotations

from bench.protocol.method import FrameOutput, MethodBase, Param

from bench.gl.vpl import CLAMP_DOC, VPL_COUNT_DOC, RsmVplSampler, VplGather

NEAR_FIELD_DOC = ("the squared distance d^2 of a VPL's transfer, d the VPL-receiver distance: disc_element "
                  "d^2 + A / pi (at least eps^2), A the area the VPL stands for (its RSM texel's footprint / "
                  "(N pdf)); clamp max(eps, d)^2 only")
NEAR_FIELD_CHOICES = ("disc_element", "clamp")


def near_field_defines(params: dict) -> dict:
    """The gather's VPL_NEAR_DISC define for a method's `near_field` parameter."""
    return {"VPL_NEAR_DISC": int(params["near_field"] == "disc_element")}


class InstantRadiosityUnshadowed(MethodBase):
    name = "ir_unshadowed"
    summary = "Instant radiosity, VPLs importance-sampled from the RSM, no indirect visibility"
    ladder = ({"vpl_count": 16}, {"vpl_count": 64}, {}, {"vpl_count": 1024})
    stages = ("vpl_sample", "gather")
    needs = frozenset({"gbuffer", "shadow_map", "direct", "rsm"})
    params = {
        "vpl_count": Param(256, VPL_COUNT_DOC, 1, 65536, quality=True, sweep=(16, 64, 256, 1024, 4096)),
        "clamp_distance_rel": Param(1e-4, CLAMP_DOC, 1e-7, 1.0),
        "near_field": Param("clamp", NEAR_FIELD_DOC, choices=NEAR_FIELD_CHOICES),
    }

    def prepare(self, gpu, scene, facts, params, view) -> None:
        self.params = params
        self.ctx = gpu.ctx
        self.eps = params["clamp_distance_rel"] * gpu.radius
        self.sampler = RsmVplSampler(gpu.ctx, params["vpl_count"])
        self.gather = VplGather(gpu.ctx, view.width, view.height, defines=near_field_defines(params))

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
