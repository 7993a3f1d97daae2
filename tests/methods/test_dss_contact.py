"""Deep Screen Space (`dss`), issue #23: the light at a right-angle contact. A wall standing on a
lit floor gets, just above the floor, about half the floor's radiosity (the floor fills half of
its hemisphere), and almost all of it from the floor within a few heights of the point. The
point term of a surfel (cosines taken at its centre) sends nothing to a receiver in the
surfel's plane, so a wall row lower than the floor's surfels are wide stays dark (lost_empire's
20 worst pixels, a wall row under a lit ceiling, read 0.026 of Mitsuba's 0.15). With
`exact_reach` > 0 (1 by default since 2026-12-03: manual rule (5)) the transfer within that many
surfel reaches is the exact form factor of the surfel's sub-triangle, drawn into every interleaved
sub-buffer with weight 1, with the radiosity at the receiver's contact for the part of it from near
the contact (`contact_scale`)."""
import numpy as np
import pytest

from bench.model.scene import Camera, DirectionalLight
from methods.dss.method import DeepScreenSpace
from tests.conftest import grid_quad, scene_from_parts
from bench.run.harness import run_method
from tests.methods.test_dss import EXACT as EXACT_SUM
from tests.methods.test_dss import dss_frame, rel_mse, triangle_form_factor

W, H = 96, 64
E0, RHO_FLOOR, RHO_WALL = 2.0, 0.8, 0.7


def wall_on_lit_floor():
    """A 4 x 4 m floor of 1 m tiles (normal +y) lit straight from above, uniform radiosity
    RHO_FLOOR E0, and an unlit 4 x 2 m wall of 1 m tiles at z = 0 (normal +z) standing on its edge,
    seen from 1.5 m (a pixel ~1.7 cm on the wall). A 70 x 70 m screen edge-on to the light, out of
    view, sets the surfel size as lost_empire's size does: 8192 surfels over the scene give ~0.6
    m^2 each, so each half-tile (0.5 m^2) is one surfel whose centre is 1/3 m from the wall."""
    parts = [grid_quad([-2, 0, 0], [0, 0, 4], [4, 0, 0], 4),     # floor, normal +y
             grid_quad([-2, 0, 0], [4, 0, 0], [0, 2, 0], 4),     # wall, normal +z
             grid_quad([40, -35, -35], [0, 70, 0], [0, 0, 70], 1)]   # screen, normal +-x, unlit
    return scene_from_parts("wall_on_lit_floor", parts, ([RHO_FLOOR] * 3, [RHO_WALL] * 3, [0.5] * 3),
                            [DirectionalLight([0.0, -1.0, 0.0], [E0] * 3)],
                            {"main": Camera([0.0, 0.45, 1.5], [0.0, 0.15, 0.0], fov_y_deg=40)})


def exact_wall_radiance(points, origin):
    """rho_wall / pi * B_floor * F(x -> floor) at wall points (re-centred), F exact (Lambert)."""
    floor = np.array([[-2, 0, 0], [2, 0, 0], [2, 0, 4], [-2, 0, 4]], float) - origin
    nx = np.tile([0.0, 0.0, 1.0], (len(points), 1))
    tau = np.zeros(len(points))
    f = sum(triangle_form_factor(floor[a] - points, floor[b] - points, floor[c] - points, nx, tau)
            for a, b, c in ((0, 1, 2), (0, 2, 3)))
    return RHO_WALL / np.pi * RHO_FLOOR * E0 * f


def test_triangle_form_factor_limits():
    """The numpy model of the shader's form factor: 1/2 from a point on a wall to the floor it
    stands on, at any height (an unbounded floor fills half the hemisphere), nothing from a
    coplanar or a hidden triangle."""
    big = 1e4
    floor = np.array([[-big, 0, 0], [big, 0, 0], [big, 0, big], [-big, 0, big]], float)
    for height in (1e-3, 0.1, 1.0):
        x = np.array([[0.0, height, 0.0]])
        nx, tau = np.array([[0.0, 0.0, 1.0]]), np.zeros(1)
        f = sum(triangle_form_factor(floor[[a]] - x, floor[[b]] - x, floor[[c]] - x, nx, tau)
                for a, b, c in ((0, 1, 2), (0, 2, 3)))
        assert abs(f[0] - 0.5) < 1e-3, (height, f)
    tri = np.array([[[1.0, 0, 0]], [[2.0, 0, 0]], [[1.0, 0, 1.0]]])
    up = np.array([[0.0, 1.0, 0.0]])
    assert triangle_form_factor(*tri, up, np.zeros(1))[0] == 0.0           # in the receiver's plane
    assert triangle_form_factor(*(tri - [0, 1, 0]), up, np.zeros(1))[0] == 0.0   # below its horizon


EXACT_REACH = 4.0


def test_exact_sum_over_surfels_matches_the_analytic_contact(gl_ctx):
    """The plain sum over the surfels (one level, no interleaving, no blur, no cut) with
    exact_reach 4 gives the exact radiance everywhere on the wall (each half-tile of the
    floor is one surfel of uniform radiosity: the exact transfer is exact here), the lowest row
    included; with the point term (exact_reach 0) the three lowest rows read 0.08, 0.19, 0.29."""
    scene = wall_on_lit_floor()
    assert DeepScreenSpace.params["exact_reach"].default == 1.0
    for reach in (EXACT_REACH, 0.0):
        f = dss_frame(gl_ctx, scene, dict(EXACT_SUM, exact_reach=reach), W, H)
        wall, expected, rows = wall_pixels(f)
        got = f["indirect"][..., 0].astype(np.float64)
        ratio = got[wall] / expected[wall]
        lowest = got[rows[0]][wall[rows[0]]].mean() / expected[rows[0]][wall[rows[0]]].mean()
        if reach > 0:
            # float32 on the GPU: measured max 1.4e-3
            assert np.abs(ratio - 1).max() < 5e-3 and abs(ratio.mean() - 1) < 1e-3, np.abs(ratio - 1).max()
        else:
            assert lowest < 0.5, lowest


def wall_pixels(f):
    """Wall mask, exact radiance and the wall's rows within 3 pixel footprints of the floor
    (lowest first), in the frame's GL row order."""
    pos, nrm = f["position"], f["normal"]
    wall = (pos[..., 3] > 0) & (nrm[..., 2] > 0.99)
    expected = np.zeros(wall.shape)
    expected[wall] = exact_wall_radiance(pos[wall][:, :3].astype(np.float64), f["origin"])
    height = pos[..., 1] + f["origin"][1]
    footprint = 1.5 * 2 * np.tan(np.radians(20)) / H
    contact = wall & (height < 3 * footprint)
    rows = sorted((r for r in range(H) if contact[r].sum() > 20), key=lambda r: height[r][contact[r]].mean())
    assert len(rows) == 3
    return wall, expected, rows


@pytest.mark.parametrize("exact_reach", [EXACT_REACH, 0.0], ids=["exact_reach_4", "point_term"])
def test_contact_rows_get_the_floors_light(gl_ctx, exact_reach):
    """With exact_reach 4 and the other parameters at their defaults the wall's three lowest rows
    match the exact one-bounce radiance of
    the uniformly lit floor over seeds 0-3 (interleaving sends each of the few large surfels there
    to one of 4 sub-buffers, weight 4: the lowest row's mean reads 0.92-1.31 by seed; measured
    mean over the seeds 1.15, 1.08, 1.01 from the lowest row up, the wall 1.004, relMSE 0.0035),
    and the whole wall too. The defaults' point term everywhere (exact_reach 0) leaves those rows
    at 0.16, 0.24, 0.31 (wall 0.95, relMSE 0.12): the test's check that it can fail. (Until
    2026-12-03 the point term was the default; the near field is no longer interleaved.)"""
    scene = wall_on_lit_floor()
    params = {"exact_reach": exact_reach}
    f = dss_frame(gl_ctx, scene, params, W, H)
    wall, expected, rows = wall_pixels(f)
    wall, expected, rows = wall[::-1], expected[::-1], [H - 1 - r for r in rows]   # images: top row first
    images = [run_method(gl_ctx, DeepScreenSpace, scene, "main", W, H, params, seed=seed, frames=1).indirect[..., 0]
              for seed in range(4)]
    got = np.mean(images, axis=0).astype(np.float64)
    row_ratio = [got[r][wall[r]].mean() / expected[r][wall[r]].mean() for r in rows]
    if exact_reach == 0.0:
        assert row_ratio[0] < 0.5, row_ratio
        return
    assert all(abs(r - 1) < 0.25 for r in row_ratio), row_ratio
    assert abs(np.mean(row_ratio) - 1) < 0.15, row_ratio
    assert abs(got[wall].mean() / expected[wall].mean() - 1) < 0.05
    assert rel_mse(got, expected, wall) < 0.01


def test_defaults_light_the_contact_rows(gl_ctx):
    """At the defaults (exact_reach 1, near field in every sub-buffer, contact radiosity) one seed
    gives the wall's three lowest rows the floor's light and the whole wall its exact radiance. The
    code before (point term at the defaults) read 0.16, 0.24, 0.31 in those rows."""
    scene = wall_on_lit_floor()
    f = dss_frame(gl_ctx, scene, {}, W, H)
    wall, expected, rows = wall_pixels(f)
    wall, expected, rows = wall[::-1], expected[::-1], [H - 1 - r for r in rows]   # images: top row first
    got = run_method(gl_ctx, DeepScreenSpace, scene, "main", W, H, {}, seed=0, frames=1).indirect[..., 0]
    got = got.astype(np.float64)
    row_ratio = [got[r][wall[r]].mean() / expected[r][wall[r]].mean() for r in rows]
    assert all(abs(r - 1) < 0.15 for r in row_ratio), row_ratio
    assert abs(got[wall].mean() / expected[wall].mean() - 1) < 0.05
    assert rel_mse(got, expected, wall) < 0.01
