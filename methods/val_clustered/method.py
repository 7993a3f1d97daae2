"""`val_clustered`: real-time indirect illumination with clustered visibility (Dong, Grosch,
Ritschel, Kautz, Seidel, "Real-time Indirect Illumination with Clustered Visibility", VMV 2009).

Instant radiosity whose N VPLs are clustered into M << N virtual area lights (VALs); every
receiver is lit by all N VPLs, but visibility is computed for the M VALs only, with a soft
shadow per VAL, so a penumbra is a sum of soft shadows instead of N hard ones:

    L(x) = rho_x / pi * sum_i Phi_i / pi * <n_x, w_i>+ <n_i, -w_i>+ / d2_i * V_C(i)(x)

d2_i bounds the 1/d^2 of VPL i near a receiver (the near field the VPL methods share,
bench/gl/near_field.py): by default max(d_i^2, A_i / pi), a clamp at the radius of the area A_i
the VPL stands for. A VAL is by the paper's construction an area emitter, and so is each of its
VPLs: the point term's 1/d^2 made a handful of pixels of conference read 4-8 where Mitsuba has
0.002 (relMSE 164 at every rung: the same VPLs at every rung), 119 with the old 1e-4 R clamp
over 2 seeds, 0.26 with the bound (NOTES.md).

The measurements behind the corrections below (on `rooms`, the map stage's share of the frame)
are in NOTES.md beside this file. Needs: gbuffer, shadow_map, direct, rsm.

Per frame (stages, after the shared `gbuffer_shadow`, `direct_light`, `rsm`; stages 1-2 are
clustering.py, stage 3 shadow_maps.py):

1. `vpl_sample`: N VPLs from the reflective shadow map. Default (`vpl_sampling=importance`):
   importance-sampled exactly as `ir_unshadowed` / `ir_shadowed` (same code and frame 0's
   random numbers: identical VPLs for a given seed), which isolates the effect of the
   clustered visibility in comparisons. `vpl_sampling=halton`: the paper's point sampling of
   the RSM at N Halton locations (VPL flux = texel flux x texels / N, unlit texels give empty
   VPLs that no cluster takes). Either pattern is the same every frame of a seed (the paper's
   fixed QMC sequence). Only the Halton pattern gives the paper's temporal coherence when the
   light moves: the importance sampler's 1-D inverse CDF over row-major texels moves VPL k
   along a texel row when the flux changes slightly anywhere before it.
2. `val_clustering`: k-means on the GPU by scattering (paper Sec. 5, 6). VAL k starts at VPL
   k N / M, the same indices every frame (the paper's restart for temporal coherence). Each
   iteration draws one point per VPL whose vertex shader finds the nearest VAL under
   d = w_x |dx| / R + w_a angle(n_vpl, n_val) and scatters position, normal, flux and a count
   to that VAL's texel with additive blending; a compute pass divides by the count. A final
   scatter writes the mapping C (VPL -> VAL) and, with MAX blending, the bounding rectangle of
   the VPLs projected on the VAL's plane; the VAL's size is lambda = sqrt(its area).
3. `val_shadow_maps`: one paraboloid map per VAL (a tile of one R32F atlas), oriented around
   its normal. A compute pass (`map_split.glsl`) tests every (VAL, triangle) pair: pairs of an
   empty VAL, triangles behind the VAL's plane, inside its ignore radius or seen edge-on are
   dropped; a pair whose projected edges need no split and whose image's bounding box holds at
   most SPLAT_MAX_TEXELS = 64 texel centres is rasterised there (each covered texel centre gets
   the exact distance by an atomic minimum into an R32UI splat image, merged into the atlas);
   the others are listed for two draws with vertices pulled from the scene's buffers: plain
   triangles, and a tessellated draw for the pairs whose edges must bend (the projection turns
   straight edges into arcs; each edge is split into pieces whose chord strays at most
   TESS_SAGITTA_TEXELS = 0.5 texel from the arc, the level set from the projected edge length
   in map units per VAL and frame). Each texel stores the exact distance along its own
   direction to the plane of the triangle drawn there (an interpolated distance is off by
   percents across a tessellated piece). Then, for `visibility=cssm`: the map's far distance
   far_j (largest drawn distance, the depth normalisation), the Fourier basis and basis-z
   atlases (`fourier_terms` terms, same tiling; paper Sec. 6) and their MIP maps.
4. `val_visibility`: V_j(x) for every pixel and VAL (compute): parabolic CSSM (blocker
   search, penumbra estimate, MIP-filtered convolution of the basis, sharpened shadow test)
   or, with `visibility=hard`, one binary shadow-map test at the VAL centre; with
   `contact_test=plane` (the default) both are completed by the contact test (below).
5. `gather`: the sum above with interleaved sampling in `interleave` x `interleave` blocks
   (the paper: 8 x 8 blocks, 1024 VPLs -> 16 VPLs per pixel).
6. `blur`: geometry-aware blur over the block (alpha = 10% of the scene extent, beta = 0.8,
   Laine et al. 2007), its visible share taken over the pixels on this pixel's side of a contact
   shadow's edge (`blur_visibility_diff`, below); skipped when `interleave` = 1.

Defaults (issue #23): the paper's operating point (30 VALs of 1024 VPLs, parabolic CSSM) with
seven readings recorded below: the contact test (`contact_test=plane`), the map origin at the
cluster's medoid VPL with nothing ignored (`val_origin=medoid`, `near_ignore=0`), the CSSM kernel matched to a box of the paper's width
(`cssm_kernel=box`), 8 Fourier terms, the interleaved-sampling block scaled to the image
width (`interleave=0`: 3 x 3 at 320 x 180), and the blur's visible share taken over the pixels
on this pixel's side of a contact shadow's edge (`blur_visibility_diff=0.3`), and the CSM depths
mapped into [0, 1 - the step's ramp] (`csm_depth_range=ramp`). The paper's own setting, which lets light through
walls on large scenes (a VAL's visibility is its mean's, geometry within 0.5 lambda of it is
ignored, its soft-shadow kernel is wider than the paper's, the 4-term step ramps over metres and
contact blockers within that ramp are missed):
`val_origin=centre near_ignore=0.5 cssm_kernel=lod fourier_terms=4 interleave=8 contact_test=off
blur_visibility_diff=1 csm_depth_range=unit`.
At 320 x 180, 1 frame, seed 0, relMSE of `indirect` against the visible one-bounce reference
(image mean / reference), paper setting -> today's defaults: sponza 1.13 (1.10) -> 0.567 (0.91),
lost_empire 2.39 (1.32) -> 0.172 (0.86), sibenik 0.29 -> 0.109, conference 0.25 -> 0.080,
cornell_box 0.031 -> 0.022, holodeck 0.19 -> 0.027, rooms/far 10.2 -> 0.213 (mean 0.47: light
through door 1 from VALs whose map origin does not see through it; a perfect map per VAL gives
0.42 of per-VPL shadows); each below no indirect at all. How each reading moved these figures, in
order, with the commands: NOTES.md ("The defaults' history").

Opt-in corrections of issue #23 (default off; measurements in NOTES.md):
- `split_clusters=S` > 0: after the maps of the M VALs are drawn, each VPL is tested against
  its VAL's map (val_visibility's hard test, the VPL standing in for the receiver; facing away
  from the origin or behind its plane counts as hidden). `split_mode=reassign`: a hidden VPL
  goes to the nearest VAL (the paper's distance) whose origin sees it; the VPLs no VAL sees
  (`recluster`: every hidden VPL) are clustered again by the same k-means into up to S spare
  VALs (ceil(orphans x M / N) of them: the paper's VPLs per VAL), each with a map of its own,
  drawn in a second map pass. The paper's clustering is by position and normal only; this is a
  visibility-driven split of clusters that straddle occluders. It reads one count back (the
  number of orphans) in the frame.
- `behind_plane=horizon`: a receiver behind a VAL's plane (outside its hemispherical map) reads
  the map's horizon texel in its azimuth at its own distance instead of being fully visible
  (paper Sec. 5.1: "full visibility must be assumed here"). On top of the defaults: sponza
  0.61 -> 0.40 but at 0.76 of the reference's mean (outside issue #23's band), rooms unchanged.
- `val_size_scale` < 1: lambda a fraction of the side of the VPLs' bounding rectangle (the
  paper's area), i.e. smaller CSSM kernels; a fitted factor, not a derivation.

Limits: with `cluster_count` = `vpl_count`, `visibility=hard` and `interleave` = 1 every VAL is
one VPL with a hard shadow and the method is `ir_shadowed` up to the shadow-map
parameterisation (paraboloid vs hemicube) and the contact test (which only removes light ir_shadowed's
one-texel bias lets past blockers within it). Receivers behind a VAL's plane are taken as visible
(paper Sec. 5.1); geometry within `near_ignore` x lambda of a VAL's map origin is ignored (none
at the default 0).

Corrections and choices relative to the paper's text (recorded here as the house rule asks):
- Contact test (`contact_test=plane`, the default; `off` is the paper's): a blocker closer to the receiver than the CSM
  step's ramp cannot be told from the receiver's own surface (the truncated Fourier step of one
  texel falls from 1 to 0 over delta = 2.2% of the map's depth range with 8 terms and s = 3,
  4.5% with 4: `csm_step_band`, the root of 1 + 2 s sum_k sin(-c_k delta) / c_k = 0), and the
  hard test's one-texel bias misses it too; at such distances the paper's own penumbra estimate
  (alpha ~ lambda (d - z_avg) / z_avg d) is a small fraction of lambda: the hard-shadow limit.
  The map stores each texel's exact distance along its own centre direction, so the test
  compares it with the distance along that direction to the receiver's plane (through x, its
  geometric normal): a texel showing the receiver's plane compares equal whatever the slope,
  with no bias (tolerance CONTACT_TOLERANCE = 1e-3 of the distance, float rounding and gently
  curved meshes). For the 2 x 2 texels of a bilinear footprint around the lifted receiver's
  direction, a texel whose surface lies in front of the receiver's plane and less than the
  band in front of the lifted receiver is a candidate blocker. It blocks only if the surface it
  shows separates the map origin o from the receiver x: its local plane is reconstructed from
  the stored points of its neighbours (p_k = o + stored_k dir_k; along each map axis each side
  whose two texels continue the texel's distance, second difference within CONTACT_COPLANAR =
  5% of it, gives a tangent, each pair of tangents a candidate plane, as depth-buffer normal
  reconstruction does), and every candidate plane must have o and x on opposite sides, x more
  than CONTACT_TOLERANCE of the distance beyond it (a texel without a continuing neighbour
  along an axis, a feature one texel wide, blocks). A receiver beside an inside corner lies in
  front of the adjacent wall's own plane, on the origin's side, so the wall a neighbouring texel
  shows there does not darken it (the test without this darkened receivers within about half a
  map texel of concave corners: cornell_box +5%, hidden_bounce +40% relMSE, lost_empire's mean
  0.90 -> 0.83); a receiver under a lip or behind a wall lies beyond every candidate (beside a
  crease a candidate is the chord across it, which the requirement on every candidate covers).
  The separating texels block the share of the VAL they hide from x, read over the VAL's spot on
  them: the VAL (size lambda) seen from x through a blocker delta = d - stored in front of the
  lifted receiver (distance d) spans lambda delta / d there, i.e. W = lambda delta / (d stored a)
  map texels (a the texel's angle; W a is the paper's penumbra angle alpha = lambda (d - z) / (z d)
  at z = stored), a square centred on the receiver's direction. A texel k blocking at its own
  delta_k hides the part of its spot its cell covers, overlap(cell_k, spot_k) / W_k^2 of the VAL:
  b = sum_k overlap(cell_k, spot_k) / W_k^2, W_k at least one texel (then the bilinear weights of
  the 2 x 2 footprint: a point VAL or a blocker within the hard-shadow limit); a blocker as wide
  as the spot hides the whole VAL however large. The test runs where one of the bilinear 2 x 2
  texels blocks, over the window of the widest of their spots (at most CONTACT_SPOT_TEXELS = 8
  texels: a wider spot is counted inside it only, the rest left to the CSSM), and
  V = V_cssm (1 - b) (`visibility=hard`: band = the test's one-texel bias, lambda = 0, blocked
  when b >= 1/2). Found on holodeck (a lip 9 mm over a slot in a door panel hid the ceiling:
  Mitsuba 0.03, the method 0.6-1.0) and rooms (a zero-thickness wall 5-10 mm in front of
  receivers along its junctions); the rule before, the variants tried and dropped: NOTES.md.
  A coplanar surface on the far side of a zero-thickness wall (the side walls of `rooms` run
  through the junction) reads as the receiver's own plane, so about half of the junction's
  bilinear footprint still lets light through there.
  Cost: the `val_visibility` stage x1.56 on llvmpipe (holodeck at 320 x 180: 384 -> 600 ms,
  frame 818 -> 986 ms; the neighbours are fetched lazily and the first candidate plane with o
  and x on one side ends the test; NOTES.md). The spot window (2026-12-03) is not timed here: it
  is read only where a 2 x 2 texel blocks with a spot wider than one texel.
- Clustering distance: the paper's d = w_x dx + w_a da adds metres to radians, so the weights
  would depend on the scene's unit; dx is divided by the scene radius R here.
- Initial centres: "the VPL at index k-N/n" is k * N / M (VAL k of M).
- Penumbra (Fig. 3): p cos(beta) = (d - z_avg) lambda / z_avg and alpha = atan(p cos(beta) / d);
  the receiver slope beta cancels, alpha = atan(lambda (d - z_avg) / (z_avg d)) -> 0 for a
  point VAL (lambda = 0) or a contact blocker (z_avg = d): the hard-shadow limit holds.
- Kernel size: the paper's alpha / pi (texture width per half circle) is the map's scale only
  on average; the paraboloid map is conformal with 1 / (2 (1 + cos theta)) texture widths per
  radian at angle theta from the VAL normal, used here (alpha / pi is 27% too large at the
  centre and 36% too small at the rim).
- CSM shadow test: f(d, z) = 1/2 + 2 sum_k sin(c_k (z - d)) / c_k, c_k = pi (2k - 1) (lit for
  z > d). An unoccluded receiver reads its own surface (z = d, f = 1/2), so the filtered
  F = [w * f] must be rescaled; Annen et al.'s V = clamp(2 F, 0, 1) leaks: the 4-term step
  ramps over 7.6% of the depth range and its ringing lets up to 11% through an umbra (what that
  gave on `rooms`: NOTES.md). The default test is the scaled and biased reconstruction
  V = clamp(1 + s (F - 1/2), 0, 1) with s = `csm_sharpening` = 3 (s = 2 is Annen's): still 1
  at F = 1/2, 0 from F = 1/6, which removes the ringing and narrows the 4-term ramp to 4.5% of the
  range; the price is a darker penumbra (V = 1 - 1.5 b where a fraction b of the kernel is
  blocked by a distant occluder, instead of 1 - b). The blocker search uses the unscaled f.
- Depth normalisation: z = distance / far_j with far_j the largest distance drawn in VAL j's
  map (a reduction pass), not the scene's extent: the step's width is a fixed fraction of
  the range, so a tight range sharpens it in metres.
- Depth range of the Fourier step (`csm_depth_range=ramp`, the default; `unit` is Annen et al.'s
  and the paper's): the truncated step f(t) = 1/2 + 2 sum_k sin(c_k t) / c_k, t = z - d, has
  period 2 in t: besides its step at t = 0 it steps back at t = -1 (and +1) with the same ramp.
  With depths normalised to the whole [0, 1] a blocker near a map's origin (z ~ 0) in front of a
  receiver at the map's far end (d ~ 1, or beyond the farthest drawn point, where d is clamped to
  1) lies within that second ramp and reads lit (8 terms, s = 3: a blocker at z = 0.0075 before
  d = 1 gives V = 0.64, at z = 0.001 V = 0.95), and a distant texel (z ~ 1) behind a receiver
  near the origin (d a few hundredths) enters the blocker search as a partial blocker. The depths (and the receiver's d)
  now span [0, R], R = 1 - delta (delta = `csm_step_band`, the sharpened step's ramp), so |z - d|
  <= 1 - delta and every blocker delta or more in front of a receiver reads blocked; the step's
  ramp in metres widens by 1 / R (2.3% with 8 terms, s = 3), and the contact test's band with it.
  Found on rooms/far (VAL 20's origin 3 cm from the wall between rooms 1 and 2 lit room 3 through
  it, V 0.33 -> 0) and holodeck's lip (the other wrap darkened it); NOTES.md has the figures.
- Map origin (default `val_origin=medoid`, `near_ignore=0`): the paper places the area light at
  the cluster's centre, the mean of its VPLs, and since that may lie inside geometry (Fig. 7)
  ignores the geometry near it, which "can result in the loss of some existing shadows". The
  map's origin here is the cluster's VPL nearest that mean, lifted along its own normal as the
  centre is: a point on a lit surface, so nothing needs ignoring. The VAL's plane, normal and
  size stay the paper's. (On `rooms` a cluster's mean lay 1 cm from the wall between two rooms
  and its 1.4 m ignore radius let room 1's light through that wall.) `val_origin=centre` with
  `near_ignore=0.5` is the paper's.
- CSSM kernel (`cssm_kernel=box`): the paper's kernel w is a box alpha wide (alpha / pi of the
  texture). A trilinear lookup at MIP level L is the level's texel, a box 2^L base texels wide,
  convolved with the bilinear tent of half-width 2^L: variance 2^2L / 12 + 2^2L / 6 = 2^2L / 4,
  that of a box sqrt(3) 2^L wide. So a kernel of w texels is read at L = log2(w / sqrt(3)),
  whose variance is the box's (blocker search and filter alike); `lod` (L = log2 w, a kernel
  sqrt(3) times the paper's) is the former lookup.
- Fourier terms: 8 by default (paper: "4 term, 8 bit"). The CSM step ramps over a fixed share
  of each map's depth range (with s = 3: 4.5% for 4 terms, 2.2% for 8), tens of centimetres to
  metres on rooms and lost_empire, so a 4-term step lets light along wall junctions and under
  lost_empire's 1 m blocks (the contact-shadow weakness the paper names, Sec. 7.1). 8 terms
  double the basis atlases and their MIP maps.
- Interleaved sampling block (default `interleave=0`): the paper's "blocks of 8 x 8 = 64
  pixels" serve 800 x 800 images; the block is also the geometry-aware blur's window, an
  image-space footprint. At 320 x 180 an 8 x 8 block spans 2.5 times the paper's share of the
  image width, and where the blur rejects most of it (sponza's columns and arches) a pixel keeps
  its own 1/64 of the VPLs, weighted 64: bright blocks in dark regions. The default scales the
  block with the image width, B = max(1, round(8 width / 800)): 3 x 3 at 320 x 180 (114 VPLs
  per pixel), 1 (no interleaving, no blur) below 150 pixels.
- Map resolution: the paper's 256^2 maps serve 800 x 800 images (3 map texels per pixel for
  M = 30) and take 8% of its frame, the per-pixel gather 69%. At the benchmark's 128 x 96 the
  per-pixel stages are 50x cheaper while the maps are not, so the default is 128^2 (still 40
  map texels per pixel); 256 is a sweep value.
- Map rasterisation (issue #11): the paper draws every (VAL, triangle) pair ("the scene needs
  to be rendered once for each VAL", Sec. 6); on the software rasteriser each primitive costs a
  fixed set-up, and a tessellated one about 4x a plain one, whatever its size, while nearly
  every pair needs no split. So the compute pass above rasterises the small pairs (the same
  chord triangle, clip distances and exact per-texel distance as the draw; the maps agree with
  the all-tessellated pass on all but a handful of texels where a texel centre lies on a
  shared edge) and the GL pipeline gets the few large ones (the stage's share of the frame
  before and after: NOTES.md).
- The basis is kept in 2-D atlases tiled as the depth atlas instead of texture arrays: MIP
  maps of one atlas cost a third of those of a 30-layer array on the software rasteriser, and
  with power-of-two tiles no MIP texel mixes two maps; lookups are clamped half a texel of
  the coarser level inside the tile. `shadow_resolution` must be a power of two.
- The basis-z images (z sin, z cos, z) are made at half resolution, each texel the mean of
  2 x 2 map texels, i.e. exactly level 1 of their MIP chain: the blocker search reads them
  with a kernel of at least 2 texels (the VAL's extent seen from the receiver, usually far
  wider), and the basis images it is divided by are read at the same level.
- VAL records carry a fourth vec4, the map origin (the lifted centre, or the medoid with
  `val_origin=medoid`); VALs M .. M + S - 1 are the split round's (empty unless it fills them).
- The VAL "irradiance" texture holds the cluster's total flux (diagnostics); lighting uses
  the N VPLs themselves, as the paper does.
- The blur averages the unweighted gather (without receiver albedo), the albedo is applied
  after it, so that albedo edges stay sharp.
- Blur's visible share (`blur_visibility_diff` = 0.3; 1 is the paper's blur): the blur averages
  the B x B window's gathered sums, each over its own VPL subset, and with them their visibility:
  a pixel of a contact shadow next to a lit face with its normal a few centimetres in front of it
  (holodeck: the door's slot under the lip, the lip's front face one pixel row above, both well
  inside the paper's alpha = 10% of the scene extent) took half the face's light (the slot 0.27-0.29
  where Mitsuba has 0.01, after the contact test's spot rule above: 20 worst pixels 0.44 of the
  squared error). The unshadowed light is smooth across such an edge, the visible share is not.
  So the gather also writes the luminance of each pixel's sum without visibility (alpha) and the
  blur keeps the window's mean (over all B^2 subsets) but replaces its visible share (the window's
  shadowed over unshadowed luminance) by that over the pixels whose VAL-level visible share
  s = sum_j U_j V_j / sum_j U_j (U_j = lum(Phi_j) cos cos / max(d^2, lambda_j^2 / pi), VAL j as
  one area light at its centre; written by `val_visibility`, free of the subsets' noise) is not
  above this pixel's by more than 0.3, nor below it by more than 0.3 across a step (the neighbour
  off this pixel's tangent plane by a sine over BLUR_STEP_SINE = 0.5). A much darker neighbour on
  the same plane is kept, as in the paper's blur: there it is as often this pixel's own leak being
  diluted (rooms' wall junctions, the contact test's remaining misses) as a shadow edge. Where no
  test fires the result is the paper's blur exactly (the variants tried and dropped: NOTES.md).

Parameters:

<!-- parameters: generated from the Param declarations by `gibench manuals --write` -->
| parameter            | default    | range                          | meaning |
|----------------------|------------|--------------------------------|---|
| vpl_count            | 1024       | 1 .. 8192                      | VPLs drawn from the RSM per frame, as vpl_sampling says (paper: 1024) |
| vpl_sampling         | importance | importance, halton             | VPL pattern: the shared RSM importance sampler (the IR baselines' VPLs) or the paper's Halton point sampling of the RSM |
| cluster_count        | 30         | 1 .. 256                       | virtual area lights M (k-means clusters of the VPLs; paper: 30) (quality knob; sweep 5, 10, 20, 30, 60) |
| kmeans_iterations    | 8          | 0 .. 64                        | k-means iterations per frame (0: the initial centres only) |
| weight_position      | 0.7        | 0.0 .. 10.0                    | w_x: clustering weight of the position difference (per scene radius) |
| weight_angle         | 0.3        | 0.0 .. 10.0                    | w_a: clustering weight of the normal angle (per radian) |
| visibility           | cssm       | cssm, hard                     | per-VAL visibility: soft (parabolic CSSM) or one hard shadow test |
| shadow_resolution    | 128        | 16 .. 1024                     | paraboloid shadow map resolution per VAL (texels, a power of two; paper: 256) (quality knob; sweep 64, 128, 256) |
| fourier_terms        | 8          | 4, 8                           | Fourier terms of the convolution shadow maps (paper: 4) |
| csm_depth_range      | ramp       | ramp, unit                     | share of the Fourier step's period the normalised map depths use: [0, 1 - the sharpened step's ramp], so that no blocker in front of a receiver reaches the step's periodic wrap at z - d = -1 (ramp), or the whole [0, 1] (unit, Annen et al.'s and the paper's) |
| csm_sharpening       | 3.0        | 2.0 .. 16.0                    | slope s of the scaled CSM shadow test V = clamp(1 + s (F - 1/2), 0, 1) (2: Annen et al.'s plain scaling) |
| split_clusters       | 0          | 0 .. 256                       | spare VALs S for the split round: the VPLs their VAL's map origin does not see are clustered again into up to S more VALs with maps of their own (0: the paper's clustering alone) |
| split_mode           | reassign   | reassign, recluster            | a VPL its VAL's origin does not see: to the nearest VAL whose origin sees it, else to the split round (reassign), or straight to the split round (recluster) |
| val_size_scale       | 1.0        | 0.01 .. 4.0                    | VAL size lambda as a fraction of the side of the square of its VPLs' bounding rectangle's area (the paper's: 1) |
| cssm_kernel          | box        | box, lod                       | CSSM kernel of width w texels as a trilinear MIP lookup: at level log2(w / sqrt(3)), whose variance is the box's (box), or at log2(w) (lod) |
| val_origin           | medoid     | medoid, centre                 | origin of a VAL's map: the cluster's mean position (centre, the paper's) or its VPL nearest that mean (medoid) |
| behind_plane         | visible    | horizon, visible               | visibility of a receiver behind a VAL's plane, outside its map: the paper's full visibility (visible) or the map's horizon in its direction (horizon) |
| near_ignore          | 0.0        | 0.0 .. 4.0                     | ignore geometry closer to a VAL's map origin than this times the VAL size (paper: 0.5, with the origin at the cluster's centre) |
| contact_test         | plane      | off, plane                     | blockers the shadow test cannot resolve (within the CSM step's ramp, or the hard test's one-texel bias, in front of the receiver): tested exactly against the receiver's own plane along each texel's direction, counted where the blocker's plane separates the map origin from the receiver (plane), or not (off, the paper's) |
| normal_offset        | 0.5        | 0.0 .. 16.0                    | receiver offset along its geometric normal for the VAL shadow test, in map texel footprints at the receiver |
| interleave           | 0          | 0 .. 16                        | interleaved sampling block size B (B x B pixels share the VPLs; 1: off, no blur; 0: the paper's 8 x 8 blocks of an 800-pixel-wide image scaled to the image width, max(1, round(8 width / 800))) |
| blur_distance_rel    | 0.1        | 0.0 .. 10.0                    | geometry-aware blur alpha: max position difference / scene extent (2R) |
| blur_normal_dot      | 0.8        | -1.0 .. 1.0                    | geometry-aware blur beta: min dot product of the normals |
| blur_visibility_diff | 0.3        | 0.0 .. 1.0                     | geometry-aware blur: the window's visible share (shadowed over unshadowed gathered light) is taken over the pixels whose VAL-level visible share is not above this pixel's by more than this, nor below it by more across a step of the surface (1: the paper's blur) |
| clamp_distance_rel   | 0.0001     | 1e-07 .. 1.0                   | distance clamp eps of max(eps, distance) relative to the scene radius (tames the 1/d^2 singularity) |
| near_field           | footprint  | clamp, disc_element, footprint | how an emitter's 1/d^2 is bounded near it, d the emitter-receiver distance, A the area it stands for: clamp max(eps, d)^2; disc_element d^2 + A / pi (a disc's form factor); footprint max(d^2, s A / pi) (a clamp at the radius of s times the emitter's area); each at least eps^2 |
| near_field_scale     | 1.0        | 0.001 .. 100.0                 | s of near_field=footprint: the clamp's area as a fraction of the area the emitter stands for |
<!-- end of parameters -->

Quality ladder (fast -> accurate; `ladder`): {cluster_count 10, shadow_resolution 64},
{cluster_count 20}, {} (the paper's 30 VALs at 128^2), {cluster_count 60, shadow_resolution 256}.
The two knobs that trade time for visibility error together: more VALs give finer clusters
(smaller penumbra errors), a finer map sharper occluders; the VPL count stays at the paper's
1024 on every rung (the IR baselines are compared at the same count).

Memory: the basis atlases hold (tiles >= cluster_count) x shadow_resolution^2 x
(2 x fourier_terms + (2 x fourier_terms + 1) / 4) half floats (+1/3 for MIP maps), the visibility array width x height x
cluster_count floats, the map pass's pair list 4 x min(cluster_count x triangles, MAX_MAP_PAIRS)
bytes (16 MiB at most: triangles are processed in chunks); a combination over 1 GiB, an atlas over GL_MAX_TEXTURE_SIZE, or a
shadow_resolution that is not a power of two is refused in prepare() with an error naming the
parameters.

Example: `gibench run --scenes rooms --methods val_clustered,ir_shadowed --res 128x96 --param
val_clustered.visibility=cssm,hard` (soft CSSM against one hard shadow test per VAL).

In motion (bench.run.sequence): It keeps nothing between states: a frame where anything moved
prepares it again (programs, cluster and shadow buffers); the VPLs and their clustering are per
frame anyway. Measured update per moved frame at 160x90, light (rooms_light_sweep) 181 ms, camera
(sponza_camera_walk) 138 ms, geometry (cornell_spot_moving_block) 116 ms (`python -m
studies.motion_costs`, 2 cores shared with other work).

Stress limit params:vpl_count=1: fewer VPLs than `cluster_count` (30) cannot be clustered into that many VALs; prepare() refuses it with one line naming both parameters.
"""
from __future__ import annotations

import math

import moderngl
import numpy as np
from scipy.optimize import brentq

from bench.gl import load_compute, load_program, set_uniforms
from bench.gl.context import loop_chunks, park
from bench.gl.passes import frame_random
from bench.protocol.method import FrameOutput, MethodBase, Param, ParamError
from bench.gl.vpl import CLAMP_DOC
from bench.gl.near_field import (NEAR_FIELD_DEFAULT, NEAR_FIELD_DOC, NEAR_FIELDS, NEAR_SCALE_DEFAULT,
                                   NEAR_SCALE_DOC, NEAR_SCALE_RANGE, near_field_defines)
from bench.gl.vpl import RsmVplSampler

from .clustering import SHADERS, HaltonVplSampler, ValClustering
from .shadow_maps import ParaboloidShadowMaps

BLOCKER_MIN = 0.02                   # filtered blocker fraction below which a receiver is unoccluded
MAX_BASIS_BYTES = 1 << 30
MAX_VALS = 256                       # VALs in all, spare ones included (shadow_maps.PAIR_TRIANGLE_BITS)
GL_R32F = 0x822E
PAPER_BLOCK, PAPER_WIDTH = 8, 800          # interleaved sampling: 8 x 8 blocks at 800 x 800 (paper Sec. 6)
KERNEL_SCALES = {"box": 1.0 / math.sqrt(3.0), "lod": 1.0}
CONTACT_TOLERANCE = 1e-3             # contact test: a stored distance within this fraction of the receiver plane's is that plane
CONTACT_COPLANAR = 0.05              # contact test: a neighbour texel off p0's surface by more than this fraction of the distance
CONTACT_SPOT_TEXELS = 8              # contact test: the widest window (map texels) read for a VAL's spot on a blocker
BLUR_STEP_SINE = 0.5                 # blur: a neighbour off the pixel's tangent plane by more than this sine is across a step


def csm_step_band(terms: int, sharpening: float) -> float:
    """The normalised depth delta behind a blocker at which the sharpened CSM test of one texel,
    clamp(1 + s (f - 1/2), 0, 1) with f = 1/2 + 2 sum_k sin(c_k (z - d)) / c_k, c_k = pi (2k - 1),
    first reaches 0 (the step's ramp: 0.022 for 8 terms and s = 3, 0.045 for 4 terms)."""
    c = math.pi * (2.0 * np.arange(1, terms + 1) - 1.0)
    return float(brentq(lambda delta: 2.0 * np.sum(np.sin(-c * delta) / c) + 1.0 / sharpening, 1e-9, 0.5 / terms))


def csm_depth_range(band: float) -> float:
    """The share [0, R] of the unit depth range that a map's normalised depths (and receivers) use:
    the truncated Fourier step f(z - d) has period 2 and steps back at z - d = -1 with the same
    ramp, so R = 1 - band (the sharpened step's ramp, `csm_step_band`) keeps every blocker in front
    of a receiver at least the ramp away from that second step (with the unit range a blocker near
    a map's origin in front of a receiver at its far end read as lit)."""
    return 1.0 - band


def interleave_block(interleave: int, width: int) -> int:
    """The interleaved-sampling block size B: `interleave`, or for 0 the paper's 8 x 8 blocks of an
    800-pixel-wide image scaled to `width` (rounded half up, at least 1)."""
    return interleave or max(1, int(PAPER_BLOCK * width / PAPER_WIDTH + 0.5))


class ClusteredVirtualAreaLights(MethodBase):
    name = "val_clustered"
    summary = "Instant radiosity with VPLs clustered into virtual area lights with soft (CSSM) visibility"
    stages = ("vpl_sample", "val_clustering", "val_shadow_maps", "val_visibility", "gather", "blur")
    needs = frozenset({"gbuffer", "shadow_map", "direct", "rsm"})
    ladder = ({"cluster_count": 10, "shadow_resolution": 64}, {"cluster_count": 20}, {},
              {"cluster_count": 60, "shadow_resolution": 256})
    params = {
        "vpl_count": Param(1024, "VPLs drawn from the RSM per frame, as vpl_sampling says (paper: 1024)", 1, 8192),
        "vpl_sampling": Param("importance", "VPL pattern: the shared RSM importance sampler (the IR baselines' "
                              "VPLs) or the paper's Halton point sampling of the RSM", choices=("importance", "halton")),
        "cluster_count": Param(30, "virtual area lights M (k-means clusters of the VPLs; paper: 30)", 1, 256,
                               quality=True, sweep=(5, 10, 20, 30, 60)),
        "kmeans_iterations": Param(8, "k-means iterations per frame (0: the initial centres only)", 0, 64),
        "weight_position": Param(0.7, "w_x: clustering weight of the position difference (per scene radius)", 0.0, 10.0),
        "weight_angle": Param(0.3, "w_a: clustering weight of the normal angle (per radian)", 0.0, 10.0),
        "visibility": Param("cssm", "per-VAL visibility: soft (parabolic CSSM) or one hard shadow test",
                            choices=("cssm", "hard")),
        "shadow_resolution": Param(128, "paraboloid shadow map resolution per VAL (texels, a power of two; "
                                        "paper: 256)", 16, 1024, quality=True, sweep=(64, 128, 256)),
        "fourier_terms": Param(8, "Fourier terms of the convolution shadow maps (paper: 4)", choices=(4, 8)),
        "csm_depth_range": Param("ramp", "share of the Fourier step's period the normalised map depths use: "
                                         "[0, 1 - the sharpened step's ramp], so that no blocker in front of a "
                                         "receiver reaches the step's periodic wrap at z - d = -1 (ramp), or the "
                                         "whole [0, 1] (unit, Annen et al.'s and the paper's)",
                                 choices=("ramp", "unit")),
        "csm_sharpening": Param(3.0, "slope s of the scaled CSM shadow test V = clamp(1 + s (F - 1/2), 0, 1) "
                                     "(2: Annen et al.'s plain scaling)", 2.0, 16.0),
        "split_clusters": Param(0, "spare VALs S for the split round: the VPLs their VAL's map origin does not "
                                    "see are clustered again into up to S more VALs with maps of their own "
                                    "(0: the paper's clustering alone)", 0, 256),
        "split_mode": Param("reassign", "a VPL its VAL's origin does not see: to the nearest VAL whose origin "
                                        "sees it, else to the split round (reassign), or straight to the split "
                                        "round (recluster)", choices=("reassign", "recluster")),
        "val_size_scale": Param(1.0, "VAL size lambda as a fraction of the side of the square of its VPLs' "
                                     "bounding rectangle's area (the paper's: 1)", 0.01, 4.0),
        "cssm_kernel": Param("box", "CSSM kernel of width w texels as a trilinear MIP lookup: at level log2(w / "
                                    "sqrt(3)), whose variance is the box's (box), or at log2(w) (lod)",
                             choices=("box", "lod")),
        "val_origin": Param("medoid", "origin of a VAL's map: the cluster's mean position (centre, the paper's) "
                                      "or its VPL nearest that mean (medoid)", choices=("medoid", "centre")),
        "behind_plane": Param("visible", "visibility of a receiver behind a VAL's plane, outside its map: the "
                                         "paper's full visibility (visible) or the map's horizon in its direction (horizon)",
                              choices=("horizon", "visible")),
        "near_ignore": Param(0.0, "ignore geometry closer to a VAL's map origin than this times the VAL size "
                                  "(paper: 0.5, with the origin at the cluster's centre)", 0.0, 4.0),
        "contact_test": Param("plane", "blockers the shadow test cannot resolve (within the CSM step's ramp, or the "
                                       "hard test's one-texel bias, in front of the receiver): tested exactly against "
                                       "the receiver's own plane along each texel's direction, counted where the "
                                       "blocker's plane separates the map origin from the receiver (plane), or not "
                                       "(off, the paper's)", choices=("off", "plane")),
        "normal_offset": Param(0.5, "receiver offset along its geometric normal for the VAL shadow test, "
                                    "in map texel footprints at the receiver", 0.0, 16.0),
        "interleave": Param(0, "interleaved sampling block size B (B x B pixels share the VPLs; 1: off, no "
                               "blur; 0: the paper's 8 x 8 blocks of an 800-pixel-wide image scaled to the "
                               "image width, max(1, round(8 width / 800)))", 0, 16),
        "blur_distance_rel": Param(0.1, "geometry-aware blur alpha: max position difference / scene extent "
                                        "(2R)", 0.0, 10.0),
        "blur_normal_dot": Param(0.8, "geometry-aware blur beta: min dot product of the normals", -1.0, 1.0),
        "blur_visibility_diff": Param(0.3, "geometry-aware blur: the window's visible share (shadowed over "
                                           "unshadowed gathered light) is taken over the pixels whose VAL-level "
                                           "visible share is not above this pixel's by more than this, nor below "
                                           "it by more across a step of the surface (1: the paper's blur)",
                                           0.0, 1.0),
        "clamp_distance_rel": Param(1e-4, CLAMP_DOC, 1e-7, 1.0),
        "near_field": Param(NEAR_FIELD_DEFAULT, NEAR_FIELD_DOC, choices=NEAR_FIELDS),
        "near_field_scale": Param(NEAR_SCALE_DEFAULT, NEAR_SCALE_DOC, *NEAR_SCALE_RANGE),
    }

    @classmethod
    def cost_terms(cls, params, size):
        clusters = params["cluster_count"]
        return {"pixel_clusters": size.pixels * clusters,                            # per-pixel VAL gather
                "cluster_triangles": clusters * size.triangles,                     # a shadow map per VAL
                "cluster_shadow_texels": clusters * params["shadow_resolution"] ** 2,
                "vpls": params["vpl_count"]}                                        # k-means over the VPLs

    def prepare(self, gpu, scene, facts, params, view) -> None:
        self.params = params
        self.ctx = ctx = gpu.ctx
        n, m = params["vpl_count"], params["cluster_count"]
        if m > n:
            raise ParamError(f"method 'val_clustered': cluster_count={m} is more than vpl_count={n}")
        if params["weight_position"] == 0.0 and params["weight_angle"] == 0.0:
            raise ParamError("method 'val_clustered': weight_position and weight_angle are both 0")
        cssm = params["visibility"] == "cssm"
        res = params["shadow_resolution"]
        groups = params["fourier_terms"] // 4
        if res & (res - 1):
            raise ParamError(f"method 'val_clustered': shadow_resolution={res} is not a power of two (the MIP "
                             f"levels of the map atlases must not mix the maps of neighbouring VALs)")
        spare = min(params["split_clusters"], MAX_VALS - m)   # the map pass encodes a VAL in 8 bits
        m_all = m + spare
        tiles = math.ceil(math.sqrt(m_all)) * math.ceil(m_all / math.ceil(math.sqrt(m_all)))
        basis_bytes = tiles * res * res * (8 * groups + (8 * groups + 1) // 4) * 2 * 4 // 3 if cssm else 0
        if basis_bytes > MAX_BASIS_BYTES:
            raise ParamError(f"method 'val_clustered': cluster_count={m} x shadow_resolution={res} x "
                             f"fourier_terms={params['fourier_terms']} needs {basis_bytes / 2**30:.1f} GiB of "
                             f"basis maps, over {MAX_BASIS_BYTES / 2**30:.0f} GiB")
        visibility_bytes = view.width * view.height * m_all * 4
        if visibility_bytes > MAX_BASIS_BYTES:
            raise ParamError(f"method 'val_clustered': cluster_count={m} at {view.width}x{view.height} needs "
                             f"{visibility_bytes / 2**30:.1f} GiB of per-pixel VAL visibility, over "
                             f"{MAX_BASIS_BYTES / 2**30:.0f} GiB")
        self.width, self.height = view.width, view.height
        self.interleave = interleave_block(params["interleave"], view.width)
        self.eps = params["clamp_distance_rel"] * gpu.radius
        self.radius = gpu.radius
        sampler_cls = HaltonVplSampler if params["vpl_sampling"] == "halton" else RsmVplSampler
        self.sampler = sampler_cls(ctx, n)
        self.clustering = ValClustering(gpu, n, m, (params["weight_position"], params["weight_angle"]),
                                        spare_count=spare,
                                        origin_medoid=params["val_origin"] == "medoid",
                                        split_reassign=params["split_mode"] == "reassign",
                                        size_scale=params["val_size_scale"])
        m = self.clustering.cluster_count   # VALs and maps in all, the spare ones included
        self.contact_band = csm_step_band(params["fourier_terms"], params["csm_sharpening"])
        self.maps = ParaboloidShadowMaps(gpu, self.clustering, res, cssm, groups, params["near_ignore"],
                                         depth_range=csm_depth_range(self.contact_band)
                                         if params["csm_depth_range"] == "ramp" else 1.0)
        defines = dict(self.maps.defines, VISIBILITY_CSSM=int(cssm), BEHIND_HORIZON=int(params["behind_plane"] == "horizon"),
                       CONTACT_TEST=int(params["contact_test"] == "plane"),
                       CONTACT_TOLERANCE=CONTACT_TOLERANCE, CONTACT_COPLANAR=CONTACT_COPLANAR,
                       CONTACT_SPOT_TEXELS=CONTACT_SPOT_TEXELS, BLUR_STEP_SINE=BLUR_STEP_SINE,
                       **near_field_defines(params["near_field"], params["near_field_scale"]))
        self.visibility_pass = load_compute(ctx, SHADERS / "val_visibility.glsl", defines)
        self.visibility = ctx.texture_array((view.width, view.height, m), 1, dtype="f4")
        self.visibility.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.visible_share = ctx.texture((view.width, view.height), 1, dtype="f4")
        self.visible_share.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.gather_prog = load_program(ctx, SHADERS / "gather.glsl", defines)
        self.gather_vao = ctx.vertex_array(self.gather_prog, [])
        self.gathered = ctx.texture((view.width, view.height), 4, dtype="f4")
        self.gathered.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.gather_fbo = ctx.framebuffer([self.gathered])
        self.blur_prog = load_program(ctx, SHADERS / "blur.glsl", defines)
        self.blur_vao = ctx.vertex_array(self.blur_prog, [])
        self.indirect = ctx.texture((view.width, view.height), 4, dtype="f4")
        self.indirect.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.blur_fbo = ctx.framebuffer([self.indirect])

    def render(self, frame, prof) -> FrameOutput:
        ctx, passes, p = self.ctx, frame.passes, self.params
        interleave = self.interleave
        with prof.stage("vpl_sample"):
            # one VPL pattern for every frame of a seed (the paper's fixed QMC sequence), so that
            # a static scene keeps its VPLs and VALs; frame 0's equals ir_shadowed's
            self.sampler.sample(passes.rsm, frame_random(frame.seed, 0, 0))
        with prof.stage("val_clustering"):
            self.clustering.run(self.sampler, p["kmeans_iterations"])
        with prof.stage("val_shadow_maps"):
            clustering, maps = self.clustering, self.maps
            if clustering.spare_count == 0:
                maps.render()
            else:
                maps.render(0, clustering.main_count, finish=False)
                clustering.split(self.sampler, maps, p["normal_offset"])
                orphans = clustering.read_split_stats()["orphans"]
                spare = min(clustering.spare_count, math.ceil(orphans * clustering.main_count / clustering.vpl_count))
                self.split_vals = spare
                if spare:
                    clustering.run(self.sampler, p["kmeans_iterations"], split_round=True, spare=spare)
                maps.render(clustering.main_count, clustering.main_count + spare, finish=True)
                clustering.recount()
        with prof.stage("val_visibility"):
            prog = self.visibility_pass
            self.clustering.bind()
            set_uniforms(prog, **self.clustering.common)
            unit = passes.gbuffer.bind(prog)
            self.maps.bind(prog, unit)
            set_uniforms(prog, u_normal_offset=float(p["normal_offset"]), u_size=(self.width, self.height),
                         u_blocker_min=BLOCKER_MIN, u_csm_sharpening=float(p["csm_sharpening"]),
                         u_kernel_scale=KERNEL_SCALES[p["cssm_kernel"]], u_contact_band=self.contact_band)
            self.visibility.bind_to_image(5, read=False, write=True, level=0, format=GL_R32F)
            self.visible_share.bind_to_image(6, read=False, write=True, level=0, format=GL_R32F)
            prog.run(group_x=(self.width + 7) // 8, group_y=(self.height + 7) // 8)
            ctx.memory_barrier()
        with prof.stage("gather"):
            fbo = self.blur_fbo if interleave == 1 else self.gather_fbo
            fbo.use()
            ctx.viewport = (0, 0, self.width, self.height)
            fbo.clear(0.0, 0.0, 0.0, 0.0)
            ctx.disable(moderngl.DEPTH_TEST)
            ctx.enable(moderngl.BLEND)  # additive: each draw sums one chunk of the VPLs
            ctx.blend_func = moderngl.ONE, moderngl.ONE
            prog = self.gather_prog
            unit = passes.gbuffer.bind(prog)
            self.visibility.use(unit)
            set_uniforms(prog, u_visibility=unit, u_interleave=interleave, u_apply_albedo=interleave == 1,
                         u_eps=float(self.eps))
            self.sampler.bind()
            self.clustering.bind()
            # the loop limit counts iterations: a draw scans chunk * B^2 VPL indices
            for first, end in loop_chunks(self.sampler.vpl_count, 16384 * interleave * interleave):
                set_uniforms(prog, u_vpl_first=first, u_vpl_end=end)
                self.gather_vao.render(moderngl.TRIANGLES, vertices=3)
            ctx.disable(moderngl.BLEND)
        skipped = ()
        if interleave > 1:
            with prof.stage("blur"):
                self.blur_fbo.use()
                ctx.viewport = (0, 0, self.width, self.height)
                prog = self.blur_prog
                unit = passes.gbuffer.bind(prog)
                self.gathered.use(unit)
                self.visible_share.use(unit + 1)
                set_uniforms(prog, u_gathered=unit, u_visible_share=unit + 1, u_interleave=interleave,
                             u_max_distance=float(p["blur_distance_rel"] * 2.0 * self.radius),
                             u_min_normal_dot=float(p["blur_normal_dot"]),
                             u_max_visibility_diff=float(p["blur_visibility_diff"]))
                self.blur_vao.render(moderngl.TRIANGLES, vertices=3)
        else:
            skipped = ("blur",)
        return FrameOutput(direct=passes.direct.radiance, indirect=self.indirect, skipped_stages=skipped)

    def release(self) -> None:
        if getattr(self, "ctx", None) is None:
            return
        park(self.ctx)
        for name in ("blur_fbo", "indirect", "blur_vao", "blur_prog", "gather_fbo", "gathered", "gather_vao",
                     "gather_prog", "visible_share", "visibility", "visibility_pass", "maps", "clustering", "sampler"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.release()
                setattr(self, name, None)
