"""Tests of `pbgi` (texture-space point-based GI): unwrap invariants, the gather against a numpy
brute force of the same transfer, convergence to `manylights` and to the analytic sphere."""
from __future__ import annotations

import numpy as np
import pytest

from bench.gl import Frame, GpuScene, SharedPasses, StageProfiler, check_gl
from bench.harness import run_method
from bench.method import ParamError, SkipRow, resolve_params
from bench.scene import Camera, PointLight, Scene, compute_facts
from methods.pbgi.method import TextureSpacePBGI
from methods.pbgi.unwrap import unwrap
from tests.conftest import make_grid_box, make_open_box


class _Live:
    """prepare + one rendered frame, kept alive for inspection (run_method releases everything)."""

    def __init__(self, ctx, scene, params, width=48, height=36):
        self.scene, self.ctx = scene, ctx
        self.facts = compute_facts(scene)
        self.gpu = GpuScene(ctx, scene, facts=self.facts)
        self.view = self.gpu.view("main", width, height)
        self.passes = SharedPasses(self.gpu, self.view, TextureSpacePBGI.needs)
        self.method = TextureSpacePBGI()
        self.method.prepare(self.gpu, scene, self.facts, resolve_params(TextureSpacePBGI, params), self.view)
        prof = StageProfiler(ctx, self.passes.stages + TextureSpacePBGI.stages)
        prof.begin_frame()
        self.passes.render(prof)
        self.out = self.method.render(Frame(ctx, self.gpu, self.view, self.passes, 0, 0), prof)
        ctx.finish()
        check_gl(ctx, "pbgi live frame")

    def close(self):
        self.method.release()
        self.passes.release()
        self.gpu.release()


def _rel_l1(a, b):
    return float(np.abs(a - b).mean() / np.abs(b).mean())


def test_unwrap_charts_and_partition_of_unity(gl_ctx):
    live = _Live(gl_ctx, make_grid_box(4), {"lightmap_resolution": 40})
    try:
        m = live.method
        uw = m.unwrap
        assert uw.chart_count == 3  # floor, back wall, left wall: each one planar chart
        lm = m.read_lightmap()
        xs, ys = m.texel_xy.T
        area = lm["position"][ys, xs, 3].astype(np.float64)
        # texel areas partition the surface: they sum to the scene's area, chart by chart
        assert area.sum() == pytest.approx(live.facts.total_area_m2, rel=1e-5)
        for c in range(uw.chart_count):
            assert area[m.texel_chart == c].sum() == pytest.approx(uw.chart_area_m2[c], rel=1e-5)
        # interior texels hold a full texel of surface: 1 / s^2 on these axis-aligned walls
        assert np.median(area) == pytest.approx(1.0 / uw.scale ** 2, rel=1e-4)
        # covered texels lie inside their chart's box, nowhere else (no bleeding between charts)
        x0, y0, w, h = uw.chart_box[m.texel_chart].T
        assert np.all((xs >= x0) & (xs < x0 + w) & (ys >= y0) & (ys < y0 + h))
        covered = np.zeros((uw.resolution, uw.resolution), bool)
        covered[ys, xs] = True
        assert not np.any((lm["position"][..., 3] != 0) & ~covered)
        # a surfel is the centroid of the surface in its texel: on the chart's plane, within the texel
        p = lm["position"][ys, xs, :3] / area[:, None]
        n = lm["face_normal"][ys, xs, :3] / area[:, None]
        assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-4)
        tri = np.array([np.flatnonzero(uw.chart_of_triangle == c)[0] for c in m.texel_chart])
        v0 = live.gpu.positions[live.gpu.faces[tri, 0]]
        assert np.abs(np.einsum("ij,ij->i", p - v0, uw.face_normal[tri])).max() < 1e-5
        uv = np.einsum("ijk,ik->ij", uw.rows[tri, :, :3], p) + uw.rows[tri, :, 3]
        off = np.abs(uv - (m.texel_xy + 0.5))
        assert off.max() <= 0.5 + 1e-3 and np.mean(off.max(axis=1) < 1e-3) > 0.7
    finally:
        live.close()


def test_curved_charts_partition_the_sphere(gl_ctx):
    from bench.corpus import load_scene
    scene = load_scene("sphere_inside", subdivisions=2)
    live = _Live(gl_ctx, scene, {"lightmap_resolution": 32})
    try:
        m = live.method
        assert 6 <= m.unwrap.chart_count <= 12   # six caps, a few stray boundary triangles at most
        area = m.read_lightmap()["position"][..., 3].astype(np.float64)
        assert area.sum() == pytest.approx(live.facts.total_area_m2, rel=1e-5)
    finally:
        live.close()


def test_unwrap_packs_many_charts_and_refuses_too_many(gl_ctx):
    rng = np.random.default_rng(1)
    # 60 disjoint tilted triangles: 60 charts
    centres = rng.uniform(-1, 1, (60, 1, 3))
    verts = (centres + rng.normal(0, 0.1, (60, 3, 3))).reshape(-1, 3)
    faces = np.arange(180).reshape(60, 3)
    uw = unwrap(verts, faces, 64, 1e-9)
    assert uw.chart_count == 60
    x0, y0, w, h = uw.chart_box.T
    assert np.all(x0 + w <= 64) and np.all(y0 + h <= 64)
    occupied = np.zeros((64, 64), int)
    for a, b, c, d in uw.chart_box:
        occupied[b:b + d, a:a + c] += 1
    assert occupied.max() == 1  # boxes never overlap
    scene = Scene.build("confetti", verts, faces, 0.5, [PointLight([0, 0, 0], [1, 1, 1])],
                        {"main": Camera([0, 0, 4], [0, 0, 0], fov_y_deg=50)})
    with pytest.raises(SkipRow, match="lightmap_resolution"):
        run_method(gl_ctx, TextureSpacePBGI, scene, "main", 16, 16, {"lightmap_resolution": 16}, frames=1)


def test_gather_matches_numpy_brute_force(gl_ctx):
    """The lightmap irradiance equals the disk-to-point sum over the surfels, side by side."""
    live = _Live(gl_ctx, make_open_box(), {"lightmap_resolution": 24})
    try:
        m = live.method
        s = np.frombuffer(m.surfels.read(), np.float32).reshape(-1, 4, 4).astype(np.float64)
        pos, area, nrm, bf, bb = s[:, 0, :3], s[:, 0, 3], s[:, 1, :3], s[:, 2, :3], s[:, 3, :3]
        assert np.all(area > 0) and bf.max() > 0
        v = pos[:, None, :] - pos[None, :, :]            # [receiver, emitter]: emitter -> receiver
        d2 = np.einsum("ijk,ijk->ij", v, v)
        d2[d2 <= 0] = np.inf                              # own surfel (and coincident ones): skipped
        w = v / np.sqrt(d2)[..., None]
        cos_e = np.einsum("jk,ijk->ij", nrm, w)
        cos_r = -np.einsum("ik,ijk->ij", nrm, w)
        transfer = area[None] * np.abs(cos_e) * np.abs(cos_r) / (np.pi * d2 + area[None])
        transfer[~np.isfinite(d2)] = 0.0
        emitted = np.where((cos_e > 0)[..., None], bf[None], bb[None])
        e = transfer[..., None] * emitted
        front = np.where((cos_r > 0)[..., None], e, 0).sum(1)
        back = np.where((cos_r <= 0)[..., None], e, 0).sum(1)
        lm = m.read_lightmap()
        xs, ys = m.texel_xy.T
        gl_front, gl_back = lm["total_front"][ys, xs, :3], lm["total_back"][ys, xs, :3]
        scale = front.max()
        assert scale > 0
        assert np.abs(gl_front - front).max() < 1e-4 * scale
        assert np.abs(gl_back - back).max() < 1e-4 * scale
    finally:
        live.close()


def test_deterministic_finite_and_timed(gl_ctx):
    scene = make_open_box()
    runs = [run_method(gl_ctx, TextureSpacePBGI, scene, "main", 48, 36, {"lightmap_resolution": 32}, seed=5,
                       frames=1) for _ in range(2)]
    a, b = runs
    assert np.array_equal(a.indirect, b.indirect) and np.array_equal(a.direct, b.direct)
    assert np.all(np.isfinite(a.indirect)) and a.indirect.max() > 0 and a.indirect.min() >= 0
    for stage in ("lightmap_gbuffer", "lightmap_direct", "gather", "resolve"):
        assert stage in a.stage_ms and len(a.stage_ms[stage]) == 1
    assert a.skipped_stages == ("emitter_clusters",)
    c = run_method(gl_ctx, TextureSpacePBGI, scene, "main", 48, 36, {"lightmap_resolution": 32, "emitter_level": 1},
                   frames=1)
    assert "emitter_clusters" in c.stage_ms and c.skipped_stages == ()
    assert c.extra["emitters"] < a.extra["emitters"]


def test_converges_to_manylights_with_lightmap_resolution(gl_ctx):
    from methods.manylights.method import ManyLights
    scene = make_grid_box(4)
    ref = run_method(gl_ctx, ManyLights, scene, "main", 48, 36, {"emission": "lambert", "jitter_frames": 256},
                     frames=1).indirect
    errors = [_rel_l1(run_method(gl_ctx, TextureSpacePBGI, scene, "main", 48, 36, {"lightmap_resolution": r},
                                 frames=1).indirect, ref) for r in (16, 32, 96)]
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 0.02   # the reference's own jitter noise is about 1%


def test_sphere_inside_analytic_bounces_and_emitter_hierarchy(gl_ctx):
    from bench.corpus import load_scene
    from bench.corpus.procedural import sphere_inside_indirect
    scene = load_scene("sphere_inside", subdivisions=3)
    expected = sphere_inside_indirect()  # rho^2 I / (pi R^2), rho = 0.5

    def ratio(**params):
        r = run_method(gl_ctx, TextureSpacePBGI, scene, "main", 48, 36, dict(lightmap_resolution=48, **params),
                       frames=1)
        return r.indirect[..., 0] / expected

    one = ratio()
    assert np.abs(one - 1.0).max() < 0.03
    # inside a sphere E_{k+1} = rho E_k: two bounces give (1 + rho) times one bounce
    two = ratio(bounces=2)
    assert np.abs(two / 1.5 - 1.0).max() < 0.03
    assert np.all(two > one)
    # the paper's key trade: coarser emitters (fewer disks) cost accuracy, monotonically
    dev = [abs(float(ratio(emitter_level=level).mean()) - 1.0) for level in (0, 2, 3)]
    assert dev[0] < dev[1] < dev[2]


@pytest.mark.parametrize("params, culprit", [({"lightmap_resolution": 8}, "lightmap_resolution"),
                                             ({"emitter_level": 5}, "emitter_level"),
                                             ({"bounces": 0}, "bounces"),
                                             ({"lightmap_size": 64}, "lightmap_size")])
def test_bad_parameters(params, culprit):
    with pytest.raises(ParamError, match=culprit) as info:
        resolve_params(TextureSpacePBGI, params)
    assert "\n" not in str(info.value)


def test_folded_chart_is_split(gl_ctx):
    """A helical ramp (1.2 turns, normals dominantly +y) is one connected height-field chart
    whose projection overlaps itself: it must be split so no two triangles share a texel."""
    theta = np.linspace(0.0, 2.4 * np.pi, 49)
    ring = []
    for r in (0.5, 1.0):
        ring.append(np.column_stack([r * np.cos(theta), 0.05 * theta, r * np.sin(theta)]))
    verts = np.concatenate(ring)
    n = len(theta)
    i = np.arange(n - 1)
    faces = np.concatenate([np.column_stack([i, i + n, i + 1]), np.column_stack([i + 1, i + n, i + n + 1])])
    scene = Scene.build("ramp", verts, faces, 0.6, [PointLight([0, 1.5, 0], [3, 3, 3])],
                        {"main": Camera([0, 2.5, 2.0], [0, 0.3, 0], fov_y_deg=60)})
    assert len(np.unique(unwrap(verts, faces, 64, 1e-9).chart_of_triangle)) == 1
    live = _Live(gl_ctx, scene, {"lightmap_resolution": 64})
    try:
        m = live.method
        assert m.folded_charts >= 1 and m.unwrap.chart_count > 1
        lm = m.read_lightmap()
        assert lm["position"][..., 3].astype(np.float64).sum() == pytest.approx(live.facts.total_area_m2, rel=1e-5)
        img = live.method.indirect.read()
        assert np.all(np.isfinite(np.frombuffer(img, np.float32)))
    finally:
        live.close()
