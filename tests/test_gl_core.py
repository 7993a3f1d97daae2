"""GL core: shader loader, GL error detection, shared passes against analytic values."""
import numpy as np
import pytest

from bench.gl import GLError, check_gl, render_direct, render_gbuffer
from bench.gl.shaders import define_block, glsl_literal, stage_sources
from bench.model.scene import Camera, DirectionalLight, PointLight, Scene, SpotLight


def test_define_injector_honours_zero(tmp_path):
    assert glsl_literal(0) == "0" and glsl_literal(False) == "0" and glsl_literal(0.0) == "0.0"
    block = define_block({"LEVELS": 0, "USE_X": False, "EPS": 1e-6})
    assert "#define LEVELS 0" in block and "#define USE_X 0" in block and "#define EPS 1e-06" in block


def test_include_and_stages(tmp_path):
    (tmp_path / "part.glsl").write_text("float twice(float x) { return 2.0 * x; }\n")
    prog = tmp_path / "prog.glsl"
    prog.write_text('#include "part.glsl"\n#include "part.glsl"\n#if defined VERTEX_SHADER\nvoid main(){}\n#endif\n'
                    '#if defined FRAGMENT_SHADER\nout vec4 c; void main(){ c = vec4(twice(1.0)); }\n#endif\n')
    src = stage_sources(prog, {"K": 3})
    assert set(src) == {"vertex_shader", "fragment_shader"}
    assert src["vertex_shader"].count("float twice") == 1  # included once
    (tmp_path / "bad.glsl").write_text('#include "missing.glsl"\n')
    with pytest.raises(GLError, match='missing.glsl" not found'):
        stage_sources(tmp_path / "bad.glsl")


def test_gl_errors_are_detected(gl_ctx):
    buf = gl_ctx.buffer(reserve=16)
    with pytest.raises(Exception):
        buf.read(size=64)  # reading past the end: moderngl raises or GL flags an error
    gl_ctx.error
    # A raw invalid GL call leaves an error that check_gl turns into an exception.
    import ctypes
    lib = ctypes.CDLL("libGL.so.1") if True else None
    try:
        lib.glEnable(0xFFFF)  # GL_INVALID_ENUM
    except AttributeError:
        pytest.skip("libGL not loadable")
    with pytest.raises(GLError, match="GL_INVALID_ENUM"):
        check_gl(gl_ctx, "glEnable(0xFFFF)")


def _quad_scene(lights):
    v = np.array([[-2, 0, -2], [2, 0, -2], [2, 0, 2], [-2, 0, 2],
                  [-0.3, 0.5, -0.3], [0.3, 0.5, -0.3], [0.3, 0.5, 0.3], [-0.3, 0.5, 0.3]], float)
    f = np.array([[0, 2, 1], [0, 3, 2], [4, 6, 5], [4, 7, 6]])
    return Scene.build("quad", v, f, [0.5, 0.4, 0.3], lights, {"main": Camera([0, 3, 3], [0, 0, 0], fov_y_deg=60)})


def test_gbuffer_positions_match_ray_casting(gl_ctx):
    scene = _quad_scene([PointLight([0, 1, 0], 1.0)])
    g = render_gbuffer(gl_ctx, scene, "main", 64, 48)
    from bench.gl.camera import View
    view = View.create("main", scene.cameras["main"], 64, 48, np.zeros(3), 3.0, np.zeros(3))
    eye, d = view.primary_rays()
    t = -eye[1] / d[..., 1]  # hit the floor plane y=0
    hit = eye + t[..., None] * d
    floor = g["mask"] & (np.abs(g["position"][..., 1]) < 1e-5)
    assert floor.sum() > 1000
    assert np.abs(g["position"][floor] - hit[floor]).max() < 1e-4


def test_direct_point_light_and_shadow_exact(gl_ctx):
    scene = _quad_scene([PointLight([0, 1, 0], [1.0, 2.0, 3.0])])
    g = render_gbuffer(gl_ctx, scene, "main", 64, 64)
    unshadowed = render_direct(gl_ctx, scene, "main", 64, 64, shadows=False)
    shadowed = render_direct(gl_ctx, scene, "main", 64, 64, shadows=True)
    p = g["position"]
    floor = g["mask"] & (np.abs(p[..., 1]) < 1e-5)
    r2 = ((p - np.array([0, 1, 0])) ** 2).sum(-1)
    expected = np.array([0.5, 0.4, 0.3]) * np.array([1, 2, 3]) / np.pi * (1 / np.sqrt(r2) / r2)[..., None]
    assert np.allclose(unshadowed[floor], expected[floor], rtol=1e-5)
    # the occluder's shadow on the floor is the square |x|,|z| < 0.6
    truth = floor & (np.abs(p[..., 0]) < 0.6) & (np.abs(p[..., 2]) < 0.6)
    got = floor & (shadowed[..., 0] == 0)
    assert truth.sum() > 50 and (truth != got).sum() <= 0.01 * floor.sum()


def test_spot_falloff_matches_numpy(gl_ctx):
    spot = SpotLight([0, 1.5, 0], [0, 0, 0], 2.0, cutoff_angle_deg=40, beam_width_deg=20)
    scene = _quad_scene([spot])
    g = render_gbuffer(gl_ctx, scene, "main", 64, 64)
    img = render_direct(gl_ctx, scene, "main", 64, 64, shadows=False)
    p = g["position"]
    floor = g["mask"] & (np.abs(p[..., 1]) < 1e-5)
    d = p - spot.position
    r = np.linalg.norm(d, axis=-1)
    cos_axis = (d / r[..., None]) @ spot.direction
    expected = 0.5 / np.pi * 2.0 * spot.falloff(cos_axis) * (1.5 / r) / r**2
    ramp = floor & (spot.falloff(cos_axis) > 0) & (spot.falloff(cos_axis) < 1)
    assert ramp.sum() > 20  # the test covers the falloff ramp, not only the flat beam
    flat = floor & ~ramp
    assert np.allclose(img[..., 0][flat], expected[flat], rtol=1e-5, atol=1e-9)
    assert np.allclose(img[..., 0][ramp], expected[ramp], rtol=1e-3, atol=1e-6)


def test_directional_light(gl_ctx):
    scene = _quad_scene([DirectionalLight([0, -1, -1], 3.0)])
    scene.cameras["main"] = Camera([0, 4, 0], [0, 0, 0], up=[0, 0, -1], fov_y_deg=60)
    g = render_gbuffer(gl_ctx, scene, "main", 48, 48)
    img = render_direct(gl_ctx, scene, "main", 48, 48, shadows=True)
    p = g["position"]
    floor = g["mask"] & (np.abs(p[..., 1]) < 1e-5)
    # shadow of the occluder along (0,-1,-1): the square shifted by -0.5 in z
    lit = floor & ~((np.abs(p[..., 0]) < 0.3) & (np.abs(p[..., 2] + 0.5) < 0.3))
    expected = 0.5 / np.pi * 3.0 * np.cos(np.pi / 4)
    inner = lit & ~((np.abs(p[..., 0]) < 0.4) & (np.abs(p[..., 2] + 0.5) < 0.4))
    assert np.allclose(img[..., 0][inner], expected, rtol=1e-5)
    shade = floor & (np.abs(p[..., 0]) < 0.2) & (np.abs(p[..., 2] + 0.5) < 0.2)
    assert shade.sum() > 5 and np.all(img[..., 0][shade] == 0)


def test_stage_clock_choice_and_override(gl_ctx, monkeypatch):
    from bench.gl.profiler import StageProfiler, default_clock
    monkeypatch.delenv("GIBENCH_STAGE_CLOCK", raising=False)
    software = "llvmpipe" in gl_ctx.info["GL_RENDERER"].lower()
    assert default_clock(gl_ctx) == ("finish_wall" if software else "gl_query")
    monkeypatch.setenv("GIBENCH_STAGE_CLOCK", "gl_query")
    assert StageProfiler(gl_ctx).clock == "gl_query"
    monkeypatch.setenv("GIBENCH_STAGE_CLOCK", "stopwatch")
    with pytest.raises(ValueError, match="GIBENCH_STAGE_CLOCK"):
        default_clock(gl_ctx)


@pytest.mark.parametrize("clock", ["gl_query", "finish_wall"])
def test_both_stage_clocks_time_a_pass(gl_ctx, open_box, clock):
    from bench.gl import GpuScene, SharedPasses
    from bench.gl.profiler import StageProfiler
    gpu = GpuScene(gl_ctx, open_box)
    view = gpu.view("main", 64, 48)
    passes = SharedPasses(gpu, view, {"gbuffer", "shadow_map", "direct"}, shadow_resolution=256)
    prof = StageProfiler(gl_ctx, passes.stages, clock=clock)
    try:
        prof.begin_frame()
        passes.render(prof)
        times = prof.collect()
        assert set(times) == set(passes.stages)
        assert all(ms > 0 for ms in times.values())
        with pytest.raises(RuntimeError, match="cannot nest"):
            with prof.stage(passes.stages[0]):
                with prof.stage(passes.stages[0]):
                    pass
    finally:
        passes.release()
        gpu.release()


@pytest.mark.parametrize("clock", ["gl_query", "finish_wall"])
def test_harness_frame_and_stage_samples_per_clock(gl_ctx, open_box, monkeypatch, clock):
    """finish_wall fences every stage, so wall times and stage times come from separate frames;
    either way K timed frames give K wall samples and K samples per stage."""
    from bench.run.harness import run_method
    from methods.direct.method import DirectMethod
    monkeypatch.setenv("GIBENCH_STAGE_CLOCK", clock)
    calls = []
    original = DirectMethod.render

    def counting_render(self, frame, prof):
        calls.append((frame.index, prof.enabled))
        return original(self, frame, prof)

    monkeypatch.setattr(DirectMethod, "render", counting_render)
    result = run_method(gl_ctx, DirectMethod, open_box, "main", 32, 24, warmup=1, frames=3,
                        shadow_resolution=128)
    assert result.stage_clock == clock
    assert len(result.frame_ms) == 3
    assert result.stage_ms and all(len(v) == 3 for v in result.stage_ms.values())
    if clock == "finish_wall":
        assert [enabled for _, enabled in calls] == [True, False, False, False, True, True, True]
    else:
        assert len(calls) == 4 and all(enabled for _, enabled in calls)


def _far_panel_scene(gap):
    """A 3 x 3 m panel `gap` metres in front of a 16 x 16 m wall, 35 m down the axis of a spot
    light and of the camera; the wall comes first in the triangle order, so when the depth test
    cannot tell the two apart the wall (drawn first) wins."""
    z_wall, z_panel, a, b = -35.0 - gap, -35.0, 8.0, 1.5
    v = np.array([[-a, -a, z_wall], [a, -a, z_wall], [a, a, z_wall], [-a, a, z_wall],
                  [-b, -b, z_panel], [b, -b, z_panel], [b, b, z_panel], [-b, b, z_panel]], float)
    f = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    spot = SpotLight([0, 0, 0], [0, 0, -35], 1000.0, cutoff_angle_deg=10, beam_width_deg=8)
    return Scene.build("far_panel", v, f, [0.5, 0.5, 0.5], [spot],
                       {"main": Camera([0.3, 0.2, 0], [0, 0, -35], fov_y_deg=8)})


def test_depth_test_orders_close_surfaces_at_the_far_end(gl_ctx):
    """2 cm between panel and wall 35 m away is far below a 24-bit 1/z depth buffer's step there
    (~20 cm for the shadow map's near = 1e-5 far) but well above the shadow tolerance (~1.3 cm):
    the GBuffer and the shadow map must both keep the panel, the nearer surface."""
    from bench.gl import GpuScene, SharedPasses, StageProfiler
    from bench.gl.passes import read_rgba
    gap = 0.02
    scene = _far_panel_scene(gap)
    g = render_gbuffer(gl_ctx, scene, "main", 64, 64)
    gpu = GpuScene(gl_ctx, scene)
    try:
        view = gpu.view("main", 64, 64)
        eye, d = view.primary_rays()
        t = (-35.0 - eye[2]) / d[..., 2]
        hit = eye + t[..., None] * d
        on_panel = (np.abs(hit[..., 0]) < 1.45) & (np.abs(hit[..., 1]) < 1.45)
        assert on_panel.sum() > 500
        assert np.all(g["triangle"][on_panel] >= 2), "the wall behind the panel won the GBuffer depth test"
        assert np.all(np.abs(g["position"][on_panel][:, 2] + 35.0) < 1e-3)

        passes = SharedPasses(gpu, view, {"direct", "shadow_map"}, shadow_resolution=512)
        passes.render(StageProfiler(gl_ctx))
        layer = passes.shadows.layers[0]
        stored = read_rgba(passes.shadows.atlas)[::-1, :, 0]  # GL rows: row 0 at the bottom
        res = passes.shadows.resolution
        c = (np.arange(res) + 0.5) / res * 2 - 1
        ndc = np.stack(np.meshgrid(c, c), -1)
        far_pt = np.einsum("ij,hwj->hwi", np.linalg.inv(layer.view_proj),
                           np.concatenate([ndc, np.ones(ndc.shape[:2] + (2,))], -1))
        ray = far_pt[..., :3] / far_pt[..., 3:]
        light = scene.lights[0].position - gpu.origin
        ray = (ray - light) / np.linalg.norm(ray - light, axis=-1, keepdims=True)
        t = (-35.0 - gpu.origin[2] - light[2]) / ray[..., 2]
        hit = light + t[..., None] * ray + gpu.origin
        texel_on_panel = (np.abs(hit[..., 0]) < 1.45) & (np.abs(hit[..., 1]) < 1.45)
        assert texel_on_panel.sum() > 1000
        err = np.abs(stored[texel_on_panel] - t[texel_on_panel])
        assert err.max() < 0.25 * gap, f"shadow map keeps the wall on {np.mean(err > 0.5 * gap):.0%} of the panel"
        # end to end: the panel and the lit wall around it are lit everywhere (no acne at 35 m)
        direct = passes.direct.read()
        unshadowed = render_direct(gl_ctx, scene, "main", 64, 64, shadows=False)
        covered = g["mask"]
        assert np.allclose(direct[covered], unshadowed[covered], rtol=1e-4, atol=0)
        passes.release()
    finally:
        gpu.release()
