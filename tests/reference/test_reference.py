"""Mitsuba 3 reference: conversion, integrators, convergence, cache, runner wiring, calibration
against the GL rasteriser (small images; the whole file runs in about a minute on 2 cores)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mitsuba")
pytestmark = pytest.mark.mitsuba

from bench.model.scene import Camera, DirectionalLight, PointLight, Scene, SceneError, SpotLight  # noqa: E402
from reference.api import build_references, get_reference  # noqa: E402
from tests.conftest import grid_quad, make_open_box, scene_from_parts  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    """One reference cache for the session (tests that need a private one make their own)."""
    root = tmp_path_factory.getbasetemp() / "reference-cache"
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(root))
    return root


def relative_mse(image, reference, mask) -> float:
    """sum of squared errors / sum of squared reference values over the masked pixels."""
    return float(((image - reference) ** 2)[mask].sum() / max(float((reference ** 2)[mask].sum()), 1e-300))


def mitsuba_aovs(scene, view, width, height):
    """Mitsuba's `aov` position and shading-normal images, one unjittered sample per pixel."""
    from reference.convert import load_view, scene_origin, scene_scale
    from reference.env import load_mitsuba
    mi = load_mitsuba()
    mscene = load_view(mi, scene, view, width, height, integrator={"type": "aov", "aovs": "p:position,n:sh_normal"},
                       sampler={"type": "stratified", "sample_count": 1, "jitter": False})
    img = np.asarray(mi.render(mscene, spp=1), dtype=np.float64)
    assert img.shape == (height, width, 6)
    hit = np.any(img[..., 3:] != 0, axis=2)
    return img[..., :3] / scene_scale(scene) + scene_origin(scene), img[..., 3:], hit


def mitsuba_positions(scene, view, width, height):
    """Mitsuba's `aov` position image (world coordinates) and its hit mask."""
    pos, _, hit = mitsuba_aovs(scene, view, width, height)
    return pos, hit


def three_light_box() -> Scene:
    """The open box lit by a point, a spot and a directional light at once (every emitter kind)."""
    base = make_open_box()
    lights = [PointLight([0.3, 1.3, 0.2], [1.5, 1.0, 0.5]),
              SpotLight([-0.4, 1.8, 0.8], [0.2, 0.0, -0.3], [4.0, 6.0, 3.0], cutoff_angle_deg=35, beam_width_deg=20),
              DirectionalLight([0.4, -1.0, -0.6], [0.3, 0.5, 0.9])]
    return Scene.build("three_lights", base.vertices, base.faces, base.albedo, lights,
                       {"main": base.cameras["main"],
                        "side": Camera([2.2, 1.6, 1.8], [-0.3, 0.5, -0.4], up=[0, 1, 0], fov_y_deg=40)})


def closed_box_scene() -> Scene:
    """A closed, flat-shaded room (walls 4x4 grids) with a floating closed block and a point light:
    light-tight, with indirect occlusion (so the two one-bounce references differ)."""
    n, m = 4, 2
    parts = [grid_quad([-1, -1, -1], [0, 0, 2], [2, 0, 0], n), grid_quad([-1, -1, -1], [0, 2, 0], [0, 0, 2], n),
             grid_quad([1, -1, -1], [0, 0, 2], [0, 2, 0], n), grid_quad([-1, 1, -1], [2, 0, 0], [0, 0, 2], n),
             grid_quad([-1, -1, -1], [2, 0, 0], [0, 2, 0], n), grid_quad([-1, -1, 1], [0, 2, 0], [2, 0, 0], n)]
    colours = [(0.8, 0.8, 0.8), (0.8, 0.2, 0.2), (0.2, 0.8, 0.2), (0.8, 0.8, 0.8), (0.8, 0.8, 0.8), (0.6, 0.6, 0.9)]
    o = np.array([-0.5, -0.95, -0.5])
    x, y, z = np.array([0.5, 0, 0]), np.array([0, 0.8, 0]), np.array([0, 0, 0.6])
    parts += [grid_quad(o, x, z, m), grid_quad(o + y, z, x, m), grid_quad(o, y, z, m), grid_quad(o + x, z, y, m),
              grid_quad(o, x, y, m), grid_quad(o + z, y, x, m)]
    colours += [(0.7, 0.7, 0.3)] * 6
    return scene_from_parts("closed_box", parts, colours, [PointLight([0.3, 0.25, 0.35], [3.0, 3.0, 3.0])],
                            {"main": Camera([0.6, 0.3, 0.95], [-0.3, -0.6, -0.5], fov_y_deg=75)})


# ---------------------------------------------------------------------------- conversion
@pytest.mark.parametrize("scene_name,view,size", [("cornell_spot", "main", (64, 48)),
                                                  ("three_lights", "side", (40, 56))])
def test_position_aov_equals_gbuffer(gl_ctx, scene_name, view, size):
    """Same view, same pixel centres: no mirroring, no half-pixel shift, vertical fov."""
    from bench.model.corpus import load_scene
    from bench.gl import render_gbuffer
    scene = three_light_box() if scene_name == "three_lights" else load_scene(scene_name)
    w, h = size
    g = render_gbuffer(gl_ctx, scene, view, w, h)
    pos, hit = mitsuba_positions(scene, view, w, h)
    assert np.array_equal(hit, g["mask"])
    assert g["mask"].mean() > 0.3
    err = np.linalg.norm(pos - g["position"], axis=2)[hit]
    extent = np.linalg.norm(scene.vertices.max(0) - scene.vertices.min(0))
    # the GL positions are float32 interpolations; a one-pixel shift would move points by ~1e-2 extent
    assert err.max() <= 1e-5 * extent, f"max position difference {err.max():.3g}"
    # a mirrored or shifted image would fail this, but check the obvious orientation too
    assert not np.allclose(pos[hit], np.flip(g["position"], axis=1)[hit], atol=1e-3)


@pytest.mark.parametrize("component", ["direct", "indirect_unshadowed"])
def test_registered_integrators_render_with_second_moment(component):
    """`gibench_<component>` plugins work through mi.render: radiance plus its second moment."""
    from reference.convert import load_view
    from reference.env import load_mitsuba
    mi = load_mitsuba()
    box = make_open_box()
    # direct: one unjittered sample at each pixel centre (comparable with the reference);
    # the bounce needs random directions (an unjittered sampler always returns 0.5)
    sampler = {"type": "stratified", "sample_count": 1, "jitter": False} if component == "direct" else None
    mscene = load_view(mi, box, "main", 24, 16, integrator={"type": f"gibench_{component}"}, sampler=sampler)
    img = np.asarray(mi.render(mscene, spp=1), dtype=np.float64)
    assert img.shape == (16, 24, 6)
    mean, m2 = img[..., :3], img[..., 3:]
    assert mean.max() > 0
    np.testing.assert_allclose(m2, mean ** 2, rtol=1e-5, atol=1e-12)  # one sample: E[L^2] = L^2
    if component == "direct":
        ref = get_reference(box, "main", 24, 16, "direct", spp_cap=2)
        np.testing.assert_allclose(mean, ref.mean, rtol=1e-5, atol=1e-7)


# ---------------------------------------------------------------------------- direct calibration
def _same_surface(scene, view, w, h, g) -> np.ndarray:
    """Pixels where Mitsuba and the rasteriser see the same point of the same surface (a pixel
    centre exactly on an edge between two walls is a tie either may win)."""
    pos, normal, hit = mitsuba_aovs(scene, view, w, h)
    extent = np.linalg.norm(scene.vertices.max(0) - scene.vertices.min(0))
    same_point = np.linalg.norm(pos - g["position"], axis=2) <= 1e-4 * extent
    same_plane = np.abs((normal * g["normal"]).sum(axis=2)) >= 0.999
    return hit & g["mask"] & same_point & same_plane


def _diagnose(folder: Path, **images) -> str:
    """Write the compared images as EXRs (called when a comparison fails) and say where."""
    from bench.model.imageio import write_exr
    for name, img in images.items():
        img = np.asarray(img, dtype=np.float32)
        write_exr(folder / f"{name}.exr", img if img.ndim == 3 else img[..., None])
    return f"diagnostic EXRs ({', '.join(images)}) in {folder}"


@pytest.mark.parametrize("scene_name", ["cornell_spot", "cornell_box", "three_lights"])
def test_direct_unshadowed_matches_gl(gl_ctx, scene_name, tmp_path):
    from bench.model.corpus import load_scene
    from bench.gl import render_direct, render_gbuffer
    scene = three_light_box() if scene_name == "three_lights" else load_scene(scene_name)
    w, h = 64, 48
    ref = get_reference(scene, "main", w, h, "direct_unshadowed", spp_cap=2)
    gl = render_direct(gl_ctx, scene, "main", w, h, shadows=False)
    g = render_gbuffer(gl_ctx, scene, "main", w, h)
    same = _same_surface(scene, "main", w, h, g)
    # edge ties (the pixel centre exactly on a crack between two triangles) are rare
    assert same.sum() >= 0.99 * g["mask"].sum()
    assert ref.mean[same].max() > 0
    assert ref.noise_floor_mse == 0.0  # delta lights at pixel centres: exact
    err = relative_mse(gl, ref.mean, same)
    assert err <= 1e-3, f"relative MSE {err:.3g}; " + _diagnose(tmp_path, gl=gl, mitsuba=ref.mean, same=same)


@pytest.mark.parametrize("scene_name,bound", [("cornell_spot", 1e-3), ("cornell_box", 2e-2), ("teapot", 1e-2)])
def test_direct_shadowed_matches_gl(gl_ctx, scene_name, bound, tmp_path):
    """Shadow maps vs shadow rays: the bound is looser where shadow edges cross the image."""
    from bench.model.corpus import load_scene
    from bench.gl import render_direct, render_gbuffer
    scene = load_scene(scene_name)
    w, h = 64, 48
    ref = get_reference(scene, "main", w, h, "direct", spp_cap=2)
    gl = render_direct(gl_ctx, scene, "main", w, h, shadows=True, shadow_resolution=2048)
    g = render_gbuffer(gl_ctx, scene, "main", w, h)
    same = _same_surface(scene, "main", w, h, g)
    err = relative_mse(gl, ref.mean, same)
    # most pixels agree to 1%: the difference is confined to shadow edges
    close = np.abs(gl - ref.mean).max(axis=2) <= 0.01 * ref.mean.max() + 1e-7
    ok = err <= bound and close[same].mean() >= 0.98
    assert ok, (f"relative MSE {err:.3g}, {close[same].mean():.3f} of pixels within 1%; "
                + _diagnose(tmp_path, gl=gl, mitsuba=ref.mean, same=same))


# ---------------------------------------------------------------------------- one bounce, analytic
@pytest.mark.parametrize("component", ["indirect_visible", "indirect_unshadowed"])
def test_sphere_inside_analytic(component):
    from bench.model.corpus import load_scene
    from bench.model.corpus.procedural import sphere_inside_indirect
    # light off centre (0.3 R): the direct light varies 3.5x over the sphere, the bounce does not
    scene = load_scene("sphere_inside")
    assert np.linalg.norm(scene.lights[0].position) >= 0.3
    expected = sphere_inside_indirect()
    ref = get_reference(scene, "main", 32, 24, component, spp_cap=512)
    m = ref.coverage
    assert m.all()
    values = ref.mean[m].mean(axis=1)
    # tessellation (5,120 triangles) changes the result by ~0.3%; the MC noise per pixel is ~0.6%
    assert abs(values.mean() / expected - 1) <= 0.01
    assert np.abs(values / expected - 1).max() <= 0.05
    # the stored noise floor is the per-pixel variance of the mean: consistent with the spread seen
    spread = float(((ref.mean[m] - expected) ** 2).mean())
    assert 0.5 * ref.noise_floor_mse <= spread <= 2.0 * ref.noise_floor_mse + (0.005 * expected) ** 2


@pytest.mark.parametrize("component", ["indirect_visible", "indirect_unshadowed"])
def test_light_sampling_mis_is_unbiased_and_less_noisy(component):
    """BSDF sampling alone and BSDF + light sampling (MIS) estimate the same integral; on the
    spot-lit Cornell box (a small bright patch on the ceiling) MIS is several times less noisy."""
    from bench.model.corpus import load_scene
    scene = load_scene("cornell_spot")
    bsdf_only = get_reference(scene, "main", 32, 24, component, spp_cap=512, light_sampling=False)
    mis = get_reference(scene, "main", 32, 24, component, spp_cap=512, light_sampling=True)
    assert mis.key != bsdf_only.key and mis.spp == bsdf_only.spp
    assert mis.noise_floor_mse * 3 <= bsdf_only.noise_floor_mse
    m = mis.coverage
    diff = float(((mis.mean - bsdf_only.mean) ** 2)[m].mean())
    assert diff <= 2.0 * (mis.noise_floor_mse + bsdf_only.noise_floor_mse)
    se = np.sqrt(mis.variance[m].sum() + bsdf_only.variance[m].sum()) / m.sum() / 3
    assert abs(mis.mean[m].mean() - bsdf_only.mean[m].mean()) <= 4 * se


def test_visible_and_unshadowed_differ_only_by_occlusion():
    """Without occluders between surfaces the two one-bounce estimates are the same samples;
    with an occluding block the unshadowed one is brighter (it ignores the block's shadowing)."""
    box = make_open_box()
    a = get_reference(box, "main", 32, 24, "indirect_visible", spp_cap=16)
    b = get_reference(box, "main", 32, 24, "indirect_unshadowed", spp_cap=16)
    assert a.mean.max() > 0 and np.array_equal(a.mean, b.mean)
    closed = closed_box_scene()
    v = get_reference(closed, "main", 32, 24, "indirect_visible", spp_cap=64)
    u = get_reference(closed, "main", 32, 24, "indirect_unshadowed", spp_cap=64)
    assert u.mean[u.coverage].mean() > 1.02 * v.mean[v.coverage].mean()


def test_indirect_visible_equals_mitsuba_path_tracer_bounce(tmp_path):
    """Independent check with Mitsuba's own `path` integrator: depth 3 minus depth 2 is the one
    bounce with visibility (box-filtered film, so compared with pixel_sampling="box")."""
    from reference.convert import load_view
    from reference.env import load_mitsuba
    mi = load_mitsuba()
    scene = closed_box_scene()
    w, h = 32, 24
    bounces = []
    for seed in (0, 1):
        depth = {d: np.asarray(mi.render(load_view(mi, scene, "main", w, h, integrator={"type": "path", "max_depth": d}),
                                         spp=512, seed=seed), dtype=np.float64) for d in (2, 3)}
        bounces.append(depth[3] - depth[2])
    path = np.mean(bounces, axis=0)
    path_noise = float(((bounces[0] - bounces[1]) ** 2).mean()) / 4
    ref = get_reference(scene, "main", w, h, "indirect_visible", spp_cap=1024, pixel_sampling="box", cache_dir=tmp_path)
    expected_mse = path_noise + float(ref.variance.mean())
    assert float(((path - ref.mean) ** 2).mean()) <= 2.0 * expected_mse
    assert abs(path.mean() / ref.mean.mean() - 1) <= 0.01


# ---------------------------------------------------------------------------- manylights
def test_manylights_lambert_matches_unshadowed_reference(gl_ctx):
    from bench.run.harness import run_method
    from methods.manylights.method import ManyLights
    scene = closed_box_scene()
    from bench.model.scene import compute_facts
    assert compute_facts(scene).closed
    w, h = 32, 24
    ref = get_reference(scene, "main", w, h, "indirect_unshadowed", spp_cap=2048)
    visible = get_reference(scene, "main", w, h, "indirect_visible", spp_cap=512)
    runs = [run_method(gl_ctx, ManyLights, scene, "main", w, h, {"emission": "lambert", "jitter_frames": 64},
                       seed=s, frames=1).indirect.astype(np.float64) for s in range(4)]
    ml = np.mean(runs, axis=0)
    m = ref.coverage
    # variance of the 4-run mean, from the difference of two 2-run halves
    ml_noise = float(((np.mean(runs[:2], 0) - np.mean(runs[2:], 0)) ** 2)[m].mean()) / 4
    expected_mse = ref.noise_floor_mse + ml_noise  # two independent unbiased estimates
    mse = float(((ml - ref.mean) ** 2)[m].mean())
    assert mse <= 2.0 * expected_mse, f"MSE {mse:.3g} vs noise {expected_mse:.3g}"
    assert abs(ml[m].mean() / ref.mean[m].mean() - 1) <= 0.01
    # and the test can tell: the visibility-correct bounce is far outside that noise
    assert float(((ml - visible.mean) ** 2)[m].mean()) >= 4.0 * expected_mse


# ---------------------------------------------------------------------------- convergence + cache
def test_convergence_curve_and_target(tmp_path):
    box = make_open_box()
    ref = get_reference(box, "main", 24, 16, "indirect_visible", spp_cap=64, cache_dir=tmp_path)
    spps = [p["spp"] for p in ref.curve]
    assert spps == [4, 8, 16, 32, 64] and ref.spp == 64
    assert all(p["seconds"] > 0 for p in ref.curve)
    assert ref.curve[-1]["mse_estimate"] < ref.curve[0]["mse_estimate"]
    assert ref.noise_floor_mse == pytest.approx(float(ref.variance[ref.coverage].mean()))
    # MC rate: 16x the samples -> about 1/16 of the variance
    assert 0.03 < ref.curve[-1]["mse_estimate"] / ref.curve[0]["mse_estimate"] < 0.15
    # a target stops early, a lower target continues from the cache (the key ignores spp/target)
    t = tmp_path / "t"
    loose = get_reference(box, "main", 24, 16, "indirect_visible", spp_cap=1024,
                          target_mse=ref.curve[1]["mse_estimate"] * 1.5, cache_dir=t)
    assert loose.spp == 8 and loose.noise_floor_mse <= ref.curve[1]["mse_estimate"] * 1.5
    tight = get_reference(box, "main", 24, 16, "indirect_visible", spp_cap=1024,
                          target_mse=loose.noise_floor_mse / 3, cache_dir=t)
    assert tight.key == loose.key and tight.spp == 32 and tight.rendered_spp == 24
    assert tight.noise_floor_mse <= loose.noise_floor_mse / 3


def test_cache_hit_renders_nothing_and_albedo_change_renders(tmp_path):
    box = make_open_box()
    first = get_reference(box, "main", 24, 16, "indirect_unshadowed", spp_cap=8, cache_dir=tmp_path)
    assert first.rendered_spp == 8
    again = get_reference(make_open_box(), "main", 24, 16, "indirect_unshadowed", spp_cap=8, cache_dir=tmp_path)
    assert again.rendered_spp == 0 and again.key == first.key
    np.testing.assert_allclose(again.mean, first.mean, rtol=1e-6)
    entry = next(tmp_path.glob(f"*/{first.key}"))
    assert {p.name for p in entry.iterdir()} == {"mean.exr", "m2.exr", "hits.exr", "meta.json"}
    assert json.loads((entry / "meta.json").read_text())["payload"]["variant"] in ("llvm_ad_rgb", "scalar_rgb")
    changed = box.with_albedo(np.clip(box.albedo * 0.5, 0, 1))
    other = get_reference(changed, "main", 24, 16, "indirect_unshadowed", spp_cap=8, cache_dir=tmp_path)
    assert other.key != first.key and other.rendered_spp == 8
    # one bounce: half the albedo at x and at y -> a quarter of the radiance (same samples)
    np.testing.assert_allclose(other.mean, first.mean * 0.25, rtol=1e-4, atol=1e-7)


def test_same_seed_same_image_other_seed_other_image(tmp_path):
    box = make_open_box()
    a = get_reference(box, "main", 24, 16, "indirect_visible", spp_cap=8, cache_dir=tmp_path / "a")
    b = get_reference(box, "main", 24, 16, "indirect_visible", spp_cap=8, cache_dir=tmp_path / "b")
    c = get_reference(box, "main", 24, 16, "indirect_visible", spp_cap=8, seed=1, cache_dir=tmp_path / "c")
    assert np.array_equal(a.mean, b.mean) and a.key == b.key
    assert c.key != a.key and not np.array_equal(a.mean, c.mean)


def test_box_pixel_sampling_antialiases_edges(tmp_path):
    box = make_open_box()
    centre = get_reference(box, "main", 24, 16, "direct", spp_cap=64, cache_dir=tmp_path)
    aa = get_reference(box, "main", 24, 16, "direct", spp_cap=64, pixel_sampling="box", cache_dir=tmp_path)
    assert centre.spp == 4 and centre.noise_floor_mse == 0.0  # exact at pixel centres: stops at once
    assert aa.key != centre.key and aa.spp == 64 and aa.noise_floor_mse > 0
    # box-filtered and centre-sampled agree on average, differ on edge pixels
    assert abs(aa.mean.mean() / centre.mean.mean() - 1) < 0.05
    assert np.abs(aa.mean - centre.mean).max() > 0.05 * centre.mean.max()


# ---------------------------------------------------------------------------- bad input
def test_bad_input_messages():
    box = make_open_box()
    with pytest.raises(ValueError, match="unknown component 'indirect'"):
        get_reference(box, "main", 24, 16, "indirect")
    with pytest.raises(SceneError, match="no camera 'top'"):
        get_reference(box, "top", 24, 16, "direct")
    with pytest.raises(ValueError, match="spp_cap=1"):
        get_reference(box, "main", 24, 16, "direct", spp_cap=1)
    with pytest.raises(ValueError, match="target_mse"):
        get_reference(box, "main", 24, 16, "direct", target_mse=-1.0)
    with pytest.raises(ValueError, match="pixel_sampling 'gauss'"):
        get_reference(box, "main", 24, 16, "direct", pixel_sampling="gauss")


def _run(code: str, **env) -> subprocess.CompletedProcess:
    full_env = dict(os.environ, **env)
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=full_env, capture_output=True, text=True,
                          timeout=120)


def test_missing_mitsuba_says_what_to_install():
    code = ("import sys; sys.modules['mitsuba'] = None\n"
            "from reference.api import get_reference, ReferenceUnavailable\n"
            "from tests.conftest import make_open_box\n"
            "try:\n    get_reference(make_open_box(), 'main', 16, 16, 'direct')\n"
            "except ReferenceUnavailable as e:\n    print('UNAVAILABLE', e)\n")
    out = _run(code)
    assert out.returncode == 0, out.stderr
    assert "UNAVAILABLE" in out.stdout and "pip install mitsuba" in out.stdout and "libllvm19" in out.stdout


def test_unusable_variant_says_what_to_install():
    out = _run("from reference.env import load_mitsuba\nload_mitsuba()\n", GIBENCH_MITSUBA_VARIANT="cuda_nonexistent")
    assert out.returncode != 0
    assert "ReferenceUnavailable" in out.stderr and "pip install mitsuba" in out.stderr


def test_llvm_unavailable_falls_back_to_scalar_with_a_warning():
    out = _run("import warnings; warnings.simplefilter('always')\n"
               "from reference.env import load_mitsuba\nprint(load_mitsuba().variant())\n",
               DRJIT_LIBLLVM_PATH="/nonexistent/libLLVM-19.so")
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "scalar_rgb"
    assert "falling back to scalar_rgb" in out.stderr and "DRJIT_LIBLLVM_PATH" in out.stderr


def test_scalar_fallback_matches_llvm(tmp_path):
    """The scalar_rgb fallback runs the same estimators: direct exactly equal, the bounce equal
    in expectation (different random streams)."""
    code = ("import numpy as np, sys\n"
            "from reference.api import get_reference\nfrom tests.conftest import make_open_box\n"
            "d = get_reference(make_open_box(), 'main', 12, 8, 'direct', spp_cap=2)\n"
            "u = get_reference(make_open_box(), 'main', 12, 8, 'indirect_unshadowed', spp_cap=64)\n"
            "np.save(sys.argv[1], np.stack([d.mean, u.mean, u.variance])); print(d.variant)\n")
    path = tmp_path / "scalar.npy"
    out = subprocess.run([sys.executable, "-c", code, str(path)], cwd=ROOT, capture_output=True, text=True,
                         env=dict(os.environ, GIBENCH_MITSUBA_VARIANT="scalar_rgb",
                                  GIBENCH_CACHE_DIR=str(tmp_path / "cache")), timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "scalar_rgb"
    direct, bounce, bounce_var = np.load(path)
    llvm = get_reference(make_open_box(), "main", 12, 8, "direct", spp_cap=2)
    assert llvm.variant == "llvm_ad_rgb"
    np.testing.assert_allclose(direct, llvm.mean, rtol=1e-4, atol=1e-7)
    llvm_bounce = get_reference(make_open_box(), "main", 12, 8, "indirect_unshadowed", spp_cap=64)
    # image means of two independent estimates: within 4 standard errors
    se = np.sqrt((bounce_var.sum() + llvm_bounce.variance.sum())) / bounce.size
    assert abs(bounce.mean() - llvm_bounce.mean.mean()) <= 4 * se
    assert not np.array_equal(bounce, llvm_bounce.mean)


# ---------------------------------------------------------------------------- bulk build
def test_build_references_parallel_then_cached(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path))
    scenes = [make_open_box(), three_light_box()]
    lines = build_references(scenes, 16, 12, processes=2, spp_cap=4, components=("direct", "indirect_visible"))
    assert len(lines) == 6 and all(": built, 4 spp" in l for l in lines), lines
    assert "reference open_box/main/direct: built" in capsys.readouterr().out
    again = build_references(scenes, 16, 12, processes=1, spp_cap=4, components=("direct", "indirect_visible"))
    assert all(": cached, 4 spp" in l for l in again), again


# ---------------------------------------------------------------------------- runner wiring
def _run_cfg(tmp_path, **kw):
    from bench.run.serial import RunConfig
    from tests.conftest import make_grid_box
    base = dict(scenes=[make_grid_box(4)], methods=["direct", "manylights"], width=32, height=24, frames=1,
                warmup=1, out=tmp_path / "run", references=True, reference_spp_cap=256, progress=False)
    base.update(kw)
    return RunConfig(**base)


def test_runner_rows_carry_reference_and_refine(gl_ctx, tmp_path, monkeypatch):
    """First pass at 8 spp, then each view's references are refined to 1/10 of the best
    method's MSE (bounded by the cap) and the rows re-evaluated against them."""
    from bench.model.imageio import read_exr
    from bench.run.references import ReferenceProvider
    from bench.run.serial import run
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(ReferenceProvider, "REFERENCE_FIRST_PASS_SPP", 8)
    logs = []
    df, runner = run(_run_cfg(tmp_path), log=logs.append)
    assert list(df.status) == ["ok", "ok"]
    ref_dir = runner.run_dir / "references" / "grid_box" / "main"
    unshadowed = read_exr(ref_dir / "indirect_unshadowed.exr")
    variance = read_exr(ref_dir / "indirect_unshadowed_variance.exr")
    covered = np.any(read_exr(ref_dir / "direct.exr") > 0, axis=2)
    for rec in df.to_dict("records"):
        assert rec["reference_spp.direct"] == 4 and rec["reference_noise_floor.direct"] == 0.0
        spp = rec["reference_spp.indirect_unshadowed"]
        floor = rec["reference_noise_floor.indirect_unshadowed"]
        assert spp > 8  # refined beyond the first pass
        assert floor == pytest.approx(float(variance[covered].mean()), rel=1e-4)
        # the error columns were recomputed against the refined reference
        indirect = read_exr(runner.run_dir / rec["image_dir"] / "indirect.exr")
        assert rec["mse.indirect"] == pytest.approx(float(((indirect - unshadowed) ** 2)[covered].mean()), rel=1e-3)
        assert len(rec["reference_key.indirect_visible"]) == 32
    floor = df["reference_noise_floor.indirect_unshadowed"].iloc[0]
    best = df["mse.indirect"].min() - floor  # the MSE against a noisy reference includes its noise
    assert floor <= 0.1 * best * 1.0001 or df["reference_spp.indirect_unshadowed"].iloc[0] == 256
    curves = json.loads((runner.run_dir / "reference_curves.json").read_text())
    curve = curves["grid_box/main/indirect_unshadowed"]
    assert [p["spp"] for p in curve][:2] == [4, 8] and curve[-1]["spp"] == df["reference_spp.indirect_unshadowed"].iloc[0]


def test_runner_without_mitsuba_goes_on_with_empty_error_columns(gl_ctx, tmp_path, monkeypatch):
    from bench.run.serial import run
    from reference import env
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(env, "_state", {"error": f"Mitsuba 3 is not installed (test): {env.INSTALL_HINT}"})
    logs = []
    df, _ = run(_run_cfg(tmp_path, methods=["direct"]), log=logs.append)
    assert list(df.status) == ["ok"]
    assert not any(c.startswith(("mse.", "reference_key.")) and df[c].notna().any() for c in df.columns)
    said = [m for m in logs if "pip install mitsuba" in m]
    assert len(said) == 1 and "error columns left empty" in said[0]


def test_runner_skipped_row_is_not_judged(gl_ctx, tmp_path, monkeypatch):
    from bench.run.references import ReferenceProvider
    from bench.run.serial import run
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(ReferenceProvider, "REFERENCE_FIRST_PASS_SPP", 4)
    df, _ = run(_run_cfg(tmp_path, params={"manylights": [{"max_triangles": 1}]}, reference_spp_cap=4),
                log=lambda m: None)
    status = df.set_index("method")["status"]
    assert status["direct"] == "ok" and status["manylights"].startswith("skipped")
    assert np.isfinite(df.set_index("method").loc["direct", "mse.indirect"])
    assert np.isnan(df.set_index("method").loc["manylights", "mse.indirect"])


def test_reference_is_scale_invariant():
    """A scene scaled by 1e-4 (intensities by s^2) gives the same radiance: Mitsuba works in a
    unit-radius frame. In world units its absolute ray-offset floor changed rooms' direct light
    by -27% and its bounce by -17% at this scale (the stress suite's scale=1e-04 row)."""
    from bench.model.corpus import load_scene
    from bench.stress.perturb import scale
    from reference.api import get_reference
    base = load_scene("rooms")
    small = scale(base, 1e-4)
    for component in ("direct", "indirect_visible"):
        a = get_reference(base, "main", 32, 24, component, spp_cap=8).mean
        b = get_reference(small, "main", 32, 24, component, spp_cap=8).mean
        assert abs(b.mean() / a.mean() - 1.0) < 0.02, component
