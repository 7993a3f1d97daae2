"""Property-based fuzzing of the TOML scene reader (bench.stress.fuzz) and the input-validation
fixes it led to (bench.model.scene, bench.model.scenefile)."""
from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402

from bench.model.scene import Camera, DirectionalLight, Scene, SceneError  # noqa: E402
from bench.model.scenefile import load_scene_file  # noqa: E402
from bench.stress.fuzz import (MESH_FILES, VALID_DOC, FuzzFailure, check_document, run_fuzz,  # noqa: E402
                               scene_documents, toml_document)


@settings(max_examples=200, deadline=None, database=None, suppress_health_check=list(HealthCheck))
@given(case=scene_documents())
def test_reader_gives_a_scene_or_one_error_line(case, tmp_path_factory):
    text, mesh = case
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a numpy overflow warning is a bug of the reader too
        assert check_document(text, mesh, tmp_path_factory.mktemp("fuzz")) in ("scene", "error")


def test_generated_documents_reach_valid_scenes(tmp_path):
    out = run_fuzz(60, tmp_path, seed=3)
    assert out["failure"] is None
    assert out["scenes"] > 0 and out["errors"] > 0 and out["scenes"] + out["errors"] >= 60


def test_toml_writer_round_trips():
    import tomllib
    assert tomllib.loads(toml_document(VALID_DOC)) == VALID_DOC
    doc = {"x": [float("nan"), float("inf"), -float("inf"), 1e-320, "a\nb", {"k y": True}]}
    back = tomllib.loads(toml_document(doc))["x"]
    assert np.isnan(back[0]) and back[1:3] == [float("inf"), -float("inf")] and back[3:] == doc["x"][3:]


def test_check_document_flags_a_traceback(tmp_path, monkeypatch):
    import bench.model.scenefile
    monkeypatch.setattr(bench.model.scenefile, "load_scene_file", lambda p: (_ for _ in ()).throw(TypeError("boom")))
    with pytest.raises(FuzzFailure, match="TypeError: boom"):
        check_document(toml_document(VALID_DOC), "quad", tmp_path)


def _write(tmp_path, doc, mesh="quad"):
    (tmp_path / "m.obj").write_text(MESH_FILES[mesh])
    path = tmp_path / "scene.toml"
    path.write_text(toml_document(doc))
    return path


def _one_line_error(path) -> str:
    with pytest.raises(SceneError) as info:
        load_scene_file(path)
    msg = str(info.value)
    assert len(msg.splitlines()) == 1 and msg.startswith(f"scene file '{path}'")
    return msg


# ---------------------------------------------------------------------------- regressions the fuzzer found
def test_line_break_in_a_key_stays_one_line(tmp_path):
    doc = dict(json.loads(json.dumps(VALID_DOC)), **{"bad\nkey\u2028x": False})
    msg = _one_line_error(_write(tmp_path, doc))
    assert "unknown key 'bad\\nkey\\u2028x'" in msg


def test_huge_direction_is_rejected_not_zeroed(tmp_path):
    # norm(1e155) overflows to inf and the direction divided by it became the zero vector
    with pytest.raises(SceneError, match="beyond"):
        DirectionalLight([1e155, 0.0, 1.0], 1.0)
    doc = json.loads(json.dumps(VALID_DOC))
    doc["light"][2]["direction"] = [1.3407807929942597e154, -1, -0.2]
    assert "'direction'" in _one_line_error(_write(tmp_path, doc))


def test_vertices_beyond_the_magnitude_bound(tmp_path):
    v = np.array([[0, 0, 0], [1e31, 0, 0], [0, 1, 0]], float)
    with pytest.raises(SceneError, match="vertex 1 .* beyond"):
        Scene.build("s", v, [[0, 1, 2]], 0.5, [DirectionalLight([0, -1, 0], 1.0)],
                    {"main": Camera([0, 0, 3], [0, 0, 0])})
    doc = json.loads(json.dumps(VALID_DOC))
    doc["mesh"][0]["scale"] = 1e29
    doc["mesh"][0]["translate"] = [9.5e29, 0.0, 0.0]
    assert "vertex" in _one_line_error(_write(tmp_path, doc))
    doc["mesh"][0]["scale"] = 1e300
    assert "'scale'" in _one_line_error(_write(tmp_path, doc))


def test_non_finite_obj_vertex_is_rejected_without_warnings(tmp_path):
    doc = json.loads(json.dumps(VALID_DOC))
    for mesh in ("nan_vertex", "inf_vertex"):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert "non-finite vertex" in _one_line_error(_write(tmp_path, doc, mesh))


def test_tiny_mirroring_scale_flips_the_winding(tmp_path):
    # det(diag(-1e-110, 1e-110, 1e-110)) underflows to -0.0, which is not < 0: the winding was kept
    from bench.model.meshfile import read_mesh, transform_matrix, transformed
    (tmp_path / "m.obj").write_text(MESH_FILES["quad"])
    mesh = read_mesh(tmp_path / "m.obj")
    out = transformed(mesh, transform_matrix(scale=[-1e-110, 1e-110, 1e-110]))
    assert np.array_equal(out.faces, mesh.faces[:, ::-1])
    assert np.array_equal(transformed(mesh, transform_matrix(scale=1e-110)).faces, mesh.faces)


def test_tiny_scale_keeps_unit_normals_without_overflow(tmp_path):
    # scale 1.6e-291 (found by the fuzzer in CI): the inverse transpose's normals were ~1e290, whose
    # squares overflowed in their norm (a RuntimeWarning escaping the reader)
    from bench.model.meshfile import read_mesh, transform_matrix, transformed
    (tmp_path / "m.obj").write_text(MESH_FILES["quad"])
    mesh = read_mesh(tmp_path / "m.obj")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tiny = transformed(mesh, transform_matrix(rotate_deg=(-90, 0, 0), scale=1.6207867400787494e-291))
    plain = transformed(mesh, transform_matrix(rotate_deg=(-90, 0, 0)))
    assert np.allclose(tiny.normals, plain.normals, atol=1e-12)
