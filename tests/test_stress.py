"""`gibench stress` (bench.stress: suite, perturb, variants, figures, limits, case, isolate): perturbations,
figures, verdicts, the quick suite."""
from __future__ import annotations

import json
from typing import ClassVar

import sys

import numpy as np
import pandas as pd
import pytest

from bench.stress import perturb
from bench.stress import suite as stress
from bench.stress.case import run_case
from bench.stress.figures import mean_change, pixel_counts, relative_change
from bench.stress.isolate import run_case_isolated
from bench.stress.limits import documented_limits, match_limit
from bench.stress.variants import param_variants
from bench.protocol.vocabulary import REFERENCE_COMPONENTS
from reports.stress import build_stress_report
from bench.protocol.method import FrameOutput, MethodBase, Param
from bench.model.scene import DirectionalLight, PointLight, SpotLight, triangle_normals
from tests.conftest import make_grid_box, make_open_box


def _spot_scene():
    """The grid box with a spot and a directional light added (every light kind)."""
    s = make_grid_box(n=4)
    from bench.model.scene import Scene
    lights = s.lights + [SpotLight([0.5, 1.5, 0.5], [0, 0, -1], 5.0), DirectionalLight([0.2, -1, -0.3], 0.5)]
    return Scene.build(s.name, s.vertices, s.faces, s.albedo, lights, s.cameras, normals=s.normals)


# ---------------------------------------------------------------------------- perturbations (no GL)
@pytest.mark.parametrize("s", [1e-4, 1e4])
def test_scale_keeps_radiance(s):
    base = _spot_scene()
    out = perturb.scale(base, s)
    assert out.name == f"{base.name}+scale={s:.0e}"
    assert np.allclose(out.vertices, base.vertices * s, rtol=1e-15)
    for a, b in zip(base.lights, out.lights):
        if isinstance(a, DirectionalLight):
            assert np.array_equal(a.irradiance, b.irradiance) and np.allclose(a.direction, b.direction)
        else:  # I / r^2 unchanged
            assert np.allclose(b.intensity, a.intensity * s * s, rtol=1e-15)
            assert np.allclose(b.position, a.position * s)
    assert np.allclose(out.cameras["main"].eye, base.cameras["main"].eye * s)
    assert np.allclose(out.areas().sum(), base.areas().sum() * s * s, rtol=1e-12)


def test_translate_moves_everything_by_radii():
    base = _spot_scene()
    out = perturb.translate(base, 1e5)
    offset = out.vertices[0] - base.vertices[0]
    radius = 0.5 * np.linalg.norm(np.ptp(base.vertices, axis=0))
    assert np.linalg.norm(offset) == pytest.approx(1e5 * radius, rel=1e-9)
    assert np.all(np.abs(offset) > 1e3 * radius)  # every coordinate moves
    assert np.allclose(out.vertices - base.vertices, offset, rtol=0, atol=1e-9 * np.linalg.norm(offset))
    assert np.allclose(out.lights[0].position - base.lights[0].position, offset)
    assert np.array_equal(out.lights[0].intensity, base.lights[0].intensity)


def test_degenerate_geometry_keeps_the_surface():
    base = make_grid_box(n=6)
    area = base.areas().sum()
    z = perturb.zero_area(base, count=16)
    assert z.triangle_count == base.triangle_count and z.dropped_degenerate == 32
    sl = perturb.sliver(base, count=16)
    new = sl.faces[base.triangle_count:]
    v = sl.vertices
    base_len = np.linalg.norm(v[new[:, 1]] - v[new[:, 0]], axis=1)
    height = 2 * sl.areas()[base.triangle_count:] / base_len
    assert sl.triangle_count == base.triangle_count + 16
    assert np.allclose(height / base_len, perturb.SLIVER_ASPECT, rtol=1e-3)
    dup = perturb.duplicate(base, count=16)  # repeated triangles are one surface: the scene model drops them
    assert dup.triangle_count == base.triangle_count and dup.dropped_duplicates == 16
    assert np.array_equal(dup.faces, base.faces) and dup.content_hash() == base.content_hash()
    fl = perturb.flipped(base, count=16)
    hosts = perturb.host_triangles(base, 16)
    assert np.allclose(fl.face_normals()[hosts], -base.face_normals()[hosts])
    assert fl.areas().sum() == pytest.approx(area, rel=1e-12)
    tj = perturb.t_junction(base, count=16)
    assert tj.triangle_count == base.triangle_count + 16 and tj.areas().sum() == pytest.approx(area, rel=1e-12)
    cp = perturb.coplanar(base, count=16)
    extra = cp.faces[base.triangle_count:]
    # each new triangle lies in its host's plane, with its albedo
    host_n = base.face_normals()[hosts]
    host_p = base.vertices[base.faces[hosts, 0]]
    for corner in range(3):
        assert np.allclose(((cp.vertices[extra[:, corner]] - host_p) * host_n).sum(1), 0, atol=1e-12)
    assert np.allclose(np.abs((triangle_normals(cp.vertices, extra) * host_n).sum(1)), 1)
    assert np.array_equal(cp.albedo[base.triangle_count:], base.albedo[hosts])


def test_scene_model_drops_repeated_triangles():
    # found by the suite: manylights and dss counted a repeated triangle's light twice (+3.1% on cornell_spot)
    base = make_open_box()
    faces = np.concatenate([base.faces, base.faces[[0]], base.faces[[2], ::-1], base.faces[[4]][:, [1, 2, 0]]])
    albedo = np.concatenate([base.albedo, base.albedo[[0, 2, 4]]])
    from bench.model.scene import Scene
    s = Scene.build("dups", base.vertices, faces, albedo, base.lights, base.cameras, normals=base.normals)
    assert s.triangle_count == base.triangle_count and s.dropped_duplicates == 3
    assert np.array_equal(s.faces, base.faces) and np.array_equal(s.albedo, base.albedo)
    # the same vertices in another triangle are not a repeat
    other = np.concatenate([base.faces, [[0, 1, 3]]])
    s2 = Scene.build("t", base.vertices, other, 0.5, base.lights, base.cameras)
    assert s2.dropped_duplicates == 0 and s2.triangle_count == base.triangle_count + 1


def test_grazing_camera_and_light():
    base = _spot_scene()
    radius = 0.5 * np.linalg.norm(np.ptp(base.vertices, axis=0))
    centroid, normal, axis, _ = perturb.dominant_plane(base)
    cam = perturb.grazing_camera(base, "main").cameras["main"]
    height = np.dot(cam.eye - centroid, normal)
    assert height == pytest.approx(perturb.GRAZING_CAMERA_HEIGHT_RADII * radius, rel=1e-6)
    assert abs(np.dot(cam.target - cam.eye, normal)) < 1e-9  # looking along the plane
    lit = perturb.grazing_light(base)
    from trimesh.triangles import closest_point
    tris = base.vertices[base.faces]
    for light in lit.lights:
        if isinstance(light, (PointLight, SpotLight)):
            dist = np.linalg.norm(closest_point(tris, np.broadcast_to(light.position, (len(tris), 3))) - light.position,
                                  axis=1).min()
            assert dist == pytest.approx(perturb.GRAZING_LIGHT_HEIGHT_RADII * radius, rel=1e-3)
        else:
            assert np.degrees(np.arcsin(abs(np.dot(light.direction, normal)))) == pytest.approx(1.0)


def test_param_variants_cover_the_declared_ends():
    from bench.protocol.registry import load_method
    cls = load_method("ir_unshadowed")
    full = dict(param_variants(cls, quick=False))
    assert full["params:vpl_count=1"] == {"vpl_count": 1} and full["params:vpl_count=65536"] == {"vpl_count": 65536}
    assert full["params:clamp_distance_rel=1e-07"] == {"clamp_distance_rel": 1e-07}
    quick = dict(param_variants(cls, quick=True))
    assert quick == {"params:vpl_count=1": {"vpl_count": 1}}
    flc = dict(param_variants(load_method("flc"), quick=False))
    assert flc["params:reach=eq18_printed"] == {"reach": "eq18_printed"}
    assert flc["params:jitter=False"] == {"jitter": False}


def test_figures():
    a = np.ones((4, 4, 3), np.float32)
    b = a.copy()
    b[0, 0] = [np.nan, 1, 1]
    b[0, 1] = [np.inf, 1, 1]
    b[1, 1] = [-0.5, 1, 1]
    counts = pixel_counts(b, a)
    assert (counts["nan_pixels"], counts["inf_pixels"], counts["negative_pixels"]) == (1, 1, 1)
    assert counts["min_value"] == -0.5
    assert relative_change(a * 1.1, a) == pytest.approx(0.1, rel=1e-6)
    assert mean_change(a * 0.9, a) == pytest.approx(-0.1, rel=1e-6)
    assert relative_change(a, a) == 0.0


def test_documented_limits_from_the_manual():
    class Documented(MethodBase):
        """A method.

        Stress limit scale=1e-0*: an absolute epsilon of 1e-3 m (change 0.2 at 1e-4).
        """
        name = "documented"
        stress_limits: ClassVar[dict] = {"translate=*": "float32 positions"}
    limits = documented_limits(Documented)
    assert match_limit(limits, "scale=1e-04").startswith("an absolute epsilon")
    assert match_limit(limits, "translate=1e+05R") == "float32 positions"
    assert match_limit(limits, "scale=1e+04") is None


def test_documented_limits_of_the_shipped_manuals():
    """The manuals are the method modules' docstrings and their patterns hold colons
    (params:NAME=VALUE): every "Stress limit" line of every method reaches the suite."""
    from bench.protocol.registry import list_methods, load_method
    for name in list_methods():
        cls = load_method(name)
        manual = sys.modules[cls.__module__].__doc__ or ""
        lines = [ln.strip() for ln in manual.splitlines() if ln.strip().startswith("Stress limit")]
        limits = documented_limits(cls)
        for line in lines:
            pattern = line[len("Stress limit"):].strip().split(": ")[0].rstrip(":")
            assert pattern in limits, (name, line, sorted(limits))
            assert match_limit(limits, pattern) is not None
    flc = documented_limits(load_method("flc"))
    assert match_limit(flc, "params:progressive_frames=4096")
    assert match_limit(flc, "params:progressive_frames=1") is None


# ---------------------------------------------------------------------------- the suite on fake methods (GL)
class TinyScaleNaN(MethodBase):
    """A method that breaks below 1 cm: NaN, Inf and negative indirect pixels (as an absolute
    epsilon would). Its parameter `spread` scales its constant indirect image."""
    name = "tiny_scale_nan"
    summary = "test method"
    needs = frozenset({"direct", "shadow_map"})
    params = {"spread": Param(1.0, "indirect level", low=0.5, high=2.0, quality=True)}

    def prepare(self, gpu, scene, facts, params, view):
        self.small = facts.scene_radius < 1e-2
        self.level = 0.1 * params["spread"]

    def render(self, frame, prof):
        indirect = np.full((frame.height, frame.width, 3), self.level, np.float32)
        if self.small:
            indirect[0, 0], indirect[0, 1], indirect[0, 2] = np.nan, np.inf, -1.0  # one pixel each
        return FrameOutput(direct=frame.passes.direct.radiance, indirect=indirect)


class DocumentedTinyScaleNaN(TinyScaleNaN):
    """The same, documented.

    Stress limit scale=1e-04: breaks below 1 cm (3 bad pixels).
    """
    name = "documented_nan"


def test_probe_counts_non_finite_pixels_instead_of_aborting(gl_ctx):
    scene = perturb.scale(make_open_box(), 1e-4)
    res = run_case(gl_ctx, TinyScaleNaN, scene, "main", 32, 24, {}, 0)
    assert res.status == "ok"
    counts = pixel_counts(res.images["direct"], res.images["indirect"])
    assert (counts["nan_pixels"], counts["inf_pixels"], counts["negative_pixels"]) == (1, 1, 1)
    # the harness alone refuses the frame: the probe is what lets the suite count
    from bench.run.harness import run_method
    with pytest.raises(FloatingPointError):
        run_method(gl_ctx, TinyScaleNaN, scene, "main", 32, 24, warmup=1, frames=1)


def test_suite_flags_and_documents_failures(gl_ctx, tmp_path):
    cfg = stress.StressConfig(scenes=[make_open_box()], methods=[TinyScaleNaN, DocumentedTinyScaleNaN, "direct"],
                              quick=True, out=tmp_path / "s", references=False, fuzz_examples=5)
    df, suite = stress.run_stress(cfg, log=lambda m: None)
    build_stress_report(suite.run_dir)  # the page is built from the folder after the suite, as `gibench stress` does
    assert list(df.columns) == list(stress.COLUMNS)
    row = lambda p, n: df[(df["perturbation"] == p) & (df["name"] == n)].iloc[0]
    bad = row("scale=1e-04", "tiny_scale_nan")
    assert bad["verdict"] == "fail" and bad["nan_pixels"] == 1 and bad["inf_pixels"] == 1 and bad["negative_pixels"] == 1
    assert "NaN" in bad["note"]
    assert row("scale=1e-04", "documented_nan")["verdict"] == "documented"
    assert row("scale=1e+04", "tiny_scale_nan")["verdict"] == "pass"
    # the shared direct pass keeps every invariance of the quick subset exactly enough
    direct = df[(df["name"] == "direct") & (df["kind"] == "invariance")]
    assert set(direct["perturbation"]) >= {"repeat", "scale=1e-04", "scale=1e+04", "translate=1e+04R", "sliver", "t_junction"}
    assert (direct["verdict"] == "pass").all(), direct[["perturbation", "note"]]
    assert (direct["change"] <= stress.TOLERANCE_FLOOR).all()
    # parameter extremes: the quality knob at its low end, change reported, not judged
    p = row("params:spread=0.5", "tiny_scale_nan")
    assert p["verdict"] == "pass" and p["change_indirect"] == pytest.approx(0.5, rel=1e-5)
    assert not (df["target"] == "reference").any()  # --no-reference
    assert (df[df["family"] == "invalid"]["verdict"] == "pass").all()
    assert (tmp_path / "s" / "stress.csv").is_file() and (tmp_path / "s" / "stress.html").is_file()
    assert "tiny_scale_nan" in (tmp_path / "s" / "stress.html").read_text()
    assert "FAIL" in stress.summary_text(df) and "tiny_scale_nan" in stress.summary_text(df)


@pytest.mark.slow
def test_isolated_case_matches_in_process(gl_ctx):
    from bench.model.corpus import load_scene
    from bench.protocol.registry import load_method
    scene = load_scene("cornell_spot")
    here = run_case(gl_ctx, load_method("direct"), scene, "main", 32, 24, {}, 0)
    there = run_case_isolated({"scene": "cornell_spot", "variant": None, "method": "direct", "params": {},
                                      "view": "main", "width": 32, "height": 24, "seed": 0}, timeout=120)
    assert there.status == "ok"
    assert np.array_equal(here.images["direct"], there.images["direct"])


# ---------------------------------------------------------------------------- the quick suite through the CLI
@pytest.mark.mitsuba
def test_quick_suite_cli(tmp_path, capsys):
    from bench.cli import main
    out = tmp_path / "quick"
    code = main(["stress", "--quick", "--scenes", "cornell_spot", "--methods", "direct,ir_unshadowed", "--out", str(out),
                 "--fuzz-examples", "20"])
    df = pd.read_csv(out / "stress.csv")
    printed = capsys.readouterr().out
    assert code == (1 if (df["verdict"] == "fail").any() else 0)
    assert printed.splitlines()[0].startswith(f"{int((df['verdict'] == 'pass').sum())} pass")
    assert set(df["family"]) >= {"determinism", "scale", "translate", "degenerate", "grazing", "params", "invalid", "fuzz"}
    refs = df[df["target"] == "reference"]
    assert set(refs["name"]) == set(REFERENCE_COMPONENTS)
    assert refs["nan_pixels"].eq(0).all() and refs["inf_pixels"].eq(0).all()
    # invariance rows carry a tolerance and the criterion that used it
    inv = df[(df["kind"] == "invariance") & df["target"].isin(["method", "reference"])]
    assert inv["tolerance"].notna().all() and inv["criterion"].str.contains("change <=").all()
    meta = json.loads((out / "stress.json").read_text())
    assert meta["config"]["width"] == 32 and meta["config"]["height"] == 24
    page = (out / "stress.html").read_text()
    assert "reference: indirect_visible" in page and "ir_unshadowed" in page
    from reports.build import build_report
    assert build_report(out).name == "stress.html"  # `gibench report` of a stress folder gives its page


def test_only_runs_the_named_families(gl_ctx, tmp_path):
    cfg = stress.StressConfig(scenes=[make_open_box()], methods=["direct"], quick=True, out=tmp_path / "o",
                              references=False, families=["scale", "invalid"])
    df, _ = stress.run_stress(cfg, log=lambda m: None)
    assert set(df["family"]) == {"scale", "invalid"}
    with pytest.raises(ValueError, match="unknown family scales"):
        stress.StressConfig(scenes=["cornell_spot"], methods=["direct"], families=["scales"]).resolve()


@pytest.mark.parametrize("field, value, message", [
    ("width", 0, "width=0 outside"), ("case_timeout", -1.0, "--timeout -1.0"), ("case_timeout", float("nan"), "--timeout"),
    ("fuzz_examples", -1, "--fuzz-examples -1"), ("fuzz_examples", 0, "--fuzz-examples 0"), ("seed", -1, "--seed -1"),
    ("families", [], "no family given"), ("families", ["scale", "scale"], "family 'scale' is given twice"),
    ("methods", ["direct", "direct"], "method 'direct' is given twice"), ("views", [], "no view given")])
def test_stress_config_refuses_instead_of_replacing(field, value, message):
    """0 was read as "not given" (width 0 -> 64), a negative timeout accepted, -1 fuzz examples a traceback
    (issue #27): ValueError, one line, before the run folder."""
    cfg = stress.StressConfig(scenes=["cornell_spot"], methods=["direct"])
    setattr(cfg, field, value)
    with pytest.raises(ValueError, match=message.replace("[", r"\[")):
        cfg.resolve()


def test_a_parameter_value_never_leaves_the_stress_folder():
    """A perturbation's folder is built from names and values a plugin declares: whatever they
    hold, the folder stays one path-safe component (two names never share it)."""
    from bench.stress.suite import folder_name
    assert folder_name("params:n_avg=64") == "params_n_avg=64"
    escaping = folder_name("params:mode=/../../../tmp/x")
    assert "/" not in escaping and ".." not in escaping
    assert escaping != folder_name("params:mode=/../../../tmp/y")
