"""FLC on a scene whose lit area is a small part of huge triangles (big_floor: an 80 m floor, a
spot lighting about 3.5 m^2 of it): the divergent pass appends only the sub-patches a light can
reach (its work follows the lit area, not the scene's), the D_near rule bounds D_near by the lit
area (so the lit spot holds about N_avg VPLs a frame instead of 0 to 3), and the quality ladder.
At the defaults, small images, one frame per seed."""
import numpy as np
import pytest

from bench.gl.passes import render_gbuffer
from bench.model.corpus import load_scene
from bench.model.scene import Camera, PointLight, Scene, SpotLight, compute_facts
from bench.protocol.method import resolve_params
from bench.run.harness import run_method
from methods.flc.levels import lit_area
from methods.flc.method import ForwardLightCuts, near_radius
from methods.manylights.method import ManyLights
from tests.conftest import make_open_box

W, H = 48, 36
_CACHE: dict = {}


class DrawnPatches(ForwardLightCuts):
    """FLC that records, after each frame (outside its timed stages), the sub-patches the
    divergent pass drew: their vertices read back from the divergent buffer."""

    def render(self, frame, prof):
        out = super().render(frame, prof)
        if self.run_divergent:
            count = int(np.frombuffer(self.command.read(), dtype=np.uint32)[0])
            rec = np.frombuffer(self.divergent_vertices.read(), dtype=np.float32).reshape(-1, 3, 4)[:count]
            out.extra["drawn_positions"] = rec[:, 0, :3].astype(np.float64) + frame.gpu.origin
        return out


def big_floor():
    if "scene" not in _CACHE:
        scene = load_scene("big_floor")
        _CACHE["scene"] = scene, compute_facts(scene)
    return _CACHE["scene"]


def spot_refined(scene, half: float = 2.0, cell: float = 0.25):
    """big_floor for `manylights` (one VPL per triangle): the floor's 4 x 4 m square around the
    spot's target cut into 0.25 m cells, the rest of the floor as 4 rectangles (unlit: their
    VPLs carry no power whatever their size), everything else as is."""
    floor = (scene.areas() > 1.0) & np.all(np.abs(scene.vertices[scene.faces][:, :, 1]) < 1e-9, axis=1)
    assert floor.sum() == 2
    lo, hi = scene.vertices[scene.faces[floor]].reshape(-1, 3).min(0), scene.vertices[scene.faces[floor]].reshape(-1, 3).max(0)
    cx, cz = scene.lights[0].target[[0, 2]]
    xs = np.concatenate([[lo[0]], np.arange(cx - half, cx + half + 1e-9, cell), [hi[0]]])
    zs = np.concatenate([[lo[2]], np.arange(cz - half, cz + half + 1e-9, cell), [hi[2]]])
    verts, faces = [], []
    for i in range(len(xs) - 1):
        for k in range(len(zs) - 1):
            b = len(verts)
            verts += [[xs[i], 0, zs[k]], [xs[i + 1], 0, zs[k]], [xs[i + 1], 0, zs[k + 1]], [xs[i], 0, zs[k + 1]]]
            faces += [[b, b + 2, b + 1], [b, b + 3, b + 2]]
    verts, faces = np.asarray(verts, float), np.asarray(faces)
    albedo = scene.albedo[floor][0]
    n = len(scene.vertices)
    out = Scene.build(scene.name + "_spot_refined", np.concatenate([scene.vertices, verts]),
                      np.concatenate([scene.faces[~floor], faces + n]),
                      np.concatenate([scene.albedo[~floor], np.repeat(albedo[None], len(faces), 0)]),
                      scene.lights, scene.cameras)
    assert out.areas().sum() == pytest.approx(scene.areas().sum(), rel=1e-9)
    return out


def big_floor_reference(ctx):
    """`manylights` (flc lobe, VPLs at the centroids) on `spot_refined` big_floor."""
    if "reference" not in _CACHE:
        _CACHE["reference"] = run_method(ctx, ManyLights, spot_refined(big_floor()[0]), "main", W, H,
                                         {"emission": "flc"}, frames=1).indirect.astype(np.float64)
    return _CACHE["reference"]


def tri_area(p):
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


def test_divergent_pass_draws_only_what_a_light_reaches(gl_ctx):
    """big_floor at the defaults: of the 2000 m^2 of divergent floor and wall, the drawn
    sub-patches cover the spot's footprint and little more (the code before drew all of it)."""
    scene, facts = big_floor()
    r = run_method(gl_ctx, DrawnPatches, scene, "main", W, H, {}, frames=1, facts=facts)
    drawn = r.extra["drawn_positions"].reshape(-1, 3, 3)
    assert r.extra["divergent_triangles"] == 4 and len(drawn) > 0
    divergent_area = compute_facts(scene).sorted_areas_m2[-4:].sum()
    spot = scene.lights[0]
    centroids = drawn.mean(axis=1)
    # every drawn sub-patch lies on the floor (y = 0) near the spot's axis; none on the unlit wall
    assert np.allclose(centroids[:, 1], 0.0, atol=1e-4)
    assert np.all(np.linalg.norm(centroids[:, [0, 2]] - spot.target[[0, 2]], axis=1) < 5.0)
    # the footprint (pi (5 m tan 12 deg)^2 = 3.5 m^2) is covered, and the drawn area is < 2% of the divergent one
    footprint = np.pi * (5.0 * np.tan(np.radians(12.0))) ** 2
    assert footprint < tri_area(drawn).sum() < 0.02 * divergent_area
    # while the buffer holds room for all of it (what is not lit is left out, not cut off)
    assert r.extra["divergent_patch_vertices"] // 3 > 50 * len(drawn)


def test_big_floor_needs_the_divergent_pass(gl_ctx):
    scene, facts = big_floor()
    reference = big_floor_reference(gl_ctx).mean()
    params = dict(tiling_level=0, blur_radius=0, progressive_frames=4)
    on = run_method(gl_ctx, ForwardLightCuts, scene, "main", W, H, params, frames=1, facts=facts)
    off = run_method(gl_ctx, ForwardLightCuts, scene, "main", W, H, dict(params, divergent_pass=False), frames=1,
                     facts=facts)
    assert on.extra["divergent_triangles"] == 4 and "divergent" not in on.skipped_stages
    assert "divergent" in off.skipped_stages
    # without it the floor's bounce, nearly all the indirect light of the view, is lost
    assert off.indirect.mean() < 0.1 * reference
    # with it (only the sub-patches the spot reaches drawn), agreement with the exact sum
    assert on.indirect.mean() == pytest.approx(reference, rel=0.1)


def test_point_light_culls_no_divergent_sub_patch(gl_ctx):
    """A point light reaches every two-sided surface: every sub-patch is drawn (conservative)."""
    scene = make_open_box()
    assert [light.kind for light in scene.lights] == ["point"]
    r = run_method(gl_ctx, DrawnPatches, scene, "main", 32, 24, {}, frames=1)
    assert r.extra["divergent_triangles"] > 0
    assert len(r.extra["drawn_positions"]) == r.extra["divergent_patch_vertices"]


def test_lit_area_of_a_spot_on_a_plane():
    """The area inside a spot's cone on a 20 m plane under it: pi (h tan theta)^2; and the whole
    surface as soon as a point light is present."""
    verts = np.array([[-10, 0, -10], [10, 0, -10], [10, 0, 10], [-10, 0, 10]], float)
    faces = np.array([[0, 2, 1], [0, 3, 2]])
    spot = SpotLight([0.0, 4.0, 0.0], [0.0, 0.0, 0.0], [10.0] * 3, cutoff_angle_deg=15.0)
    cameras = {"main": Camera([0.0, 3.0, 8.0], [0.0, 0.0, 0.0], fov_y_deg=45.0)}
    scene = Scene.build("plane", verts, faces, np.full((2, 3), 0.5), [spot], cameras)
    expected = np.pi * (4.0 * np.tan(np.radians(15.0))) ** 2
    assert lit_area(scene, 0.01) == pytest.approx(expected, rel=0.03)
    both = Scene.build("plane2", verts, faces, np.full((2, 3), 0.5), [spot, PointLight([0, 1, 0], [1.0] * 3)], cameras)
    assert lit_area(both, 0.01) == pytest.approx(400.0)
    with pytest.raises(ValueError, match="piece_area"):
        lit_area(scene, 0.0)


def test_dnear_rule_bounds_d_near_by_the_lit_area():
    """D_near = min(dnear_factor R_scene, sqrt(A_lit / (4 pi))) for the default rule: on big_floor
    about 0.53 m instead of 5.7 m; the scene rule keeps the paper's 0.2 R_scene; a bad rule is named."""
    scene, facts = big_floor()
    p = resolve_params(ForwardLightCuts, {})
    lit = lit_area(scene, 0.01)
    r_lit = near_radius(facts, p["dnear_rule"], p["dnear_factor"], lit)
    assert p["dnear_factor"] * r_lit == pytest.approx(np.sqrt(lit / (4 * np.pi)))
    assert p["dnear_factor"] * r_lit < 0.1 * p["dnear_factor"] * facts.scene_radius
    assert near_radius(facts, "scene", 0.2, lit) == facts.scene_radius
    assert near_radius(facts, "lit", 0.2, facts.total_area_m2) == facts.scene_radius   # lit everywhere: unchanged
    with pytest.raises(ValueError, match="dnear_rule"):
        near_radius(facts, "nearest", 0.2, lit)


def test_big_floor_default_single_frame(gl_ctx):
    """The issue's criterion on big_floor at the defaults, one frame, 4 seeds: image mean within
    20% of jittered `manylights` on average, per-seed spread <= 25% (it was 110%: the lit spot
    held 0 to 3 VPLs), and every frame far better than no indirect light (relMSE 1)."""
    scene, facts = big_floor()
    ref = big_floor_reference(gl_ctx)
    imgs = [run_method(gl_ctx, ForwardLightCuts, scene, "main", W, H, {}, seed=s, frames=1, facts=facts)
            .indirect.astype(np.float64) for s in range(4)]
    ratio = np.array([img.mean() for img in imgs]) / ref.mean()
    assert 0.8 <= ratio.mean() <= 1.2, ratio
    assert ratio.std(ddof=1) / ratio.mean() <= 0.25, ratio
    errors = [float(((img - ref) ** 2).mean() / (ref ** 2).mean()) for img in imgs]
    assert max(errors) < 0.3, errors


def test_quality_ladder():
    """3-5 rungs, fast -> accurate in N_avg, one of them the defaults, each valid."""
    ladder = ForwardLightCuts.ladder
    assert 3 <= len(ladder) <= 5 and {} in ladder
    n_avg = [resolve_params(ForwardLightCuts, rung)["n_avg"] for rung in ladder]
    assert n_avg == sorted(n_avg) and len(set(n_avg)) == len(n_avg)


def test_view_rule_takes_the_median_view_distance(gl_ctx):
    """dnear_rule = view: D_near = dnear_factor min(R_scene, median eye distance of the visible
    surface); on big_floor the view is far smaller than the 80 m floor's R_scene."""
    scene, facts = big_floor()
    r = run_method(gl_ctx, ForwardLightCuts, scene, "main", 64, 48, {"dnear_rule": "view"}, frames=1, facts=facts)
    g = render_gbuffer(gl_ctx, scene, "main", 64, 48)
    seen = np.median(np.linalg.norm(g["position"][g["mask"]] - scene.cameras["main"].eye, axis=1))
    assert seen < 0.5 * facts.scene_radius
    assert r.extra["D_near_m"] == pytest.approx(0.2 * seen, rel=1e-3)
