"""`flc`: Forward Light Cuts (Laurent, Delalandre, de La Rivière, Boubekeur, EGSR 2016).

One-bounce diffuse indirect lighting without indirect visibility, estimated without bias from
the many-lights sum of eq. 4 over the scene's surfaces,

    L_ML(x) = sum_t H(t, x, n_x) A(t),
    H = rho_x / pi * L_t(y_t -> x) <n_x, xy>+ <n_t, yx>+ / max(eps, |x - y_t|)^2,
    L_t(w) = rho_t E(t) 3/(2 pi) <n_t, w>+                                     (eq. 5, 6)

by a stochastic multiscale cut computed forward, every frame, with no precomputation. E(t) is
the shadowed direct irradiance at the VPL, its cosine taken against the interpolated shading
normal there, and the side of that normal a receiver lies on picks which side's radiosity it
sees (as Mitsuba's two-sided diffuse and `manylights`); the emission lobe <n_t, yx>, the support
balls and the area use the face. A VPL lit on one side emits on that side.

1. Alg. 2: every vertex carries a uint32 `v_rand` (set at load); a triangle's key is the xor
   of its three v_rand; its level draw is the PCG hash of key xor u_rand (u_rand new every
   frame). The interleaving tile and the VPL jitter use their own per-frame values (independent
   streams of `frame.random_u32`).
2. Alg. 1: S_0 = 4 pi D_near^2 / N_avg (eq. 1), S_k = S_0 mu^k (eq. 17), S_bar_k =
   1 / sum_{j<=k} 1/S_j; a triangle goes to the first level k with u < A / S_bar_k, else it is
   discarded. Triangles with A > S_bar_N are divergent.
3. Regular pass (stage `regular`): first the GBuffer's receivers are deinterleaved into the
   tiled layout (`deinterleave.glsl`: the split G-buffer of interleaved sampling, one texel per
   splat fragment holding position and an octahedral 2 x 16-bit normal: a splat fragment reads
   one texel beside its neighbours' instead of two 2^L pixels apart). Then, with
   `regular_selection = compute` (default), a compute pass (`select_regular.glsl`) makes the
   geometry shader's cheap decision for every triangle (divergent, or kept by Alg. 1's level
   draw with the same key and hash) and compacts the kept ones in scene order (an ordered scan,
   not an atomic append: same blending order, so the image is bit for bit the single draw's;
   tested); the draw (`render_indirect`, no read-back) carries only those. The paper's one draw
   of the whole scene is `regular_selection = single_draw`. Then one draw: its geometry shader
   classifies each triangle, appends divergent ones to a storage buffer and atomically grows an
   indirect draw command, and turns each kept regular triangle into one VPL, uniformly jittered
   over the triangle (`jitter`; at the centroid when off), with the shadowed direct radiosity
   rho E of both sides, emitted as a quad over the exact screen-space bound of its support (the
   ball on each lit side, Mara & McGuire's tangent bound; a ball crossing the near plane takes
   the whole screen) in one random interleaved-sampling tile. The fragment stage reads the
   GBuffer and adds H S_k f^k(d), d = |x - y| / |<n_t, (x - y)/|x - y|>| (eq. 10, 14).
4. Divergent pass (stage `divergent`): the buffer drawn with `render_indirect` (no CPU
   read-back) as patches through the tessellator, at the smallest uniform level whose largest
   piece is regular (measured once on the tessellator, `tessellation.py`). A divergent triangle
   is appended as m^2 equal sub-patches, each small enough for level 8 (`TESS_SUB_LEVEL`), and
   only the sub-patches a light can reach: one is left out when every light is a spot whose
   cutoff cone misses its bounding sphere (a conservative test; point and directional lights
   reach every two-sided surface). A left-out piece would be a VPL of zero power (E = 0 on both
   sides), which the splat drops anyway, so the estimate is unchanged (no bias); the pass's
   work then follows the lit area instead of the scene's. A piece's key is the base triangle's
   v_rand xor the noise texture at its three vertices' barycentric coordinates (Alg. 2,
   Fig. 8); then the same splat. The buffer is sized from the scene facts for all sub-patches
   (a row needing more than 128 MB is skipped). Skipped (and recorded as skipped) when the
   scene facts say no triangle is divergent, or with `divergent_pass` off (divergent triangles
   are then dropped: Fig. 7 top). The command is reset by a GPU buffer copy and the pass waits
   on a command + storage memory barrier only (no CPU upload, no full barrier in a frame).
5. Stage `upscale_blur`: untile the 4^L tiles and a separable geometry-aware tent blur (each
   tile's samples linearly interpolated, every tile weighing the same), then rho_x / pi.

Against which sum it is unbiased. A triangle (piece) lands in level k with probability A / S_k
and then weighs F^k = S_k f^k, so E[K] = sum_t H A sum_k f^k: unbiased wherever the f^k sum to
1, which with the last level unbounded (the default) is everywhere. With `jitter` (the default)
each VPL is uniform over its triangle or tessellated piece, so a single frame's expectation is
the integral of eq. 4 over every triangle: the limit of `manylights` with `emission=flc` and
many `jitter_frames` (jittered `manylights`), not centroid `manylights` (one VPL at each whole
triangle's centroid: divergent triangles are split here, so the sums differ). With `jitter`
off a frame is unbiased only for the centroid sum over the pieces the divergent pass makes
(a sum no `manylights` setting computes). Interleaved sampling keeps the expectation (a VPL
splats into one of T = 4^L tiles at random with weight T); the blur is the one spatial bias.
With `last_level_unbounded` false (the paper's eq. 16 literally) pairs with d > D_N are cut
(`studies/flc_analysis.py`, `energy_beyond_support`). Progressive mode averages F sub-frames
inside one render(); for regular triangles its jitter is the same as `manylights`' jitter
frame j, so the two converge together.

Corrections to the paper (details and derivations in `levels.py`):
- eq. 3 prints P(t in L^k) = A / S_bar_k; by Alg. 1 that is the probability of levels 0..k.
  The level-k probability is A / S_k, which is what makes eq. 9 hold with F^k = S_k f^k.
- eq. 16 prints f^0 = 1 on ]0, D_1], overlapping f^1's ramp on ]D_0, D_1] (sum > 1 there).
  We use hats that sum to 1: f^0 = 1 up to D_0 and falls to 0 at D_1; f^k rises on
  ]D_{k-1}, D_k] and falls on ]D_k, D_{k+1}]; f^N = 1 beyond D_N (unbounded, default).
- eq. 18 prints D_k = sqrt(S_k): every level then reaches a receiver with a fixed handful of
  VPLs (about 4 pi) whatever N_avg, and the reach D_N shrinks as N_avg grows (2.84, 1.42,
  0.71 R_scene for N_avg 64, 256, 1024 at mu 4, N 5), against eq. 1's intent (N_avg VPLs within
  D_near of a pixel) and Fig. 10 (N_avg "the approximate number of VPLs influencing every
  pixel", time proportional to it). From eq. 1's model (surface within distance D: 4 pi D^2;
  level k: one VPL per S_k) N_avg VPLs of every level reach a receiver when
  4 pi D_k^2 / S_k = N_avg, i.e. D_k = D_near mu^(k/2) (`reach="eq1_intent"`, default; D_0 =
  D_near). `reach="eq18_printed"` keeps the literal print for comparison.

Near field (`near_field = disc_element`, default): eq. 5 clamps d_i = max(eps, |x - y|) with eps
a user parameter "to avoid singularities". A level-k VPL stands for S_k of surface (its weight in
eq. 10), so we give it the singularity of that surface rather than a point's: d_i^2 = |x - y|^2 +
r_k^2 with r_k = sqrt(S_k / pi) the radius of the disc of area S_k, i.e. H S_k = L <n_x, xy>
<n_t, yx> S_k / (pi |x - y|^2 + S_k), the form factor of a disc element (Bunnell, GPU Gems 2
ch. 14, 2005; exact on the disc's axis, tested against the closed form in
`test_flc_near_field.py`). It tends to the point VPL's S_k / (pi |x - y|^2) beyond a few r_k and
never exceeds a whole hemisphere of radiosity B (H S_k <= 1.5 rho_x B / pi:
`test_near_field_clamp_removes_the_single_vpl_spikes`); eps_rel R_scene stays a floor. Its bias
is the light a VPL loses within a few r_k of a receiver; r_k^2 / D_{k-1}^2 = 4 mu / N_avg at the
inner edge of a level k >= 1's support, and r_k -> 0 as N_avg grows (consistent). Other settings:
`vpl_disc` clamps d_i >= max(eps, r_k) (the same bound at d <= r_k, the point's light beyond);
`paper_eps` is eq. 5 as printed (eps only: unbiased for `manylights`' point sum, the setting of
the unbiasedness tests). Why: where a small sunlit share of the surface carries the bounce
(sponza), a pixel's bounce rests on the few lit level-0 VPLs near it, and a point VPL a little
more than r_0 away brightens it many times over; the disc element takes those spikes out.

Documented rules (a user setting always wins):
- D_near (`dnear_rule = lit`, default): D_near = min(dnear_factor R_scene, sqrt(A_lit / (4 pi))),
  A_lit the area a light's emission reaches, occlusion ignored (`levels.lit_area`: all of the
  surface when a point or directional light is present, else the part inside a spot's cutoff
  cone, measured once in prepare on pieces of (dnear_factor R_scene / 16)^2). Why: eq. 1 models
  the surface within D of a receiver as 4 pi D^2 and keeps one level-0 VPL per S_0, so that
  N_avg VPLs lie within D_near; only lit VPLs carry light, and when the lit surface is smaller
  than 4 pi D_near^2 a pixel is lit by A_lit / S_0 < N_avg of them. Bounding D_near so that
  4 pi D_near^2 <= A_lit keeps N_avg lit VPLs per level. The paper's D_near = 0.2 R_scene holds
  wherever the light reaches at least 4 pi (0.2 R_scene)^2: every scene of the default run but
  big_floor, and sponza, sibenik, conference, highpoly_* (a point or directional light each).
  `dnear_rule = scene` is the paper's 0.2 R_scene; `view` takes R = min(R_scene, median eye
  distance of the visible surface, measured once in prepare), which also bounds big_floor's
  D_near but shrinks it on every scene whose R_scene is large against the view depth.
- Level set (`levels = -1`): N = min(ceil(log_mu (R_scene / D_0)^2), ceil(log_mu (A_lit /
  (32 N_avg S_0)))), at least 0: the fewest levels whose unbounded top level holds at most
  32 N_avg lit VPLs, and no more than the reach needs (D_N >= R_scene). A level-k VPL stands
  for S_k of surface: each level added divides the top level's VPLs by mu and makes them mu
  times more powerful, and a frame whose light comes from a small lit patch then rests on a
  handful of them (the paper's "spikes"). Every lit top-level VPL lights the whole screen, so
  the budget bounds the fill cost; unlit VPLs splat nothing, so it counts lit ones (A_lit).
- Tiling (`tiling_level = -1`): L = floor(log4(W H / (64 x 48))), at least 0 (at most 5): tiles
  of at least 64 x 48 px (3072 px). The paper's x64 tiling at 1280 x 720 (Table 1) has tiles of
  160 x 90 px on a GPU with fill rate to spare; a fifth of that keeps FLC near `direct`'s frame
  time on a CPU rasteriser while a tile still resolves the low-frequency bounce. 1 at 128 x 96,
  2 at 320 x 180, 4 at 1280 x 720. The blur radius follows (`blur_radius = -1`: 2^L - 1, every
  tile phase weighing the same).

Quality ladder (`ladder`, fast -> accurate): n_avg 32, 64, 128 (default), 512. N_avg is the
paper's one quality knob (Fig. 10: the VPLs reaching a pixel per level, time in proportion);
the level set, D_near, tiling and blur follow their rules at every rung.

Parameters:

<!-- parameters: generated from the Param declarations by `gibench manuals --write` -->
| parameter             | default      | range                             | meaning |
|-----------------------|--------------|-----------------------------------|---|
| n_avg                 | 128          | 8 .. 4096                         | N_avg of eq. 1: about how many VPLs reach a pixel per level (quality knob; sweep 64, 128, 256, 512, 1024) |
| mu                    | 4.0          | 1.05 .. 16.0                      | level size ratio mu of S_k = S_0 mu^k (paper: 1.4 .. 5) |
| levels                | -1           | -1 .. 15                          | N: levels 0..N (-1: the level-set rule, the fewest levels whose top level holds at most 32 N_avg lit VPLs, no more than D_N >= R_scene needs) |
| reach                 | eq1_intent   | eq1_intent, eq18_printed          | influence distances D_k: eq1_intent D_near mu^(k/2) (N_avg VPLs per level), eq18_printed sqrt(S_k) (the printed eq. 18) |
| dnear_factor          | 0.2          | 0.001 .. 10.0                     | D_near / R_scene in eq. 1 (bounded by dnear_rule) |
| dnear_rule            | lit          | lit, view, scene                  | D_near: lit = min(dnear_factor R_scene, sqrt(A_lit / 4 pi)) (N_avg lit VPLs per level), view = dnear_factor min(R_scene, median view distance), scene = dnear_factor R_scene (the paper) |
| regular_selection     | compute      | compute, single_draw              | regular pass: compute = a compute pass selects the triangles Alg. 1 keeps (and the divergent ones) and the draw carries only those (same image); single_draw = the paper's one draw of the whole scene through the geometry shader |
| near_field            | disc_element | paper_eps, vpl_disc, disc_element | d_i^2 of eq. 5 for a level-k VPL at distance d from the receiver, r_k = sqrt(S_k / pi) the radius of the disc of area S_k it stands for: d^2 + r_k^2, the disc element's form factor (disc_element); max(r_k, d)^2 (vpl_disc); max(eps, d)^2 only (paper_eps, eq. 5 as printed); d_i >= eps_rel R_scene in all three |
| eps_rel               | 0.0001       | 1e-07 .. 1.0                      | eps of d_i = max(eps, d) (eq. 5, d the VPL-receiver distance), relative to the scene radius |
| tiling_level          | -1           | -1 .. 5                           | L: the viewport is split into 4^L interleaved tiles (-1: from the resolution, tiles of at least 64 x 48 px each) |
| blur_radius           | -1           | -1 .. 32                          | tent blur radius in pixels (-1: 2^L - 1, i.e. 0 when L = 0; 0: no blur) |
| blur_depth_threshold  | 0.05         | 0.0 .. 10.0                       | max tangent-plane distance of a blur neighbour / camera distance |
| blur_normal_threshold | 0.9          | -1.0 .. 1.0                       | min cosine between the normals of blur neighbours |
| progressive_frames    | 1            | 1 .. 4096                         | sub-frames averaged in one render (new u_rand, jittered VPLs) |
| jitter                | true         | bool                              | VPL uniformly jittered over its (sub-)triangle in every (sub-)frame (false: at the centroid when progressive_frames = 1, the paper's real-time mode) |
| last_level_unbounded  | true         | bool                              | f^N = 1 beyond D_N: unbiased (false: every f^k is 0 beyond D_N, far field cut) |
| divergent_pass        | true         | bool                              | tessellate divergent triangles (false: drop them) |
<!-- end of parameters -->

Example (the defaults, then the ladder's ends):

    gibench run --scenes cornell_spot --methods flc --res 128x96 --defaults-only
    gibench run --scenes cornell_spot --methods flc --res 128x96 --param flc.n_avg=32,512

Stages: `regular`, `divergent`, `upscale_blur` (after the shared `gbuffer_shadow` and
`direct_light`); the paper's "indirect" total is their sum. Needs: gbuffer, shadow_map, direct.
Each row records `extra.S0_m2`, `D_near_m`, `lit_area_m2`, `S_bar_N_m2`, `D_N_m`, `levels`,
`tiling_level`, `blur_radius`, `divergent_triangles`, `divergent_patch_vertices` (the buffer's
size: the sub-patches a light can reach are drawn).

Measurements: NOTES.md beside this file holds the figures behind these rules and defaults (the
single-frame study against jittered `manylights` and Mitsuba, the N_avg sweep, frame times,
each rule's comparison); `python -m studies.flc_study` reproduces them.

In motion (bench.run.sequence): It keeps nothing between states (its light cuts are rebuilt from the
frame's geometry and direct light every frame): a frame where anything moved prepares it again
(programs and per-scene buffers). Measured update per moved frame at 160x90, light
(rooms_light_sweep) 11 ms, camera (sponza_camera_walk) 46 ms, geometry (cornell_spot_moving_block)
44 ms (`python -m studies.motion_costs`, 2 cores shared with other work).

Stress limit params:progressive_frames=4096: 4096 sub-frames averaged in one render by design (the converged estimate); minutes per frame on llvmpipe, over the stress suite's timeout.
Stress limit params:dnear_factor=0.001: D_near of 1e-3 R_scene makes S_0 ~1e6 times smaller, so nearly every triangle is divergent and tessellated into millions of VPLs (the paper's D_near is 0.2 R_scene); the row exceeds the stress suite's timeout.
Stress limit coplanar: coincident coplanar faces are two emitting triangles in eq. 4's sum over triangles (the paper's formulation) while Mitsuba's rays see one surface: the overlapped area emits twice (cornell_box 64x48: mean +6.3%).
Stress limit flipped: a flipped winding reorders a divergent triangle's barycentric frame, so Alg. 2's keys of its tessellated pieces (noise at barycentric coordinates, Fig. 8) draw another random realisation: the same expectation, other noise (big_floor 64x48: indirect change 0.0865 against a seed-pair tolerance of 0.0853).
"""
from __future__ import annotations

from pathlib import Path

import moderngl
import numpy as np

from bench.gl import load_compute, load_program, set_uniforms
from bench.gl.shaders import has_member
from bench.gl.context import park
from bench.gl.passes import GBuffer
from bench.protocol.method import FrameOutput, MethodBase, Param, SkipRow

from .levels import REACHES, FlcLevels, lit_area, presplit_count
from .tessellation import MAX_TESS_LEVEL, measure_fmax

SHADERS = Path(__file__).parent / "shaders"
BINDINGS = {"BINDING_DIVERGENT_VERTICES": 3, "BINDING_DIVERGENT_COMMAND": 4, "BINDING_KEPT_TRIANGLES": 5}
SELECT_BINDINGS = {"BINDING_SELECT_FACES": 6, "BINDING_SELECT_POSITIONS": 7, "BINDING_SELECT_RANDOM": 8,
                   "BINDING_SELECT_RANK": 9, "BINDING_SELECT_GROUPS": 10, "BINDING_SELECT_KEPT_INDICES": 11,
                   "BINDING_SELECT_COMMAND": 12}
SELECT_GROUP = 64           # invocations per workgroup of the ordered selection (select_regular.glsl)
SELECT_CHUNK = 32           # consecutive triangles per invocation
SELECT_MARGIN = 1.0 + 1e-5  # the compute test keeps float ties; the geometry shader decides exactly
REGULAR_SELECTIONS = ("compute", "single_draw")
# glMemoryBarrier bit: the compacted indices are read as an element array.
GL_ELEMENT_ARRAY_BARRIER_BIT = 0x00000002
NOISE_SIZE = 1024
DIVERGENT_VERTEX_BYTES = 48
MAX_DIVERGENT_BYTES = 128 * 1024 * 1024   # GL_MAX_SHADER_STORAGE_BLOCK_SIZE guaranteed on llvmpipe
CPU_MARGIN = 1e-3  # float64 facts vs float32 GPU areas: borderline triangles counted as divergent
RESET_COMMAND = np.array([0, 1, 0, 0, 0, 0, 0, 0], dtype=np.uint32).tobytes()
# Random streams of frame.random_u32: stream j is sub-frame j's VPL jitter (as `manylights`'
# jitter frame j); the level draw (Alg. 2's u_rand) and the tile draw have their own.
STREAM_LEVEL, STREAM_TILE = 1 << 20, 2 << 20
# glMemoryBarrier bits: the appended patches are read as shader storage, the command as an indirect draw.
GL_COMMAND_BARRIER_BIT, GL_SHADER_STORAGE_BARRIER_BIT = 0x00000040, 0x00002000
# Divergent triangles are appended as equal sub-patches that tessellation level TESS_SUB_LEVEL
# makes regular, the ones no light reaches left out: the divergent pass's work then follows the
# lit area, not the scene's (see the manual, "Divergent pass").
TESS_SUB_LEVEL = 8
# Automatic tiling: tiles of at least 64 x 48 px (see the manual's tiling rule; the paper's are
# 160 x 90 px: x64 at 1280 x 720, Table 1, on a GPU with the fill rate for it).
MIN_TILE_PIXELS = 64 * 48


DNEAR_RULES = ("lit", "view", "scene")
NEAR_FIELDS = ("paper_eps", "vpl_disc", "disc_element")   # index = FLC_NEAR_MODE in vpl_splat.glsl
LIT_PIECES_PER_DNEAR = 16   # lit-area measurement: pieces of at most (D_near / 16)^2


def lit_area_for(scene, facts, dnear_factor: float) -> float:
    """`levels.lit_area` measured on pieces of at most (dnear_factor R_scene / 16)^2."""
    return lit_area(scene, (dnear_factor * float(facts.scene_radius) / LIT_PIECES_PER_DNEAR) ** 2)


def near_radius(facts, rule: str, dnear_factor: float, lit: float, seen: float | None = None) -> float:
    """R of D_near = dnear_factor R (the manual's D_near rule): R_scene for "scene" (the paper);
    for "lit" the largest R <= R_scene with 4 pi D_near^2 <= A_lit (`lit`: the area a light's
    emission reaches, `lit_area_for`), i.e. D_near = min(dnear_factor R_scene, sqrt(A_lit / (4 pi)));
    for "view" min(R_scene, `seen`: the median distance from the eye to the visible surface)."""
    if rule not in DNEAR_RULES:
        raise ValueError(f"flc: dnear_rule must be one of {list(DNEAR_RULES)}, got {rule!r}")
    radius = float(facts.scene_radius)
    if rule == "lit" and lit > 0:
        radius = min(radius, float(np.sqrt(lit / (4.0 * np.pi))) / dnear_factor)
    elif rule == "view":
        if seen is None:
            raise ValueError("flc: dnear_rule 'view' needs the median view distance")
        if seen > 0:
            radius = min(radius, seen)
    return radius


def median_view_distance(gpu, view, max_pixels: int = 64 * 48) -> float | None:
    """Median distance from the eye to the visible surface, from a GBuffer of the view at most
    `max_pixels` large (same aspect), rendered once in prepare; None when nothing is in view."""
    scale = min(1.0, float(np.sqrt(max_pixels / (view.width * view.height))))
    w, h = max(1, int(round(view.width * scale))), max(1, int(round(view.height * scale)))
    gbuffer = GBuffer(gpu, w, h)
    try:
        gbuffer.render(view)
        g = gbuffer.read()
    finally:
        gbuffer.release()
    if not g["mask"].any():
        return None
    dist = np.linalg.norm(g["position"][g["mask"]].astype(np.float64) - view.camera.eye, axis=1)
    return float(np.median(dist))


def auto_tiling_level(width: int, height: int) -> int:
    """The largest L in 0..5 whose 4^L tiles hold at least 64 x 48 px each:
    L = floor(log4(W H / 3072)), 0 below 128 x 96."""
    ratio = width * height / MIN_TILE_PIXELS
    return int(min(5, np.floor(np.log(ratio) / np.log(4.0) + 1e-9))) if ratio >= 4.0 else 0


class ForwardLightCuts(MethodBase):
    name = "flc"
    summary = "Forward Light Cuts: stochastic multiscale VPLs from triangles, splatted (Laurent et al. 2016)"
    stages = ("regular", "divergent", "upscale_blur")
    needs = frozenset({"gbuffer", "shadow_map", "direct"})
    # Quality ladder (manual, "Quality ladder"): N_avg, the paper's quality knob (Fig. 10).
    ladder = ({"n_avg": 32}, {"n_avg": 64}, {}, {"n_avg": 512})
    params = {
        "n_avg": Param(128, "N_avg of eq. 1: about how many VPLs reach a pixel per level", 8, 4096,
                       quality=True, sweep=(64, 128, 256, 512, 1024)),
        "mu": Param(4.0, "level size ratio mu of S_k = S_0 mu^k (paper: 1.4 .. 5)", 1.05, 16.0),
        "levels": Param(-1, "N: levels 0..N (-1: the level-set rule, the fewest levels whose top level holds at most "
                       "32 N_avg lit VPLs, no more than D_N >= R_scene needs)", -1, 15),
        "reach": Param("eq1_intent", "influence distances D_k: eq1_intent D_near mu^(k/2) (N_avg VPLs per level), "
                       "eq18_printed sqrt(S_k) (the printed eq. 18)", choices=REACHES),
        "dnear_factor": Param(0.2, "D_near / R_scene in eq. 1 (bounded by dnear_rule)", 1e-3, 10.0),
        "dnear_rule": Param("lit", "D_near: lit = min(dnear_factor R_scene, sqrt(A_lit / 4 pi)) (N_avg lit VPLs "
                            "per level), view = dnear_factor min(R_scene, median view distance), scene = "
                            "dnear_factor R_scene (the paper)", choices=DNEAR_RULES),
        "regular_selection": Param("compute", "regular pass: compute = a compute pass selects the triangles Alg. 1 keeps "
                                   "(and the divergent ones) and the draw carries only those (same image); "
                                   "single_draw = the paper's one draw of the whole scene through the geometry shader",
                                   choices=REGULAR_SELECTIONS),
        "near_field": Param("disc_element", "d_i^2 of eq. 5 for a level-k VPL at distance d from the receiver, "
                            "r_k = sqrt(S_k / pi) the radius of the disc of area S_k it stands for: d^2 + r_k^2, "
                            "the disc element's form factor (disc_element); max(r_k, d)^2 (vpl_disc); max(eps, d)^2 "
                            "only (paper_eps, eq. 5 as printed); d_i >= eps_rel R_scene in all three",
                            choices=NEAR_FIELDS),
        "eps_rel": Param(1e-4, "eps of d_i = max(eps, d) (eq. 5, d the VPL-receiver distance), relative to the "
                         "scene radius", 1e-7, 1.0),
        "tiling_level": Param(-1, "L: the viewport is split into 4^L interleaved tiles (-1: from the resolution, "
                              "tiles of at least 64 x 48 px each)", -1, 5),
        "blur_radius": Param(-1, "tent blur radius in pixels (-1: 2^L - 1, i.e. 0 when L = 0; 0: no blur)", -1, 32),
        "blur_depth_threshold": Param(0.05, "max tangent-plane distance of a blur neighbour / camera distance", 0.0, 10.0),
        "blur_normal_threshold": Param(0.9, "min cosine between the normals of blur neighbours", -1.0, 1.0),
        "progressive_frames": Param(1, "sub-frames averaged in one render (new u_rand, jittered VPLs)", 1, 4096),
        "jitter": Param(True, "VPL uniformly jittered over its (sub-)triangle in every (sub-)frame (false: at the "
                        "centroid when progressive_frames = 1, the paper's real-time mode)"),
        "last_level_unbounded": Param(True, "f^N = 1 beyond D_N: unbiased (false: every f^k is 0 beyond D_N, far field cut)"),
        "divergent_pass": Param(True, "tessellate divergent triangles (false: drop them)"),
    }

    # ------------------------------------------------------------------ setup (untimed)
    @classmethod
    def cost_terms(cls, params, size):
        # each level's VPLs (about n_avg lit ones) are gathered by every pixel of its tiles
        return {"pixel_navg": size.pixels * params["n_avg"], "triangle_navg": size.triangles * params["n_avg"]}

    def prepare(self, gpu, scene, facts, params, view) -> None:
        self.params = params
        self.ctx = ctx = gpu.ctx
        # "view": nothing in view (0) keeps R_scene
        seen = (median_view_distance(gpu, view) or 0.0) if params["dnear_rule"] == "view" else None
        self.lit_area = lit_area_for(scene, facts, params["dnear_factor"])
        self.near_radius = near_radius(facts, params["dnear_rule"], params["dnear_factor"], self.lit_area, seen)
        self.levels = FlcLevels(scene_radius=facts.scene_radius, n_avg=float(params["n_avg"]), mu=params["mu"],
                                levels=params["levels"], dnear_factor=params["dnear_factor"],
                                last_level_unbounded=params["last_level_unbounded"], reach=params["reach"],
                                scene_area=self.lit_area, near_radius=self.near_radius)
        lv = self.levels
        self.eps = params["eps_rel"] * facts.scene_radius
        L = params["tiling_level"]
        if L < 0:
            L = auto_tiling_level(view.width, view.height)
        self.tiling_level = L
        self.tiles_per_axis = 1 << L
        self.tile_size = (-(-view.width // self.tiles_per_axis), -(-view.height // self.tiles_per_axis))
        radius = params["blur_radius"]
        self.blur_radius = (self.tiles_per_axis - 1) if radius < 0 else radius

        # Divergent triangles: how many, and the exact buffer they need (from the scene facts).
        threshold = lv.divergent_area
        n_divergent = facts.triangles_above(threshold * (1.0 - CPU_MARGIN))
        self.divergent_count = n_divergent
        self.run_divergent = bool(params["divergent_pass"]) and n_divergent > 0
        fmax = measure_fmax(ctx)
        self.tess_target = threshold * (1.0 - CPU_MARGIN)
        capacity = 0
        if self.run_divergent:
            areas = facts.sorted_areas_m2[len(facts.sorted_areas_m2) - n_divergent:]
            m = presplit_count(areas * (1.0 + CPU_MARGIN), fmax[TESS_SUB_LEVEL - 1], self.tess_target)
            capacity = int(3 * np.sum(m * m))
            if capacity * DIVERGENT_VERTEX_BYTES > MAX_DIVERGENT_BYTES:
                raise SkipRow(f"flc: scene '{scene.name}' has {n_divergent} divergent triangles needing "
                              f"{capacity} patch vertices (> {MAX_DIVERGENT_BYTES // DIVERGENT_VERTEX_BYTES}); "
                              f"lower n_avg or raise dnear_factor")
        self.divergent_capacity = capacity

        defines = dict(BINDINGS, **lv.defines(), DIVERGENT_APPEND=self.run_divergent,
                       DIVERGENT_CAPACITY=max(capacity, 1), TESS_MAX_LEVEL=MAX_TESS_LEVEL,
                       TESS_FMAX_SUB=float(fmax[TESS_SUB_LEVEL - 1]), TESS_TARGET_AREA=float(self.tess_target),
                       TESS_FMAX="float[%d](%s)" % (len(fmax), ", ".join(repr(float(v)) for v in fmax)),
                       NOISE_SIZE=NOISE_SIZE, FLC_NEAR_MODE=NEAR_FIELDS.index(params["near_field"]))
        self.selected = params["regular_selection"] == "compute"
        defines["REGULAR_SELECTED"] = self.selected
        self.regular = load_program(ctx, SHADERS / "splat_regular.glsl", defines)
        self.select_steps = ()
        index_buffer = gpu.ibo
        if self.selected:
            self._prepare_selection(gpu, defines)
            index_buffer = self.kept_indices
        self.regular_vao = ctx.vertex_array(self.regular, [(gpu.vbo_position, "3f", "in_position"),
                                                           (gpu.vbo_normal, "3f", "in_normal"),
                                                           (gpu.vbo_random, "u", "in_vrand")],
                                            index_buffer=index_buffer, index_element_size=4)
        self.divergent_vertices = ctx.buffer(reserve=max(capacity, 1) * DIVERGENT_VERTEX_BYTES)
        self.command = ctx.buffer(RESET_COMMAND)
        self.command_reset = ctx.buffer(RESET_COMMAND)  # copied on the GPU: no CPU upload in a frame
        self.divergent = self.divergent_vao = self.noise = None
        if self.run_divergent:
            self.divergent = load_program(ctx, SHADERS / "splat_divergent.glsl", defines)
            self.divergent_vao = ctx.vertex_array(self.divergent, [])
            rng = np.random.default_rng(np.random.SeedSequence([gpu.seed, 0x666C6374]))
            noise = rng.integers(0, 2**32, size=NOISE_SIZE * NOISE_SIZE, dtype=np.uint64).astype(np.uint32)
            self.noise = ctx.texture((NOISE_SIZE, NOISE_SIZE), 1, noise.tobytes(), dtype="u4")
            self.noise.filter = (moderngl.NEAREST, moderngl.NEAREST)

        self.resolve = load_program(ctx, SHADERS / "resolve.glsl")
        self.resolve_vao = ctx.vertex_array(self.resolve, [])
        tw, th = self.tile_size[0] * self.tiles_per_axis, self.tile_size[1] * self.tiles_per_axis
        self.accum = ctx.texture((tw, th), 4, dtype="f4")
        self.blurred = ctx.texture((view.width, view.height), 4, dtype="f4")
        self.indirect = ctx.texture((view.width, view.height), 4, dtype="f4")
        for t in (self.accum, self.blurred, self.indirect):
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.accum_fbo = ctx.framebuffer([self.accum])
        # the receivers in the tiled layout (deinterleave.glsl), rewritten every frame from the GBuffer
        self.receivers = ctx.texture((tw, th), 4, dtype="u4")
        self.receivers.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.receivers_fbo = ctx.framebuffer([self.receivers])
        self.deinterleave = load_program(ctx, SHADERS / "deinterleave.glsl")
        self.deinterleave_vao = ctx.vertex_array(self.deinterleave, [])
        self.blurred_fbo = ctx.framebuffer([self.blurred])
        self.indirect_fbo = ctx.framebuffer([self.indirect])

    def _prepare_selection(self, gpu, defines: dict) -> None:
        """Buffers and the three programs of the ordered triangle selection (select_regular.glsl)."""
        ctx = self.ctx
        count = gpu.triangle_count
        self.select_chunks = max(1, -(-count // SELECT_CHUNK))
        self.select_groups = -(-self.select_chunks // SELECT_GROUP)
        select_defines = dict(defines, **SELECT_BINDINGS, SELECT_GROUP=SELECT_GROUP, SELECT_CHUNK=SELECT_CHUNK,
                              SELECT_MARGIN=SELECT_MARGIN)
        self.select_steps = tuple(load_compute(ctx, SHADERS / "select_regular.glsl", dict(select_defines, SELECT_STEP=k))
                                  for k in (1, 2, 3))
        self.select_rank = ctx.buffer(reserve=4 * max(count, 1))
        self.select_group_counts = ctx.buffer(reserve=4 * self.select_chunks)
        self.kept_indices = ctx.buffer(reserve=12 * max(count, 1))
        self.kept_triangles = ctx.buffer(reserve=4 * max(count, 1))
        self.select_command = ctx.buffer(reserve=20)
        self.triangle_count = count

    def _select(self, gpu, u_rand: int) -> None:
        """The ordered selection of the regular pass's triangles (3 dispatches, no CPU read-back)."""
        for buffer, name in ((gpu.ibo, "FACES"), (gpu.vbo_position, "POSITIONS"), (gpu.vbo_random, "RANDOM"),
                             (self.select_rank, "RANK"), (self.select_group_counts, "GROUPS"),
                             (self.kept_indices, "KEPT_INDICES"), (self.select_command, "COMMAND")):
            buffer.bind_to_storage_buffer(SELECT_BINDINGS[f"BINDING_SELECT_{name}"])
        self.kept_triangles.bind_to_storage_buffer(BINDINGS["BINDING_KEPT_TRIANGLES"])
        for step, groups in zip(self.select_steps, (self.select_groups, 1, self.select_groups)):
            set_uniforms(step, u_triangle_count=self.triangle_count, u_chunk_total=self.select_chunks, u_rand=u_rand)
            step.run(group_x=groups)
            self.ctx.memory_barrier(GL_SHADER_STORAGE_BARRIER_BIT)
        # the draw reads the compacted indices and its command
        self.ctx.memory_barrier(GL_ELEMENT_ARRAY_BARRIER_BIT | GL_COMMAND_BARRIER_BIT)

    def describe(self) -> dict:
        """The derived constants of this setup (for the record and the tests)."""
        lv = self.levels
        return {"S0_m2": lv.s0, "D_near_m": lv.d_near, "lit_area_m2": self.lit_area, "S_bar_N_m2": lv.divergent_area, "D_N_m": float(lv.d[lv.levels]),
                "levels": int(lv.levels), "tiling_level": int(self.tiling_level), "blur_radius": int(self.blur_radius),
                "divergent_triangles": self.divergent_count, "divergent_patch_vertices": self.divergent_capacity}

    # ------------------------------------------------------------------ frame (timed)
    def _bind_splat(self, prog, frame, j: int, unit0: int = 0) -> int:
        passes, gpu = frame.passes, frame.gpu
        unit = passes.shadows.bind(prog, unit0)
        if has_member(prog, "u_receivers"):
            self.receivers.use(unit)
            prog["u_receivers"].value = unit
            unit += 1
        gpu.bind_scene_buffers()
        self.divergent_vertices.bind_to_storage_buffer(BINDINGS["BINDING_DIVERGENT_VERTICES"])
        self.command.bind_to_storage_buffer(BINDINGS["BINDING_DIVERGENT_COMMAND"])
        frames = self.params["progressive_frames"]
        view = frame.view
        set_uniforms(prog, u_view=view.view, u_proj_scale=(float(view.proj[0, 0]), float(view.proj[1, 1])),
                     u_near=float(view.near), u_rand=frame.random_u32(STREAM_LEVEL + j),
                     u_rand_tile=frame.random_u32(STREAM_TILE + j), u_rand_jitter=frame.random_u32(j),
                     u_jitter=bool(self.params["jitter"]) or frames > 1,
                     u_screen=(frame.width, frame.height), u_tiles_per_axis=self.tiles_per_axis,
                     u_tile_size=self.tile_size, u_weight=float(self.tiles_per_axis ** 2) / frames,
                     u_eps=float(self.eps), u_light_count=gpu.light_count)
        return unit

    def _splat_state(self) -> None:
        ctx = self.ctx
        self.accum_fbo.use()
        ctx.viewport = (0, 0, self.accum.width, self.accum.height)
        ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        ctx.enable(moderngl.BLEND)
        ctx.blend_func = moderngl.ONE, moderngl.ONE

    def render(self, frame, prof) -> FrameOutput:
        ctx = self.ctx
        self.accum_fbo.use()
        ctx.viewport = (0, 0, self.accum.width, self.accum.height)
        self.accum_fbo.clear(0.0, 0.0, 0.0, 0.0)
        for j in range(self.params["progressive_frames"]):
            with prof.stage("regular"):
                if j == 0:
                    self._deinterleave(frame)
                if self.run_divergent:
                    ctx.copy_buffer(self.command, self.command_reset)
                if self.selected:
                    self._select(frame.gpu, frame.random_u32(STREAM_LEVEL + j))
                self._splat_state()
                self._bind_splat(self.regular, frame, j)
                if self.selected:   # kept_triangles stays bound from _select
                    self.regular_vao.render_indirect(self.select_command, mode=moderngl.TRIANGLES, count=1)
                else:
                    self.regular_vao.render(moderngl.TRIANGLES)
            if self.run_divergent:
                with prof.stage("divergent"):
                    # the appended patches (storage) and the command (indirect draw) are read next
                    ctx.memory_barrier(GL_COMMAND_BARRIER_BIT | GL_SHADER_STORAGE_BARRIER_BIT)
                    self._splat_state()
                    unit = self._bind_splat(self.divergent, frame, j)
                    self.noise.use(unit)
                    self.divergent["u_noise"].value = unit
                    ctx.patch_vertices = 3
                    self.divergent_vao.render_indirect(self.command, mode=moderngl.PATCHES, count=1)
        ctx.disable(moderngl.BLEND)
        with prof.stage("upscale_blur"):
            self._resolve(frame)
        skipped = () if self.run_divergent else ("divergent",)
        return FrameOutput(direct=frame.passes.direct.radiance, indirect=self.indirect,
                           skipped_stages=skipped, extra=self.describe())

    def _deinterleave(self, frame) -> None:
        """The GBuffer's receivers in the tiled layout the splat fragments read (deinterleave.glsl)."""
        ctx, prog = self.ctx, self.deinterleave
        self.receivers_fbo.use()
        ctx.viewport = (0, 0, self.receivers.width, self.receivers.height)
        ctx.disable(moderngl.BLEND | moderngl.DEPTH_TEST | moderngl.CULL_FACE)
        frame.passes.gbuffer.bind(prog, 0)
        set_uniforms(prog, u_screen=(frame.width, frame.height), u_tiles_per_axis=self.tiles_per_axis,
                     u_tile_size=self.tile_size)
        self.deinterleave_vao.render(moderngl.TRIANGLES, vertices=3)

    def _resolve(self, frame) -> None:
        ctx, prog = self.ctx, self.resolve
        ctx.viewport = (0, 0, frame.width, frame.height)
        unit = frame.passes.gbuffer.bind(prog, 0)
        common = dict(u_tiles_per_axis=self.tiles_per_axis, u_tile_size=self.tile_size,
                      u_screen=(frame.width, frame.height), u_radius=self.blur_radius,
                      u_depth_threshold=float(self.params["blur_depth_threshold"]),
                      u_normal_threshold=float(self.params["blur_normal_threshold"]),
                      u_camera_pos=tuple(float(v) for v in frame.view.eye_local), u_source=unit)
        if self.blur_radius > 0:
            steps = ((self.accum, self.blurred_fbo, True, (1, 0), False),
                     (self.blurred, self.indirect_fbo, False, (0, 1), True))
        else:
            steps = ((self.accum, self.indirect_fbo, True, (1, 0), True),)
        for source, fbo, from_tiled, direction, albedo in steps:
            fbo.use()
            source.use(unit)
            set_uniforms(prog, u_from_tiled=from_tiled, u_direction=direction, u_apply_albedo=albedo, **common)
            self.resolve_vao.render(moderngl.TRIANGLES, vertices=3)

    def release(self) -> None:
        if getattr(self, "ctx", None) is None:
            return
        park(self.ctx)
        for name in ("receivers_fbo", "receivers", "deinterleave_vao", "deinterleave", "accum_fbo", "blurred_fbo",
                     "indirect_fbo", "accum", "blurred", "indirect", "resolve_vao",
                     "resolve", "noise", "divergent_vao", "divergent", "command", "command_reset", "divergent_vertices",
                     "regular_vao", "regular", "select_rank", "select_group_counts", "kept_indices",
                     "kept_triangles", "select_command"):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.release()
                setattr(self, name, None)
        for step in getattr(self, "select_steps", ()):
            step.release()
        self.select_steps = ()
