"""The near field the VPL methods share (bench/gl/near_field.py, issue #23), at their defaults.

A 1 m wall stands on a 30 x 30 m floor lit by a sun: the VPLs the RSM draws on the floor stand
for about 1 m^2 each at 1024 VPLs, so the wall's lowest pixels lie within a VPL's footprint
radius of floor VPLs. The point term's 1/d^2 (near_field=clamp, eps = 1e-4 of the scene radius)
lights them many times over; the default bound clamps each VPL's distance at the radius of the
area it stands for. The same VPLs and visibility otherwise: no pixel brighter than with the
point term, and the pixels beside the floor VPLs lower. (The bound's bias is the light of the floor within a
footprint radius of the wall: at 1 m^2 per VPL it takes a quarter of this small scene's bounce,
and vanishes as 1 / N with the VPL count.)
"""
from __future__ import annotations

import pytest

from bench.model.scene import Camera, DirectionalLight
from bench.protocol.method import SkipRow
from bench.protocol.registry import load_method
from bench.run.harness import run_method
from tests.conftest import grid_quad, scene_from_parts

W, H = 64, 48


def wall_on_a_wide_floor():
    parts = [grid_quad([-15, 0, -15], [0, 0, 30], [30, 0, 0], 1),          # floor, normal +y
             grid_quad([-0.3, 0, 0], [0.6, 0, 0], [0, 1.0, 0], 4)]         # wall facing +z
    return scene_from_parts("wall_on_floor", parts, ([0.8] * 3, [0.8] * 3),
                            [DirectionalLight([0.3, -1.0, -0.4], [3.0] * 3)],
                            {"main": Camera([0.0, 0.35, 1.2], [0.0, 0.1, 0.0], fov_y_deg=50)})


@pytest.mark.parametrize("method", ["ir_unshadowed", "ir_shadowed", "val_clustered", "visibility_gates"])
def test_default_near_field_bounds_vpls_beside_a_receiver(gl_ctx, method):
    cls = load_method(method)
    assert cls.params["near_field"].default == "footprint"
    scene = wall_on_a_wide_floor()
    try:
        bounded = run_method(gl_ctx, cls, scene, "main", W, H, {}, frames=1).indirect
    except SkipRow as exc:
        pytest.skip(f"{method} declines the scene: {exc}")
    point = run_method(gl_ctx, cls, scene, "main", W, H, {"near_field": "clamp"}, frames=1).indirect
    assert (bounded <= point * (1 + 1e-5) + 1e-9).all()
    lowered = bounded.max(axis=2) < 0.9 * point.max(axis=2)
    assert lowered.sum() >= 5, lowered.sum()
    assert bounded.mean() > 0.7 * point.mean()
