"""Forward Light Cuts (`flc`): the level/partition maths (influence distances, level set), its
GLSL mirror, unbiasedness against `manylights`, the regular and divergent pipelines, interleaved
sampling and its resolution rule, determinism and robustness. The single-frame accuracy at the
defaults is in test_flc_defaults.py."""
import dataclasses

import numpy as np
import pytest

from bench.gl.shaders import GLSL_VERSION, define_block, expand_includes
from bench.model.corpus import load_scene
from bench.model.scene import Camera, DirectionalLight, compute_facts
from bench.protocol.method import ParamError
from bench.run.harness import run_method
from methods.flc.levels import TOP_LEVEL_BUDGET, FlcLevels, auto_levels, presplit_count
from methods.flc.method import CPU_MARGIN, SHADERS, TESS_SUB_LEVEL, ForwardLightCuts, auto_tiling_level
from methods.flc.tessellation import measure_fmax
from methods.manylights.method import ManyLights
from studies.flc_analysis import count_vpls_reaching, energy_beyond_support, level_statistics
from tests.conftest import grid_quad, make_grid_box, make_open_box, scene_from_parts

CONFIGS = [dict(n_avg=256, mu=4.0, levels=5), dict(n_avg=64, mu=1.4, levels=8), dict(n_avg=1024, mu=2.0, levels=1),
           dict(n_avg=32, mu=5.0, levels=0)]
# The settings under which FLC is unbiased for `manylights`' point sum: no tiling, no blur, f^N
# unbounded, and the paper's eps (the default near field shapes d_i, a bias that vanishes as N_avg
# grows: tests/methods/test_flc_near_field.py).
EXACT = dict(tiling_level=0, blur_radius=0, last_level_unbounded=True, near_field="paper_eps")


def rel_mse(a, b):
    return float(((a - b) ** 2).mean() / (b ** 2).mean())


# ---------------------------------------------------------------------------- maths (numpy)
@pytest.mark.parametrize("cfg", CONFIGS)
def test_partition_of_unity(cfg):
    lv = FlcLevels(scene_radius=1.7, last_level_unbounded=False, **cfg)
    nodes = lv.d[: lv.levels + 1]
    d = np.concatenate([np.geomspace(nodes[0] * 1e-4, nodes[-1], 5000), nodes, nodes * (1 - 1e-9)])
    f = lv.partition(d)
    assert f.min() >= 0.0 and f.max() <= 1.0
    np.testing.assert_allclose(f.sum(axis=0), 1.0, atol=1e-12)
    beyond = nodes[-1] * np.array([1.0 + 1e-9, 1.5, 1e3])
    assert np.all(lv.partition(beyond) == 0.0)
    unbounded = dataclasses.replace(lv, last_level_unbounded=True)
    np.testing.assert_allclose(unbounded.partition(np.concatenate([d, beyond])).sum(axis=0), 1.0, atol=1e-12)


def test_printed_eq16_is_not_a_partition_of_unity():
    """The correction matters: eq. 16 as printed (f^0 = 1 on ]0, D_1]) sums to more than 1."""
    lv = FlcLevels(scene_radius=1.0, n_avg=256, mu=4.0, levels=3)
    d = 0.5 * (lv.d[0] + lv.d[1])
    f = lv.partition(np.array([d]))[:, 0]
    printed = f.copy()
    printed[0] = 1.0
    assert f.sum() == pytest.approx(1.0) and printed.sum() > 1.4


@pytest.mark.parametrize("cfg", CONFIGS)
def test_eq9_expectation_identity(cfg):
    """sum_k F^k P(t in L^k) = A with F^k = S_k f^k and P = A / S_k, for d in ]0, D_N]."""
    lv = FlcLevels(scene_radius=2.3, **cfg)
    rng = np.random.default_rng(1)
    area = rng.uniform(0.0, lv.divergent_area, 400)
    d = rng.uniform(0.0, lv.d[lv.levels], 400) + 1e-12
    p = lv.level_probabilities(area)                    # (400, N+1)
    assert np.all(p.sum(-1) <= 1.0 + 1e-12)             # regular triangles: a valid distribution
    expectation = (lv.s[None, :] * lv.partition(d).T * p).sum(-1)
    np.testing.assert_allclose(expectation, area, rtol=1e-12)


def test_alg1_level_frequencies_are_area_over_s_k():
    """Eq. 3 correction: Alg. 1 puts a triangle in level k with probability A / S_k, not A / S_bar_k."""
    lv = FlcLevels(scene_radius=1.0, n_avg=64, mu=2.0, levels=3)
    area = 0.9 * lv.divergent_area
    u = np.random.default_rng(2).random(400_000)
    level = lv.level_of(u, np.full_like(u, area))
    freq = np.array([(level == k).mean() for k in range(lv.levels + 1)])
    expected = area / lv.s
    np.testing.assert_allclose(freq, expected, atol=4e-3)
    assert abs(freq[1] - area / lv.s_bar[1]) > 0.1  # the cumulative (printed) one is far off
    assert (level == -1).mean() == pytest.approx(1 - expected.sum(), abs=4e-3)
    assert np.all(lv.level_of(u[:1000], np.zeros(1000)) == -1)  # zero area: never a VPL


def test_model_count_of_vpls_reaching_a_receiver_grows_with_n_avg():
    """Eq. 1 / Fig. 10: about N_avg VPLs influence a pixel. Under eq. 1's model the interior
    levels' counts are proportional to N_avg with D_k = D_near mu^(k/2), and constant (4 pi times
    the hats' shape) with the printed D_k = sqrt(S_k)."""
    for mu in (1.4, 3.0, 5.0):
        counts = {}
        for reach in ("eq1_intent", "eq18_printed"):
            for n_avg in (64, 256):
                lv = FlcLevels(scene_radius=1.0, n_avg=n_avg, mu=mu, levels=6, last_level_unbounded=False, reach=reach)
                n = lv.expected_vpls_reaching()
                np.testing.assert_allclose(n[1:-1], n[1], rtol=1e-3)   # the same count from every interior level
                counts[reach, n_avg] = n[1]
        assert counts["eq1_intent", 256] / counts["eq1_intent", 64] == pytest.approx(4.0, rel=1e-3)
        assert counts["eq18_printed", 256] == pytest.approx(counts["eq18_printed", 64], rel=1e-3)
        assert counts["eq1_intent", 64] == pytest.approx(counts["eq18_printed", 64] * 64 / (4 * np.pi), rel=1e-3)


@pytest.mark.parametrize("levels", [-1, 3])
def test_measured_vpls_reaching_a_pixel_grow_in_proportion_to_n_avg(levels):
    """The paper's invariant measured on a scene (Alg. 1 on cornell_spot's triangles, divergent ones
    cut into regular pieces): 4x N_avg gives 3-5x the VPLs whose f^k is non-zero at a receiver,
    with the default level set and with four bounded-reach levels below the unbounded top.
    The printed eq. 18 (with the former defaults N = 5, bounded) does not: its count even falls."""
    scene = load_scene("cornell_spot")
    total = {n: count_vpls_reaching(scene, {"n_avg": n, "levels": levels}, receivers=96)["total"] for n in (64, 256)}
    assert 3.0 <= total[256] / total[64] <= 5.0, total
    printed = dict(reach="eq18_printed", levels=5, last_level_unbounded=False)
    old = {n: count_vpls_reaching(scene, dict(printed, n_avg=n), receivers=96)["total"] for n in (64, 256)}
    assert old[256] / old[64] < 1.5, old


def test_reach_starts_at_d_near_while_the_printed_one_shrinks_with_n_avg():
    r = 2.0
    for n_avg in (64, 256, 1024):
        lv = FlcLevels(scene_radius=r, n_avg=n_avg, mu=4.0, levels=5)
        np.testing.assert_allclose(lv.d[:6], 0.2 * r * 4.0 ** (np.arange(6) / 2))   # D_0 = D_near
    printed = [FlcLevels(scene_radius=r, n_avg=n, mu=4.0, levels=5, reach="eq18_printed").d[5] / r for n in (64, 256, 1024)]
    np.testing.assert_allclose(printed, [2.84, 1.42, 0.71], rtol=0.01)   # the figures of issue 10


def test_automatic_level_set():
    """levels = -1: the fewest levels whose top level holds at most 32 N_avg VPLs in the scene
    (A_scene / S_N), and never more than needed for D_N >= R_scene."""
    for radius, area, mu, n_avg in ((1.73, 29.0, 4.0, 256), (4.18, 135.5, 4.0, 64), (20.8, 7504.0, 4.0, 128),
                                    (20.8, 7504.0, 1.4, 1024), (1.0, 1e6, 4.0, 256), (1.0, 0.01, 4.0, 256)):
        lv = FlcLevels(scene_radius=radius, n_avg=n_avg, mu=mu, levels=-1, scene_area=area)
        n = lv.levels

        def ok(k):
            other = FlcLevels(scene_radius=radius, n_avg=n_avg, mu=mu, levels=k, scene_area=area)
            return area / other.s[k] <= TOP_LEVEL_BUDGET * n_avg * (1 + 1e-9) or other.d[k] >= radius * (1 - 1e-9)
        assert ok(n)
        assert n == 0 or not ok(n - 1)
    assert FlcLevels(1.73, 128, 4.0, -1, scene_area=29.0).levels == 0        # cornell_spot
    assert FlcLevels(20.8, 128, 4.0, -1, scene_area=7504.0).levels == 1      # sponza
    assert FlcLevels(1.0, 256, 4.0, -1, scene_area=1e6).levels == 3          # the reach caps it: D_3 = 1.6 R
    assert auto_levels(1.0, 256, 4.0, 0.2) == 3


def test_automatic_tiling_level_follows_the_resolution():
    """Tiles of at least 64 x 48 px (the paper's: 160 x 90 px, x64 at 1280 x 720)."""
    assert [auto_tiling_level(w, h) for w, h in ((64, 48), (100, 90), (128, 96), (160, 90), (320, 180), (640, 360),
                                                 (1280, 720), (1024, 1024), (8000, 8000))] == [0, 0, 1, 1, 2, 3, 4, 4, 5]


def test_tiling_and_blur_from_the_view_unless_set(gl_ctx):
    scene = make_grid_box(4)
    small = run_method(gl_ctx, ForwardLightCuts, scene, "main", 64, 48, {}, frames=1, warmup=1)
    wide = run_method(gl_ctx, ForwardLightCuts, scene, "main", 320, 180, {}, frames=1, warmup=1)
    user = run_method(gl_ctx, ForwardLightCuts, scene, "main", 64, 48, {"tiling_level": 2, "blur_radius": 5}, frames=1)
    assert (small.extra["tiling_level"], small.extra["blur_radius"]) == (0, 0)
    assert (wide.extra["tiling_level"], wide.extra["blur_radius"]) == (2, 3)
    assert (user.extra["tiling_level"], user.extra["blur_radius"]) == (2, 5)


def test_glsl_partition_matches_numpy(gl_ctx):
    lv = FlcLevels(scene_radius=1.3, n_avg=128, mu=2.5, levels=4)
    d = np.concatenate([np.geomspace(lv.d[0] * 1e-3, lv.d[-1] * 3, 997), lv.d * 1.0001]).astype(np.float32)
    body = """
    layout(local_size_x = 64) in;
    layout(std430, binding = 5) readonly buffer In { float dist[]; };
    layout(std430, binding = 6) writeonly buffer Out { float f[]; };
    uniform int u_count;
    void main() {
        int i = int(gl_GlobalInvocationID.x);
        if (i >= u_count) return;
        for (int k = 0; k <= FLC_N; ++k) f[i * (FLC_N + 1) + k] = flc_partition(k, dist[i]);
    }
    """
    src = (GLSL_VERSION + "\n" + define_block(lv.defines()) + "#define COMPUTE_SHADER\n"
           + expand_includes(SHADERS / "partition.glsl") + body)
    cs = gl_ctx.compute_shader(src)
    inp = gl_ctx.buffer(d.tobytes())
    out = gl_ctx.buffer(reserve=len(d) * (lv.levels + 1) * 4)
    try:
        inp.bind_to_storage_buffer(5)
        out.bind_to_storage_buffer(6)
        cs["u_count"].value = len(d)
        cs.run(group_x=(len(d) + 63) // 64)
        gpu = np.frombuffer(out.read(), dtype=np.float32).reshape(len(d), lv.levels + 1).T
    finally:
        for obj in (cs, inp, out):
            obj.release()
    np.testing.assert_allclose(gpu, lv.partition(d.astype(np.float64)), atol=2e-5)


def test_glsl_level_matches_numpy(gl_ctx):
    lv = FlcLevels(scene_radius=2.0, n_avg=64, mu=3.0, levels=4)
    rng = np.random.default_rng(3)
    u = rng.random(4096).astype(np.float32)
    area = (rng.random(4096) * lv.divergent_area).astype(np.float32)
    area[:16] = 0.0
    body = """
    layout(local_size_x = 64) in;
    layout(std430, binding = 5) readonly buffer In { vec2 u_area[]; };
    layout(std430, binding = 6) writeonly buffer Out { int level[]; };
    void main() {
        int i = int(gl_GlobalInvocationID.x);
        level[i] = flc_level(u_area[i].x, u_area[i].y);
    }
    """
    src = (GLSL_VERSION + "\n" + define_block(lv.defines()) + "#define COMPUTE_SHADER\n"
           + expand_includes(SHADERS / "partition.glsl") + body)
    cs = gl_ctx.compute_shader(src)
    inp = gl_ctx.buffer(np.stack([u, area], 1).tobytes())
    out = gl_ctx.buffer(reserve=len(u) * 4)
    try:
        inp.bind_to_storage_buffer(5)
        out.bind_to_storage_buffer(6)
        cs.run(group_x=len(u) // 64)
        gpu = np.frombuffer(out.read(), dtype=np.int32)
    finally:
        for obj in (cs, inp, out):
            obj.release()
    expected = lv.level_of(u.astype(np.float64), area.astype(np.float64))
    # float32 thresholds on the GPU: only draws within rounding of a threshold may differ
    assert np.mean(gpu == expected) > 0.999
    assert np.all(gpu[:16] == -1) and set(np.unique(gpu)) == set(range(-1, lv.levels + 1))


# ---------------------------------------------------------------------------- rendering
def test_progressive_converges_to_manylights(gl_ctx):
    """Unbiasedness: progressive FLC (f^N unbounded, no tiling/blur) against the exact sum of
    eq. 4 with eq. 6's lobe and the same VPL jitter. eps is large so the 1/d^2 singularity of
    jittered VPLs near corners (infinite variance in both estimators) does not dominate."""
    scene = make_grid_box(8)
    params = dict(EXACT, n_avg=32, levels=2, mu=2.0, eps_rel=0.3)
    errors = []
    for frames in (16, 64, 256):
        flc = run_method(gl_ctx, ForwardLightCuts, scene, "main", 48, 36, dict(params, progressive_frames=frames),
                         frames=1)
        ml = run_method(gl_ctx, ManyLights, scene, "main", 48, 36,
                        {"emission": "flc", "jitter_frames": frames, "eps_rel": 0.3}, frames=1)
        errors.append(rel_mse(flc.indirect, ml.indirect))
    assert flc.extra["divergent_triangles"] > 0  # both pipelines take part
    assert errors[0] > errors[1] > errors[2]
    assert errors[0] / errors[2] > 4.0  # ~1/frames (16x more frames)
    assert errors[2] < 1e-3


def test_multilevel_regular_pass_converges_to_manylights(gl_ctx):
    """Three levels, every triangle regular (no divergent pass): the regular pipeline alone,
    progressive with the last level unbounded, against the exact jittered sum."""
    scene = make_grid_box(12)   # 0.014 m^2 triangles, below S_bar_2
    params = dict(EXACT, n_avg=32, levels=2, mu=2.0, eps_rel=0.3)
    errors = []
    for frames in (8, 128):
        flc = run_method(gl_ctx, ForwardLightCuts, scene, "main", 48, 36, dict(params, progressive_frames=frames),
                         frames=1)
        ml = run_method(gl_ctx, ManyLights, scene, "main", 48, 36,
                        {"emission": "flc", "jitter_frames": frames, "eps_rel": 0.3}, frames=1)
        errors.append(rel_mse(flc.indirect, ml.indirect))
    assert flc.extra["divergent_triangles"] == 0 and flc.skipped_stages == ("divergent",)
    assert flc.extra["levels"] == 2
    assert errors[0] > 4.0 * errors[1]
    assert errors[1] < 2e-3
    assert flc.indirect.mean() == pytest.approx(ml.indirect.mean(), rel=0.02)


def test_vpl_irradiance_uses_the_shading_normal(gl_ctx):
    """The VPL's incident cosine is taken against the interpolated shading normal (as Mitsuba and
    `manylights`), the emission side against the face: under a directional light, tilting the
    vertex normals of the emitting floor scales the bounce by cos(tilted) / cos(flat)."""
    light = DirectionalLight([0.3, -1.0, 0.2], [3.0, 3.0, 3.0])
    parts = [grid_quad([-1, 0, -1], [0, 0, 2], [2, 0, 0], 6),     # floor, normal +y: the emitter
             grid_quad([-1, 0, -1], [2, 0, 0], [0, 2, 0], 6)]     # back wall, facing +z: lit by the floor only
    flat = scene_from_parts("tilt", parts, ([0.8] * 3, [0.8] * 3), [light], {"main": Camera([0, 1, 3.5], [0, 0.7, 0], fov_y_deg=50)})
    floor = np.zeros(len(flat.vertices), bool)
    floor[np.unique(flat.faces[: len(flat.faces) // 2])] = True
    tilt = np.array([0.0, np.cos(0.8), -np.sin(0.8)])   # towards the wall: every wall pixel stays on the +ns side
    normals = flat.normals.copy()
    normals[floor] = tilt
    tilted = dataclasses.replace(flat, normals=normals, _hash=None)
    wi = -light.direction / np.linalg.norm(light.direction)
    expected = float(tilt @ wi) / float(np.array([0.0, 1.0, 0.0]) @ wi)
    params = dict(EXACT, progressive_frames=4)
    a = run_method(gl_ctx, ForwardLightCuts, flat, "main", 48, 36, params, frames=1).indirect
    b = run_method(gl_ctx, ForwardLightCuts, tilted, "main", 48, 36, params, frames=1).indirect
    assert abs(expected - 1.0) > 0.1
    assert b.mean() / a.mean() == pytest.approx(expected, rel=1e-3)


def test_divergent_triangles_are_presplit_into_sub_patches(gl_ctx):
    """At n_avg = 4096 the open box's 2 m^2 triangles need more than tessellation level
    TESS_SUB_LEVEL: each is appended as m x m equal sub-patches (m > 1) that this level makes
    regular, and the result still agrees with the exact sum."""
    scene = make_open_box()
    params = dict(EXACT, n_avg=4096, levels=3, eps_rel=0.05, progressive_frames=16, reach="eq18_printed")
    r = run_method(gl_ctx, ForwardLightCuts, scene, "main", 48, 36, params, frames=1)
    ml = run_method(gl_ctx, ManyLights, scene, "main", 48, 36, {"emission": "flc", "jitter_frames": 256, "eps_rel": 0.05},
                    frames=1)
    assert r.extra["divergent_triangles"] == 6
    area = compute_facts(scene).area_max_m2
    m = int(presplit_count(area * (1 + CPU_MARGIN), measure_fmax(gl_ctx)[TESS_SUB_LEVEL - 1],
                           r.extra["S_bar_N_m2"] * (1 - CPU_MARGIN)))
    assert m > 1 and r.extra["divergent_patch_vertices"] == 6 * m * m * 3
    assert rel_mse(r.indirect, ml.indirect) < 0.03


def test_divergent_stage_skipped_when_no_triangle_is_divergent(gl_ctx):
    r = run_method(gl_ctx, ForwardLightCuts, make_grid_box(8), "main", 32, 24, {"n_avg": 8}, frames=1)
    assert r.extra["divergent_triangles"] == 0
    assert r.skipped_stages == ("divergent",)
    assert {"regular", "upscale_blur", "gbuffer_shadow"} <= set(r.stage_ms)
    assert r.indirect.max() > 0


def test_interleaved_sampling_keeps_the_expectation(gl_ctx):
    scene = make_grid_box(6)
    base = dict(EXACT, n_avg=16, levels=2, mu=2.0, eps_rel=0.3, progressive_frames=48)
    means = {}
    for level in (0, 2):
        r = run_method(gl_ctx, ForwardLightCuts, scene, "main", 48, 36, dict(base, tiling_level=level), frames=1)
        means[level] = r.indirect.mean()
    assert means[2] == pytest.approx(means[0], rel=0.05)


def test_default_frame_is_finite_and_deterministic(gl_ctx):
    scene = make_grid_box(6)
    a = run_method(gl_ctx, ForwardLightCuts, scene, "main", 64, 48, {}, seed=5, frames=1)
    b = run_method(gl_ctx, ForwardLightCuts, scene, "main", 64, 48, {}, seed=5, frames=1)
    c = run_method(gl_ctx, ForwardLightCuts, scene, "main", 64, 48, {}, seed=6, frames=1)
    assert np.array_equal(a.indirect, b.indirect)
    assert not np.array_equal(a.indirect, c.indirect)
    assert np.all(np.isfinite(a.indirect)) and a.indirect.max() > 0
    assert set(a.stage_ms) >= {"regular", "divergent", "upscale_blur"}


def test_zero_area_triangle_is_never_a_vpl(gl_ctx):
    scene = make_grid_box(4)
    # Scene.build drops degenerate triangles, so append one by hand (repeated vertex: area 0,
    # its normal would be NaN and poison the image if it were ever splatted)
    faces = np.concatenate([scene.faces, [[0, 0, 5]]])
    albedo = np.concatenate([scene.albedo, [[1.0, 1.0, 1.0]]])
    degenerate = dataclasses.replace(scene, faces=faces, albedo=albedo, _hash=None)
    params = dict(n_avg=8, progressive_frames=8)
    ref = run_method(gl_ctx, ForwardLightCuts, scene, "main", 32, 24, params, frames=1)
    out = run_method(gl_ctx, ForwardLightCuts, degenerate, "main", 32, 24, params, frames=1)
    assert np.array_equal(out.indirect, ref.indirect)


@pytest.mark.parametrize("divergent", [False, True])
def test_tiny_eps_gives_no_nan_or_inf(gl_ctx, divergent):
    params = dict(eps_rel=1e-6, tiling_level=0, blur_radius=0, n_avg=256 if divergent else 8, last_level_unbounded=True)
    r = run_method(gl_ctx, ForwardLightCuts, make_open_box() if divergent else make_grid_box(8), "main", 48, 36,
                   params, frames=1)
    assert np.all(np.isfinite(r.indirect)) and r.indirect.max() > 0


def test_bad_parameter_is_named(gl_ctx):
    with pytest.raises(ParamError, match="'mu'"):
        run_method(gl_ctx, ForwardLightCuts, make_open_box(), "main", 16, 16, {"mu": 1.0}, frames=1)
    with pytest.raises(ParamError, match="'tiling_level'"):
        run_method(gl_ctx, ForwardLightCuts, make_open_box(), "main", 16, 16, {"tiling_level": 9}, frames=1)


def test_energy_beyond_support_measurement(gl_ctx):
    scene = make_grid_box(4)
    shares = [energy_beyond_support(gl_ctx, scene, "main", 32, 24, {"mu": mu, "levels": n, "reach": "eq18_printed"})
              ["share_beyond_DN"] for mu, n in ((2.0, 3), (4.0, 5), (16.0, 15))]
    assert 0.0 < shares[1] < shares[0] <= 1.0
    assert shares[2] < 1e-6  # D_N far beyond the scene: only (nearly) grazing pairs are cut



def test_level_statistics_is_consistent(gl_ctx):
    scene = make_grid_box(4)   # every triangle faces the point light: 12 m^2 lit
    params = {"mu": 4.0, "levels": 1, "progressive_frames": 4}
    bounded = level_statistics(gl_ctx, scene, "main", 32, 24, dict(params, last_level_unbounded=False))
    unbounded = level_statistics(gl_ctx, scene, "main", 32, 24, params)
    beyond = energy_beyond_support(gl_ctx, scene, "main", 32, 24, params)["share_beyond_DN"]
    assert 0.0 < beyond < 1.0
    assert bounded["share"].sum() == pytest.approx(1.0 - beyond, abs=1e-9)
    assert unbounded["share"].sum() == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(unbounded["lit_vpls_per_subframe"] * unbounded["S_m2"], 12.0, rtol=1e-5)
    assert unbounded["relative_std"] == pytest.approx(unbounded["relative_std_subframe"] / 2.0)
    assert unbounded["relative_std_subframe"] > bounded["relative_std_subframe"] > 0.0

# ---------------------------------------------------------------------------- cornell_spot
# Every part of the pipeline on that scene (spot light, shadowed two-sided E, jitter, tessellated
# divergent triangles) matches `manylights` to ~1% once the level noise is removed (one level).
W, H = 64, 48


@pytest.fixture(scope="module")
def cornell_spot(_session_gl_ctx):
    scene = load_scene("cornell_spot")
    ml = run_method(_session_gl_ctx, ManyLights, scene, "main", W, H, {"emission": "flc", "jitter_frames": 64},
                    seed=1, frames=1).indirect
    return scene, ml


def _blocks(img):
    return img.mean(-1).reshape(4, H // 4, 4, W // 4).mean((1, 3))


@pytest.mark.parametrize("n_avg,frames,divergent,tol", [(256, 32, 996, 0.015), (32, 128, 0, 0.03)])
def test_cornell_spot_single_level_matches_manylights(gl_ctx, cornell_spot, n_avg, frames, divergent, tol):
    """levels = 0 and unbounded: f^0 = 1 everywhere, so each kept triangle (piece) is one VPL of
    weight S_0 over the whole screen and the level noise is small. n_avg = 256 makes every triangle
    divergent (tessellated pieces), n_avg = 32 none (regular pass only)."""
    scene, ml = cornell_spot
    params = dict(EXACT, levels=0, n_avg=n_avg, progressive_frames=frames)
    r = run_method(gl_ctx, ForwardLightCuts, scene, "main", W, H, params, frames=1)
    assert r.extra["divergent_triangles"] == divergent
    # tolerances ~3 standard errors (about 0.5% and 1%: few VPLs per sub-frame at n_avg = 32)
    assert r.indirect.mean() / ml.mean() == pytest.approx(1.0, abs=tol)
    np.testing.assert_allclose(_blocks(r.indirect) / _blocks(ml), 1.0, atol=0.04)


# ---------------------------------------------------------------------------- frame pipeline
def test_receiver_normal_encoding_round_trips_every_direction(gl_ctx):
    """The deinterleaved receivers (receivers.glsl) keep every unit normal, the axes included
    (an octahedral code whose "no receiver" marker was the code of -z dropped every wall
    facing -z), to within the 16-bit snorm quantisation."""
    rng = np.random.default_rng(0)
    axes = np.concatenate([np.eye(3), -np.eye(3)])
    random = rng.normal(size=(250, 3))
    normals = np.concatenate([axes, random / np.linalg.norm(random, axis=1, keepdims=True)]).astype(np.float32)
    src = GLSL_VERSION + "\n" + define_block({}) + expand_includes(SHADERS / "receivers.glsl") + """
layout(local_size_x = 1) in;
layout(std430, binding = 3) buffer Io { vec4 io[]; };
void main() {
    uint i = gl_GlobalInvocationID.x;
    uint code = encode_receiver_normal(io[i].xyz);
    io[i] = vec4(decode_receiver_normal(code), code == RECEIVER_NONE ? 1.0 : 0.0);
}
"""
    prog = gl_ctx.compute_shader(src)
    buf = gl_ctx.buffer(np.concatenate([normals, np.zeros((len(normals), 1), np.float32)], axis=1).tobytes())
    try:
        buf.bind_to_storage_buffer(3)
        prog.run(group_x=len(normals))
        out = np.frombuffer(buf.read(), np.float32).reshape(-1, 4)
    finally:
        buf.release()
        prog.release()
    assert not out[:, 3].any(), normals[out[:, 3] > 0]
    assert np.abs(out[:, :3] - normals).max() < 1e-3


def test_compute_selection_gives_the_single_draw_image(gl_ctx):
    """The regular pass's compute selection (ordered, in scene order) draws exactly what the
    paper's single draw of the whole scene would: the same image, bit for bit, with divergent
    triangles (big_floor) and several levels (cornell_spot at levels 2)."""
    for name, params in (("big_floor", {}), ("cornell_spot", {"levels": 2})):
        scene = load_scene(name)
        images = [run_method(gl_ctx, ForwardLightCuts, scene, "main", 64, 48, dict(params, regular_selection=mode),
                             seed=5, frames=1).indirect for mode in ("compute", "single_draw")]
        assert images[0].max() > 0
        assert np.array_equal(images[0], images[1]), name
