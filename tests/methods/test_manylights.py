"""manylights against a brute-force numpy evaluation of the same formula (eq. 4)."""
import numpy as np
import pytest

from bench.gl import render_gbuffer
from bench.harness import run_method
from methods.manylights.method import ManyLights
from tests.conftest import make_grid_box, make_open_box


def brute_force(scene, gbuffer, emission: str, eps: float) -> np.ndarray:
    tri = scene.vertices[scene.faces]
    y, area, n = tri.mean(axis=1), scene.areas(), scene.face_normals()
    light = scene.lights[0]

    def irradiance(p, normal):
        d = light.position - p
        r2 = (d * d).sum(-1)
        w = d / np.sqrt(r2)[:, None]
        return light.intensity[None] * (np.maximum((w * normal).sum(-1), 0) / r2)[:, None]

    front, back = scene.albedo * irradiance(y, n), scene.albedo * irradiance(y, -n)
    m = gbuffer["mask"]
    x, nx, rho_x = gbuffer["position"][m], gbuffer["normal"][m], gbuffer["albedo"][m]
    d = y[None] - x[:, None]
    dist = np.linalg.norm(d, axis=-1)
    w = d / dist[..., None]
    cos_x = np.maximum((nx[:, None] * w).sum(-1), 0)
    cos_y = -(n[None] * w).sum(-1)
    radiosity = np.where((cos_y > 0)[..., None], front[None], back[None])
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
    from bench.method import SkipRow
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
    expected = brute_force(scene, g, "lambert", 1e-4 * radius)
    assert expected.max() > 0
    assert np.abs(result.indirect - expected).max() <= 1e-4 * expected.max()
