"""The shared shadow test's acne offsets erode shadows by about their size (bench/gl/shaders/
shadow.glsl). A wall under an overhang, lit by a slanted sun, has an exact shadow line; the band
just above it must stay dark (the former offsets, up to 2 texels along the normal, lit 41% of it:
sponza's sun lines under its roof), and the lit wall below must not darken (acne)."""
import numpy as np

from bench.gl.passes import render_direct, render_gbuffer
from bench.model.scene import Camera, DirectionalLight, Scene

SLAB_Y, SLAB_DEPTH = 3.0, 0.5
SUN_TRAVEL = np.array([0.0, -1.0, -0.35])           # down and towards the wall (z = 0, facing +z)
SHADOW_LINE = SLAB_Y - SLAB_DEPTH / 0.35             # wall points above it see the slab towards the sun
BAND = 0.25                                         # m above the line, checked for light leaking
SHADOW_RESOLUTION = 256


def wall_under_overhang():
    v = np.array([[-2, 0, 0], [2, 0, 0], [2, 4, 0], [-2, 4, 0],                      # wall, normal +z
                  [-2, SLAB_Y, 0], [2, SLAB_Y, 0], [2, SLAB_Y, SLAB_DEPTH], [-2, SLAB_Y, SLAB_DEPTH]], float)
    f = np.array([[0, 1, 2], [0, 2, 3], [4, 6, 5], [4, 7, 6]])
    albedo = np.full((4, 3), 0.5)
    sun = DirectionalLight(SUN_TRAVEL, [3.0, 3.0, 3.0])
    camera = Camera([0.0, 1.6, 2.0], [0.0, 1.6, 0.0], fov_y_deg=40.0)
    return Scene.build("wall_under_overhang", v, f, albedo, [sun], {"main": camera})


def test_shadow_line_under_an_overhang_is_not_eroded(gl_ctx):
    scene = wall_under_overhang()
    g = render_gbuffer(gl_ctx, scene, "main", 128, 96)
    direct = render_direct(gl_ctx, scene, "main", 128, 96, shadows=True, shadow_resolution=SHADOW_RESOLUTION)
    y = g["position"][..., 1]
    wall = g["mask"] & (np.abs(g["position"][..., 2]) < 1e-4) & (np.abs(g["position"][..., 0]) < 1.0)
    lit = direct.mean(-1) > 0
    band = wall & (y > SHADOW_LINE) & (y < SHADOW_LINE + BAND)
    below = wall & (y < SHADOW_LINE - 0.1)
    assert band.sum() > 200 and below.sum() > 200
    assert lit[band].mean() < 0.3, lit[band].mean()        # 0.12; the former offsets: 0.41
    assert lit[below].all()                                  # no acne on the lit wall
    assert not lit[wall & (y > SHADOW_LINE + BAND) & (y < SLAB_Y - 0.05)].any()
