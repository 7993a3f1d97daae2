"""FLC's near field (issue 10): the d_i of eq. 5 that each `near_field` setting gives a VPL, on
a scene where it can be written down. One small emitter triangle hangs at height h = r_0 (the
radius of the disc of area S_0 a level-0 VPL stands for) over a floor, lit from below by a point
light; with one level, a centroid VPL, no tiling and no blur, a frame either keeps the triangle
(one VPL of weight S_0 at its centroid, probability A / S_0 = 0.98) or not, whatever `near_field`
is. So, same seed, the images of two settings differ pixel by pixel only by their d_i^2, and the
paper's is the closed form of eq. 5 - 6.
"""
import numpy as np
import pytest

from bench.gl.passes import render_gbuffer
from bench.model.scene import Camera, PointLight, Scene, compute_facts
from bench.run.harness import run_method
from methods.flc.method import ForwardLightCuts

W, H = 64, 48
R0 = 0.3                 # r_0 = sqrt(S_0 / pi), and the emitter's height
KEEP = 0.98              # A / S_0: the emitter is regular and kept in most sub-frames
INTENSITY = 1.0
RHO_FLOOR, RHO_EMITTER = 0.5, 0.8


def emitter_over_floor():
    area = KEEP * np.pi * R0 ** 2
    side = np.sqrt(2.0 * area)   # triangle of base `side` and height `side`: area side^2 / 2
    v = np.array([[-2, 0, -2], [2, 0, -2], [2, 0, 2], [-2, 0, 2],
                  [-side / 2, R0, -side / 3], [side / 2, R0, -side / 3], [0, R0, 2 * side / 3]], float)
    f = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6]])
    albedo = np.array([[RHO_FLOOR] * 3] * 2 + [[RHO_EMITTER] * 3])
    light = PointLight([0.0, R0 / 2, 0.0], [INTENSITY] * 3)   # right under the emitter's centroid
    camera = Camera([1.5, 1.0, 1.5], [0.0, 0.0, 0.0], fov_y_deg=40.0)
    return Scene.build("emitter_over_floor", v, f, albedo, [light], {"main": camera}), area


@pytest.fixture(scope="module")
def setup(_session_gl_ctx):
    scene, area = emitter_over_floor()
    facts = compute_facts(scene)
    n_avg = 8
    s0 = np.pi * R0 ** 2
    # dnear_rule = scene: D_near = dnear_factor R_scene and S_0 = 4 pi D_near^2 / n_avg
    dnear_factor = float(np.sqrt(s0 * n_avg / (4 * np.pi)) / facts.scene_radius)
    params = dict(levels=0, n_avg=n_avg, dnear_rule="scene", dnear_factor=dnear_factor, tiling_level=0,
                  blur_radius=0, jitter=False)   # one frame (progressive sub-frames jitter the VPL)
    g = render_gbuffer(_session_gl_ctx, scene, "main", W, H)
    return scene, facts, area, params, g


def render(ctx, setup, near_field):
    scene, facts, _, params, _ = setup
    r = run_method(ctx, ForwardLightCuts, scene, "main", W, H, dict(params, near_field=near_field), seed=3,
                   frames=1, facts=facts)
    return r.indirect[..., 0].astype(np.float64), r.extra


def test_near_field_settings_differ_only_by_their_d_i(gl_ctx, setup):
    _, _, _, _, g = setup
    paper, extra = render(gl_ctx, setup, "paper_eps")
    assert paper.max() > 0   # this seed keeps the emitter
    assert extra["levels"] == 0 and extra["divergent_triangles"] == 2   # the floor's two; the emitter is regular
    r0 = np.sqrt(extra["S0_m2"] / np.pi)
    assert r0 == pytest.approx(R0, rel=1e-3)
    floor = g["mask"] & (np.abs(g["position"][..., 1]) < 1e-4) & (paper > 0)
    assert floor.sum() > 200
    dist2 = ((g["position"][floor] - np.array([0.0, R0, 0.0])) ** 2).sum(-1)
    assert dist2.min() < (1.3 * R0) ** 2      # pixels where the settings differ most (d ~ r_0)
    for near_field, d2 in (("disc_element", dist2 + r0 ** 2), ("vpl_disc", np.maximum(dist2, r0 ** 2))):
        img, _ = render(gl_ctx, setup, near_field)
        np.testing.assert_allclose(img[floor] / paper[floor], dist2 / d2, rtol=2e-3, err_msg=near_field)
    default, _ = render(gl_ctx, setup, ForwardLightCuts.params["near_field"].default)
    np.testing.assert_array_equal(default, render(gl_ctx, setup, "disc_element")[0])


def test_paper_near_field_is_eq5_with_eq6_lobe(gl_ctx, setup):
    """The closed form at each floor pixel x (normal up), VPL at the centroid y = (0, r_0, 0) facing
    down, lit head-on by the light r_0 / 2 below: B = rho_e I / (r_0 / 2)^2, c = cos at both ends
    = r_0 / |x - y|, L(x) = rho_x / pi * B 3 / (2 pi) c * c c / |x - y|^2 * S_0 (eq. 10's
    weight of a kept level-0 VPL)."""
    _, _, _, _, g = setup
    paper, extra = render(gl_ctx, setup, "paper_eps")
    floor = g["mask"] & (np.abs(g["position"][..., 1]) < 1e-4) & (np.linalg.norm(g["position"], axis=-1) < 1.5)
    dist2 = ((g["position"][floor] - np.array([0.0, R0, 0.0])) ** 2).sum(-1)
    c = R0 / np.sqrt(dist2)
    radiosity = RHO_EMITTER * INTENSITY / (R0 / 2) ** 2
    expected = RHO_FLOOR / np.pi * radiosity * 1.5 / np.pi * c ** 3 / dist2 * extra["S0_m2"]
    np.testing.assert_allclose(paper[floor], expected, rtol=5e-3)
