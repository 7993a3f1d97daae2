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

The RSM samples the surfaces the light sees, i.e. exactly the shadowed-lit surfaces, so with
many VPLs the result converges to `manylights` (emission lambert) up to the RSM's
discretisation (texel-centre positions, 128^2 texels per light layer). The clamp eps tames the
1/d^2 singularity of VPLs close to the receiver (bright splotches at low N) at the price of a
bias near corners; the default is tiny, i.e. almost unbiased and noisy there. What that costs
in relMSE (a few VPLs within centimetres of a receiver carry most of it), 320 x 180, 3 seeds,
image mean of Mitsuba's unshadowed bounce in brackets, clamp_distance_rel 1e-4 -> 3e-2:
conference 1.28 (1.021) -> 0.096 (0.992), sponza 2.60 (1.043) -> 1.16 (0.980), sibenik 0.54
(0.993) -> 0.054 (0.977), cornell_box 0.665 -> 0.030, rooms 0.053 -> 0.033; the other
procedural scenes do not change, and 1e-1 takes 70% of big_floor's bounce (a small lit disc
next to the blob). The same VPLs and term make the spikes of `ir_shadowed`, `val_clustered`
and `visibility_gates` (val_clustered on conference, seed 0: ten pixels hold 99% of its
relMSE of 241 against the visible bounce). A near field that scales with the area each VPL
stands for (an RSM texel's footprint x Q / (N q_i), as FLC's disc element) is the better
remedy than a clamp relative to the scene; until then the default stays the almost-unbiased
clamp and `--param ir_unshadowed.clamp_distance_rel=0.03` is the low-variance operating point.

| parameter          | default | range        | meaning                                                 |
|--------------------|---------|--------------|---------------------------------------------------------|
| vpl_count          | 256     | 1 .. 65536   | VPLs per frame (quality; sweep 16, 64, 256, 1024, 4096) |
| clamp_distance_rel | 1e-4    | 1e-7 .. 1    | eps of max(eps, d), relative to the scene radius        |

Stages: `vpl_sample`, `gather` (after the shared `gbuffer_shadow`, `direct_light`, `rsm`).

Quality ladder (`gibench run`): vpl_count 16, 64, 256 (default), 1024: the gather costs VPLs x
pixels and the variance falls as 1 / VPLs, so the count is the knob a user turns.
"""
from __future__ import annotations

from bench.method import FrameOutput, MethodBase, Param

from .vpl_sampling import RsmVplSampler, VplGather

VPL_COUNT_DOC = "VPLs drawn from the RSM per frame (importance sampled by flux luminance, stratified)"
CLAMP_DOC = "distance clamp eps of max(eps, |x - y|) relative to the scene radius (tames the 1/d^2 singularity)"


class InstantRadiosityUnshadowed(MethodBase):
    name = "ir_unshadowed"
    summary = "Instant radiosity, VPLs importance-sampled from the RSM, no indirect visibility"
    ladder = ({"vpl_count": 16}, {"vpl_count": 64}, {}, {"vpl_count": 1024})
    stages = ("vpl_sample", "gather")
    needs = frozenset({"gbuffer", "shadow_map", "direct", "rsm"})
    params = {
        "vpl_count": Param(256, VPL_COUNT_DOC, 1, 65536, quality=True, sweep=(16, 64, 256, 1024, 4096)),
        "clamp_distance_rel": Param(1e-4, CLAMP_DOC, 1e-7, 1.0),
    }

    def prepare(self, gpu, scene, facts, params, view) -> None:
        self.params = params
        self.ctx = gpu.ctx
        self.eps = params["clamp_distance_rel"] * gpu.radius
        self.sampler = RsmVplSampler(gpu.ctx, params["vpl_count"])
        self.gather = VplGather(gpu.ctx, view.width, view.height)

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
