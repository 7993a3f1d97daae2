"""Property-based fuzzing of the TOML scene reader (`bench.model.scenefile.load_scene_file`) with hypothesis.

The property: for any document (valid scene files, valid files with some values replaced by
random TOML values, keys dropped or added, text with random edits, random text) and any of a
few mesh files (a valid quad, non-finite vertices, garbage, an empty file, collinear points),
`load_scene_file` either returns a Scene whose facts can be computed (`compute_facts`: every
consumer's first step) or raises `SceneError` whose message is one line naming the scene file.
Any other exception, or a multi-line message, is a failure.

Documents are written as TOML with inline tables (`mesh = [{file = "m.obj"}]`), which tomllib
reads exactly like `[[mesh]]` tables, so any mutated structure can be written out.

hypothesis is imported only when a fuzz runs (`run_fuzz`, `scene_documents`).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

from bench.model import scenefile
from bench.model.scene import SceneError, compute_facts

QUAD_OBJ = "v 0 0 0\nv 1 0 0\nv 1 0 1\nv 0 0 1\nf 1 2 3\nf 1 3 4\n"
MESH_FILES = {
    "quad": QUAD_OBJ,
    "nan_vertex": QUAD_OBJ.replace("v 1 0 0", "v nan 0 0"),
    "inf_vertex": QUAD_OBJ.replace("v 1 0 1", "v 1e999 0 1"),
    "collinear": "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n",
    "empty": "",
    "garbage": "f 9 9 9\nv x y z\n\x00\x01",
}

VALID_DOC = {
    "name": "fuzz",
    "mesh": [{"file": "m.obj", "scale": 2.0, "rotate_deg": [-90, 0, 0], "translate": [0, 0, 0]}],
    "light": [{"type": "point", "position": [0.5, 1.0, 0.5], "intensity": [1, 1, 1]},
              {"type": "spot", "position": [0, 1.9, 1.5], "target": [0, 0, -0.5], "intensity": 10,
               "cutoff_angle_deg": 30, "beam_width_deg": 22.5},
              {"type": "directional", "direction": [0.3, -1, -0.2], "irradiance": 0.5}],
    "camera": {"main": {"eye": [0.5, 2, 2], "target": [0.5, 0, 0.5], "up": [0, 1, 0], "fov_y_deg": 50}},
}


# ---------------------------------------------------------------------------- TOML writer
def _key(k: str) -> str:
    return json.dumps(k, ensure_ascii=False)


def toml_value(v) -> str:
    """One TOML value (inline), for the types the fuzzer generates."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        text = repr(v)
        return text if any(c in text for c in ".en") else text + ".0"
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"no TOML form for {type(v).__name__}")


def toml_document(doc: dict) -> str:
    return "".join(f"{_key(k)} = {toml_value(v)}\n" for k, v in doc.items())


# ---------------------------------------------------------------------------- the property
class FuzzFailure(AssertionError):
    pass


def check_document(text: str, mesh: str, workdir: Path) -> str:
    """Write the document and mesh file into `workdir`, load it; 'scene' or 'error' when the property
    holds, FuzzFailure otherwise."""
    workdir.mkdir(parents=True, exist_ok=True)
    (workdir / "m.obj").write_text(MESH_FILES[mesh], encoding="utf-8")
    path = workdir / "scene.toml"
    path.write_text(text, encoding="utf-8")
    try:
        scene = scenefile.load_scene_file(path)
        compute_facts(scene)
    except SceneError as exc:
        msg = str(exc)
        if len(msg.splitlines()) != 1 or not msg.startswith(f"scene file '{path}'"):
            raise FuzzFailure(f"error is not one line naming the file: {msg!r}") from None
        return "error"
    except Exception as exc:  # the property: nothing but SceneError escapes
        raise FuzzFailure(f"{type(exc).__name__}: {' '.join(str(exc).split())}") from exc
    return "scene"


def scene_documents():
    """A hypothesis strategy of (toml text, mesh file key)."""
    from hypothesis import strategies as st

    scalars = st.one_of(
        st.booleans(), st.integers(min_value=-(2 ** 63), max_value=2 ** 63 - 1),
        st.floats(allow_nan=True, allow_infinity=True),
        st.sampled_from([0.0, -0.0, 1e-320, 1e-300, 1e300, 1e308, 90.0, 180.0, -1.0]),
        st.text(st.characters(blacklist_categories=("Cs",)), max_size=12),
        st.sampled_from(["m.obj", "missing.obj", "../m.obj", "/etc/passwd", "m.xyz", "point", "spot",
                         "directional", "..", "a b", ""]))
    values = st.recursive(scalars, lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=6), inner, max_size=3)), max_leaves=8)
    numbers = st.one_of(st.floats(-1e6, 1e6), st.integers(-1000, 1000), st.floats(allow_nan=True, allow_infinity=True))
    vec3 = st.lists(numbers, min_size=3, max_size=3)

    def paths(doc, prefix=()):
        out = [prefix] if prefix else []
        if isinstance(doc, dict):
            for k, v in doc.items():
                out += paths(v, prefix + (k,))
        elif isinstance(doc, list):
            for i, v in enumerate(doc):
                out += paths(v, prefix + (i,))
        return out

    all_paths = paths(VALID_DOC)

    @st.composite
    def mutated(draw):
        doc = json.loads(json.dumps(VALID_DOC))
        for _ in range(draw(st.integers(1, 3))):
            path = draw(st.sampled_from(all_paths))
            parent, ok = doc, True
            for step in path[:-1]:
                try:
                    parent = parent[step]
                except (KeyError, IndexError, TypeError):
                    ok = False
                    break
            if not ok or not isinstance(parent, (dict, list)):
                continue
            last = path[-1]
            if isinstance(parent, dict) and last not in parent or \
                    isinstance(parent, list) and not (isinstance(last, int) and last < len(parent)):
                continue
            action = draw(st.sampled_from(["replace", "number", "vector", "delete", "add"]))
            if action == "replace":
                parent[last] = draw(values)
            elif action == "number":
                parent[last] = draw(numbers)
            elif action == "vector":
                parent[last] = draw(vec3)
            elif action == "delete":
                del parent[last]
            elif isinstance(parent, dict):
                parent[draw(st.text(min_size=1, max_size=8))] = draw(values)
        return toml_document(doc)

    @st.composite
    def edited(draw):
        text = draw(mutated())
        for _ in range(draw(st.integers(1, 3))):
            i = draw(st.integers(0, len(text)))
            j = draw(st.integers(i, min(len(text), i + 8)))
            text = text[:i] + draw(st.text(st.characters(blacklist_categories=("Cs",)), max_size=4)) + text[j:]
        return text

    raw = st.text(st.characters(blacklist_categories=("Cs",)), max_size=80)

    @st.composite
    def document(draw):
        # weights by repetition: mostly structured documents, so valid scenes are reached too
        kind = draw(st.sampled_from(("valid", "mutated", "mutated", "mutated", "edited", "raw")))
        if kind == "valid":
            return toml_document(VALID_DOC)
        return draw({"mutated": mutated(), "edited": edited(), "raw": raw}[kind])

    meshes = ("quad",) * (len(MESH_FILES) - 1) + tuple(sorted(MESH_FILES))
    return st.tuples(document(), st.sampled_from(meshes))


def run_fuzz(examples: int, workdir: Path, seed: int = 0) -> dict:
    """Run the property on `examples` generated documents. Returns {"examples", "scenes", "errors",
    "failure": None or the shrunk failing case and what went wrong}."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import seed as hypothesis_seed
    from hypothesis.reporting import with_reporter

    counts = {"scene": 0, "error": 0}
    last: dict = {}

    @hypothesis_seed(seed)
    @settings(max_examples=int(examples), database=None, deadline=None, print_blob=False,
              suppress_health_check=list(HealthCheck))
    @given(case=scene_documents())
    def prop(case):
        text, mesh = case
        last["case"] = case
        counts[check_document(text, mesh, workdir)] += 1

    failure = None
    with with_reporter(lambda _msg: None):
        try:
            prop()
        except FuzzFailure as exc:
            text, mesh = last.get("case", ("", ""))
            failure = {"problem": str(exc), "document": text, "mesh": mesh}
    return {"examples": int(examples), "scenes": counts["scene"], "errors": counts["error"], "failure": failure}
