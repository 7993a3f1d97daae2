"""manylights against a brute-force numpy evaluation of the same formula (eq. 4)."""
import numpy as np
import pytest

from bench.gl import create_context, render_gbuffer
from bench.model.corpus import load_scene
from bench.model.scene import Camera, PointLight, Scene, SpotLight
from bench.protocol.method import SkipRow
from bench.run.harness import run_method
from bench.stress.perturb import sliver
from methods.manylights.method import ManyLights
from reference.api import get_reference
from tests.conftest import grid_quad, make_grid_box, make_open_box, scene_from_parts


def segment_blocked(scene, y, light, eps=1e-4):
    """Does the open segment y_i -> light hit a triangle? (Moller-Trumbore; the shadow rays)"""
    tri = scene.vertices[scene.faces]
    a, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    blocked = np.zeros(len(y), bool)
    for i, p in enumerate(y):
        d = light - p
        h = np.cross(d, e2)
        det = (e1 * h).sum(-1)
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = p - a
        u = (s * h).sum(-1) * inv
        q = np.cross(s, e1)
        v = (q * d).sum(-1) * inv
        t = (q * e2).sum(-1) * inv
        blocked[i] = np.any(ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > eps) & (t < 1 - eps))
    return blocked


def normalize(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def brute_force(scene, gbuffer, emission: str, eps: float, shading: bool = True, shadows: bool = True) -> np.ndarray:
    """Eq. 4 over centroid VPLs: incident cosine and side against the shading normal at the
    centroid (vertex normals interpolated; `shading=False`: the face normal), geometric term
    against the face normal."""
    tri = scene.vertices[scene.faces]
    y, area, n = tri.mean(axis=1), scene.areas(), scene.face_normals()
    ns = normalize(scene.normals[scene.faces].mean(axis=1)) if shading else n
    light = scene.lights[0]

    lit = ~segment_blocked(scene, y, light.position) if shadows else np.ones(len(y), bool)

    def irradiance(p, normal):
        d = light.position - p
        r2 = (d * d).sum(-1)
        w = d / np.sqrt(r2)[:, None]
        return light.intensity[None] * (np.maximum((w * normal).sum(-1), 0) / r2 * lit)[:, None]

    front, back = scene.albedo * irradiance(y, ns), scene.albedo * irradiance(y, -ns)
    m = gbuffer["mask"]
    x, nx, rho_x = gbuffer["position"][m], gbuffer["normal"][m], gbuffer["albedo"][m]
    d = y[None] - x[:, None]
    dist = np.linalg.norm(d, axis=-1)
    w = d / dist[..., None]
    cos_x = np.maximum((nx[:, None] * w).sum(-1), 0)
    cos_y = -(n[None] * w).sum(-1)
    radiosity = np.where(((ns[None] * w).sum(-1) < 0)[..., None], front[None], back[None])
    lobe = 1.5 / np.pi * np.abs(cos_y) if emission == "flc" else np.full_like(cos_y, 1 / np.pi)
    contrib = radiosity * (lobe * cos_x * np.abs(cos_y) / np.maximum(eps, dist) ** 2 * area[None])[..., None]
    out = np.zeros(gbuffer["position"].shape)
    out[m] = rho_x / np.pi * contrib.sum(axis=1)
    return out


@pytest.mark.parametrize("emission", ["lambert", "flc"])
def test_matches_numpy_brute_force(gl_ctx, emission):
    scene = make_open_box()
    result = run_method(gl_ctx, ManyLights, scene, "main", 48, 40, {"emission": emission}, frames=1)
    g = render_gbuffer(gl_ctx, scene, "main", 48, 40)
    radius = 0.5 * np.linalg.norm(scene.vertices.max(0) - scene.vertices.min(0))
    expected = brute_force(scene, g, emission, 1e-4 * radius)
    assert expected.max() > 0
    # float32 precision on the GPU
    assert np.abs(result.indirect - expected).max() <= 2e-6 * expected.max()
    assert set(result.stage_ms) >= {"gbuffer_shadow", "direct_light", "vpl_irradiance", "gather"}


def test_jitter_converges_and_is_deterministic(gl_ctx):
    scene = make_grid_box(8)
    a = run_method(gl_ctx, ManyLights, scene, "main", 32, 32, {"jitter_frames": 32}, seed=3, frames=1)
    b = run_method(gl_ctx, ManyLights, scene, "main", 32, 32, {"jitter_frames": 32}, seed=3, frames=1)
    c = run_method(gl_ctx, ManyLights, scene, "main", 32, 32, {"jitter_frames": 32}, seed=4, frames=1)
    assert np.array_equal(a.indirect, b.indirect)
    assert not np.array_equal(a.indirect, c.indirect)
    # jittered averages of two seeds agree closely (the centroid rule differs by its bias)
    rel = np.abs(a.indirect - c.indirect).mean() / a.indirect.mean()
    assert rel < 0.05


def test_skips_scene_over_budget(gl_ctx):
    with pytest.raises(SkipRow, match="triangles"):
        run_method(gl_ctx, ManyLights, make_open_box(), "main", 16, 16, {"max_triangles": 2}, frames=1)


def test_more_vpls_than_one_shader_loop_may_run(gl_ctx):
    """llvmpipe stops a shader invocation after 65535 loop iterations in total; the gather is
    split into draws so a scene with more triangles is still summed whole."""
    scene = make_grid_box(109)  # 71,286 triangles
    assert len(scene.faces) > 65535
    result = run_method(gl_ctx, ManyLights, scene, "main", 12, 10, frames=1, shadow_resolution=256)
    g = render_gbuffer(gl_ctx, scene, "main", 12, 10)
    radius = 0.5 * np.linalg.norm(scene.vertices.max(0) - scene.vertices.min(0))
    expected = brute_force(scene, g, "lambert", 1e-4 * radius, shadows=False)  # nothing occludes the light
    assert expected.max() > 0
    assert np.abs(result.indirect - expected).max() <= 1e-4 * expected.max()


def smooth_cube_scene():
    """A cube of 8 shared vertices (area-weighted vertex normals: smooth shading that tilts up to
    55 degrees from the faces) on a flat floor under a point light."""
    c = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (0.2, 1.2) for z in (-0.5, 0.5)], float)
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    tri = c[f]
    inward = (np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]) * (tri.mean(1) - [0, 0.7, 0])).sum(1) < 0
    f[inward] = f[inward][:, ::-1]
    fv, ff = grid_quad([-2, 0, -2], [0, 0, 4], [4, 0, 0], 4)
    albedo = np.array([[0.8, 0.8, 0.8]] * len(ff) + [[0.9, 0.6, 0.3]] * len(f))
    return Scene.build("smooth_cube", np.concatenate([fv, c]), np.concatenate([ff, f + len(fv)]), albedo,
                       [PointLight([1.2, 2.2, 1.0], [8.0] * 3)],
                       {"main": Camera([0.8, 1.6, 3.5], [0, 0.4, 0], fov_y_deg=50)})


def test_shading_normals_match_numpy_brute_force(gl_ctx):
    """On a smooth-shaded mesh the VPL's incident cosine and its side use the vertex normals
    interpolated at the VPL (here the centroid), the geometric term the face normal."""
    scene = smooth_cube_scene()
    tri_normals = scene.normals[scene.faces].mean(axis=1)
    assert np.degrees(np.arccos(np.clip((normalize(tri_normals) * scene.face_normals()).sum(1), -1, 1))).max() > 10
    result = run_method(gl_ctx, ManyLights, scene, "main", 48, 40, frames=1)
    g = render_gbuffer(gl_ctx, scene, "main", 48, 40)
    radius = 0.5 * np.linalg.norm(scene.vertices.max(0) - scene.vertices.min(0))
    expected = brute_force(scene, g, "lambert", 1e-4 * radius)
    assert np.abs(result.indirect - expected).max() <= 1e-5 * expected.max()
    flat = brute_force(scene, g, "lambert", 1e-4 * radius, shading=False)
    assert np.abs(flat - expected).max() > 0.05 * expected.max()  # the rule matters on this mesh


def test_smooth_shaded_emitters_match_mitsuba():
    """Jittered VPLs on the smooth cube against Mitsuba's unshadowed bounce, within the noise of
    both (the face-normal cosine, which ignores the shading frame, is ~8x the noise away)."""
    pytest.importorskip("mitsuba")
    ctx = create_context()
    scene = smooth_cube_scene()
    w, h = 64, 48
    ref = get_reference(scene, "main", w, h, "indirect_unshadowed", spp_cap=2048)
    runs = [run_method(ctx, ManyLights, scene, "main", w, h, {"jitter_frames": 256}, seed=s, frames=1)
            .indirect.astype(np.float64) for s in range(4)]
    ml = np.mean(runs, axis=0)
    m = ref.coverage
    noise = float(((np.mean(runs[:2], 0) - np.mean(runs[2:], 0)) ** 2)[m].mean()) / 4
    mse = float(((ml - ref.mean) ** 2)[m].mean())
    assert mse <= 2.0 * (ref.noise_floor_mse + noise), (mse, ref.noise_floor_mse, noise)
    assert abs(ml[m].mean() / ref.mean[m].mean() - 1) < 0.02


def small_spot_on_big_triangles():
    """big_floor in small: a 4 x 4 m floor of 2 triangles whose centroids both lie outside the
    disc a narrow spot lights, and an unlit box beside the disc receiving its bounce."""
    q = lambda o, u, v: grid_quad(o, u, v, 1)  # noqa: E731
    parts = [q([-2, 0, -2], [0, 0, 4], [4, 0, 0]), q([0.1, 0, 0.7], [0, 0.6, 0], [0, 0, 0.6]),
             q([-0.5, 0, 0.7], [0, 0, 0.6], [0, 0.6, 0]), q([-0.5, 0, 1.3], [0.6, 0, 0], [0, 0.6, 0]),
             q([-0.5, 0, 0.7], [0, 0.6, 0], [0.6, 0, 0]), q([-0.5, 0.6, 0.7], [0, 0, 0.6], [0.6, 0, 0])]
    spot = SpotLight([1.0, 3.0, 1.0], [1.0, 0.0, 1.0], [20.0] * 3, cutoff_angle_deg=13.0, beam_width_deg=10.0)
    return scene_from_parts("small_spot", parts, [(0.8, 0.8, 0.8)] + [(0.7, 0.5, 0.3)] * 5, [spot],
                            {"main": Camera([2.4, 1.4, 3.0], [0.0, 0.3, 1.0], fov_y_deg=50)})


def test_centroid_vpls_miss_a_small_spot_and_jitter_converges():
    """One VPL at each triangle's centroid is eq. 4's sum over centroid VPLs, not the continuous
    integral: here both floor centroids are unlit and the bounce is 0, while jittered VPLs
    (jitter_frames > 1) converge to Mitsuba's unshadowed reference."""
    pytest.importorskip("mitsuba")
    ctx = create_context()
    scene = small_spot_on_big_triangles()
    w, h = 64, 48
    ref = get_reference(scene, "main", w, h, "indirect_unshadowed", spp_cap=256)
    m = ref.coverage
    centroid = run_method(ctx, ManyLights, scene, "main", w, h, frames=1).indirect
    jittered = run_method(ctx, ManyLights, scene, "main", w, h, {"jitter_frames": 4096}, frames=1).indirect
    assert ref.mean[m].mean() > 0
    assert abs(centroid[m].mean() / ref.mean[m].mean() - 1) > 0.5
    assert abs(jittered[m].mean() / ref.mean[m].mean() - 1) < 0.15


def test_float32_slivers_emit_nothing_instead_of_nan(gl_ctx):
    # 1e-6-aspect slivers on the rooms' surfaces: their float32 cross product can vanish; the
    # normalised normal then made every pixel they reach NaN (the stress suite's degenerate row)
    base = load_scene("rooms")
    scene = sliver(base, count=32, seed=0)
    out = run_method(gl_ctx, ManyLights, scene, "main", 32, 24, {}, frames=1)
    ref = run_method(gl_ctx, ManyLights, base, "main", 32, 24, {}, frames=1)
    assert np.isfinite(out.indirect).all()
    assert abs(out.indirect.mean() / ref.indirect.mean() - 1.0) < 0.01
