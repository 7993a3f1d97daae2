"""Deep Screen Space (`dss`), issue #23: a face one or two pixels wide (the side of a column,
a fin seen edge-on) has no grid receiver of its surface at the coarse levels; it gets receivers
of its own (the thin-face slots, rule (4) of the manual) instead of another surface's irradiance
(which gave sponza's thin faces 3x theirs and made its ladder rise)."""
import numpy as np
import pytest

from bench.model.scene import Camera, DirectionalLight
from methods.dss.method import DeepScreenSpace, orient_radius
from tests.conftest import grid_quad, scene_from_parts
from tests.methods.test_dss import brute_force_surfels, dss_frame, rel_mse

W, H = 96, 64


def fins_scene():
    """A lit floor and back wall with nine thin fins (0.1 m faces along x) standing edge-on to the
    camera: each fin's face covers one or two pixels of a column, between floor and wall pixels."""
    parts = [grid_quad([-2, 0, -2], [0, 0, 4], [4, 0, 0], 4),       # floor, normal +y
             grid_quad([-2, 0, -2], [4, 0, 0], [0, 2, 0], 4)]       # back wall, normal +z
    xs = np.linspace(-1.6, 1.6, 9)
    parts += [grid_quad([x, 0, -1.05], [0, 1.2, 0], [0, 0, 0.1], 1) for x in xs]   # fins, normal +-x
    return scene_from_parts("fins", parts, [[0.8] * 3] * len(parts), [DirectionalLight([0.3, -1.0, -0.2], [3.0] * 3)],
                            {"main": Camera([0.0, 1.2, 3.0], [0.0, 0.5, -1.0], fov_y_deg=50)})


def test_orient_radius_is_half_the_inner_shell():
    assert orient_radius(8.0) == 4 and orient_radius(0.25) == 1 and orient_radius(256.0) == 8


@pytest.mark.parametrize("rung", DeepScreenSpace.ladder, ids=lambda r: ",".join(f"{k}={v}" for k, v in r.items()) or "defaults")
def test_thin_faces_match_the_sum_over_surfels_on_every_rung(gl_ctx, rung):
    """On every rung (the defaults included) the fins' pixels stay close to the exact sum over the
    same surfels: mean within 5%, relative MSE under 0.04 (measured 0.98-1.01, 0.002-0.023).
    Taking the coarse levels from the floor and wall around them (another orientation) left them
    15-17% dark with relMSE 0.06-0.08."""
    f = dss_frame(gl_ctx, fins_scene(), rung, W, H)
    expected, covered = brute_force_surfels(f)
    got = f["indirect"][..., :3].astype(np.float64)
    fin = covered & (np.abs(f["normal"][..., 0]) > 0.9)
    assert 30 < fin.sum() < 200   # thin: a few pixels per fin
    assert abs(got[fin].mean() / expected[fin].mean() - 1) < 0.05
    assert rel_mse(got, expected, fin) < 0.04
    assert rel_mse(got, expected, covered) < 0.02
