"""Input rejection (the `invalid` family of bench.stress.suite): non-finite vertices, normals,
lights and cameras, given to the Scene model or written in a scene file (TOML + OBJ), must raise
SceneError with one line that names the culprit."""
from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from bench.model.scene import Camera, PointLight, Scene, SceneError
from bench.model.scenefile import load_scene_file
from bench.stress.fuzz import MESH_FILES, VALID_DOC, toml_document


def invalid_input_checks() -> dict:
    """{check name: None if bad input is rejected with one clear SceneError line, else the problem}."""
    out = {}
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    light, cam = [PointLight([0, 0, 1], 1.0)], {"main": Camera([0, 0, 3], [0, 0, 0])}

    def expect(name, fn, must_contain):
        try:
            fn()
        except SceneError as exc:
            msg = str(exc)
            if len(msg.splitlines()) != 1:
                out[name] = f"multi-line error {msg!r}"
            elif not any(word in msg for word in must_contain):
                out[name] = f"error does not name the culprit: {msg!r}"
            else:
                out[name] = None
            return
        except Exception as exc:
            out[name] = f"{type(exc).__name__} instead of SceneError: {' '.join(str(exc).split())}"
            return
        out[name] = "accepted"

    for label, value in (("nan", np.nan), ("inf", np.inf), ("-inf", -np.inf)):
        bad = v.copy()
        bad[1, 0] = value
        expect(f"{label}_vertex", lambda bad=bad: Scene.build("s", bad, [[0, 1, 2]], 0.5, light, cam), ("vertex 1",))
        expect(f"{label}_normal", lambda value=value: Scene.build("s", v, [[0, 1, 2]], 0.5, light, cam,
                                                                  normals=np.where(v == 1, value, 0.0) + [0, 0, 1]),
               ("normal",))
        expect(f"{label}_light", lambda value=value: PointLight([0, value, 1], 1.0), ("position",))
        expect(f"{label}_camera", lambda value=value: Camera([0, 0, value], [0, 0, 0]), ("eye",))
    with tempfile.TemporaryDirectory(prefix="gibench-invalid-") as tmp:
        d = Path(tmp)
        for mesh in ("nan_vertex", "inf_vertex"):
            (d / f"{mesh}.obj").write_text(MESH_FILES[mesh])
            doc = json.loads(json.dumps(VALID_DOC))
            doc["mesh"][0]["file"] = f"{mesh}.obj"
            (d / f"{mesh}.toml").write_text(toml_document(doc))
            expect(f"obj_{mesh}", lambda p=d / f"{mesh}.toml": load_scene_file(p), (f"{mesh}.obj",))
        (d / "m.obj").write_text(MESH_FILES["quad"])
        for key, where, value in (("translate", "mesh", float("nan")), ("scale", "mesh", float("inf")),
                                  ("position", "light", float("nan")), ("eye", "camera", float("-inf"))):
            doc = json.loads(json.dumps(VALID_DOC))
            table = doc["mesh"][0] if where == "mesh" else doc["light"][0] if where == "light" else doc["camera"]["main"]
            table[key] = [value, 0.0, 0.0] if key != "scale" else value
            path = d / f"toml_{key}.toml"
            path.write_text(toml_document(doc))
            expect(f"toml_{where}_{key}_nonfinite", lambda p=path: load_scene_file(p), (f"'{key}'",))
        for label, scale_value, shift, culprit in (("toml_mesh_huge_scale", 1e300, 0.0, "'scale'"),
                                                   ("toml_mesh_overflow", 1e29, 9.5e29, "vertex")):
            doc = json.loads(json.dumps(VALID_DOC))
            doc["mesh"][0]["scale"] = scale_value
            doc["mesh"][0]["translate"] = [shift, 0.0, 0.0]
            path = d / f"{label}.toml"
            path.write_text(toml_document(doc))
            expect(label, lambda p=path: load_scene_file(p), (culprit,))
        for label in ("light_direction", "camera_eye"):
            doc = json.loads(json.dumps(VALID_DOC))
            key = "direction" if label == "light_direction" else "eye"
            (doc["light"][2] if label == "light_direction" else doc["camera"]["main"])[key] = [1e155, 0.0, 1.0]
            path = d / f"toml_{label}_overflow.toml"
            path.write_text(toml_document(doc))
            expect(f"toml_{label}_overflow", lambda p=path: load_scene_file(p), (f"'{key}'", key))
    return out
