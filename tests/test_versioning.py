"""A method's version is a hash of the code its images depend on (its folder, the gibench modules
and shaders it reaches, transitively, and the GL core), never of prose (issue #22)."""
from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

from bench.protocol import versioning
from bench.protocol.registry import load_method
from bench.protocol.versioning import code_files, glsl_code, method_version, python_code

ROOT = Path(__file__).resolve().parent.parent
VPL_RECORDS = ROOT / "bench/gl/shaders/vpl_records.glsl"


def test_python_prose_is_not_code():
    code = 'import math\n\n\ndef area(r):\n    """Area of a disc."""\n    return math.pi * r * r  # pi r^2\n'
    prose = ('"""A module docstring."""\nimport math\n# a comment\n\ndef area(r):\n    """Another docstring,\n'
             '    two lines."""\n\n    return math.pi * r * r\n')
    assert python_code(code) == python_code(prose)
    assert python_code(code) != python_code(code.replace("r * r", "r ** 2"))
    assert python_code(code) != python_code(code.replace('"""Area of a disc."""', 'x = "Area of a disc."'))


def test_glsl_prose_is_not_code():
    a = "// header\nfloat f(float x) {\n    return x * 2.0; /* twice */\n}\n"
    b = "float f(float x)\n{\n  return x * 2.0;\n}\n/* a longer\n   comment */\n"
    assert glsl_code(a).replace("\n", " ").split() != glsl_code(a.replace("2.0", "3.0")).replace("\n", " ").split()
    assert glsl_code(a) == glsl_code("float f(float x) {\nreturn x * 2.0;\n}")
    assert glsl_code(b).split() == glsl_code(a).split()


@pytest.mark.parametrize("method", ["ir_unshadowed", "ir_shadowed", "val_clustered", "visibility_gates"])
def test_vpl_methods_depend_on_the_shared_vpl_code(method):
    files = set(code_files(load_method(method)))
    assert VPL_RECORDS in files and ROOT / "bench/gl/vpl.py" in files
    assert ROOT / "bench/protocol/method.py" in files          # imported: Param, MethodBase
    assert not any(p.suffix == ".md" for p in files)


def _plugin(tmp_path, monkeypatch):
    """A method package outside gibench's folders whose image code reaches a sibling package: a
    Python module it imports and a shader its shader includes through a relative path."""
    pkg = tmp_path / "plugpkg"
    (pkg / "helpers" / "shaders").mkdir(parents=True)
    (pkg / "mymethod" / "shaders").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "helpers" / "__init__.py").write_text("")
    (pkg / "helpers" / "weights.py").write_text('"""Weights."""\nSCALE = 2.0  # doubled\n')
    (pkg / "helpers" / "shaders" / "shared.glsl").write_text("// shared\nfloat shared_scale() { return 2.0; }\n")
    (pkg / "mymethod" / "__init__.py").write_text("")
    (pkg / "mymethod" / "shaders" / "main.glsl").write_text('#include "../../helpers/shaders/shared.glsl"\n'
                                                            "void main() {}\n")
    (pkg / "mymethod" / "method.py").write_text(
        '"""mymethod: the manual."""\nfrom bench.protocol.method import MethodBase\n'
        "from plugpkg.helpers.weights import SCALE\n\n\nclass My(MethodBase):\n"
        '    """The class."""\n    name = "mymethod"\n    scale = SCALE\n')
    (pkg / "mymethod" / "README.md").write_text("# mymethod\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in [m for m in sys.modules if m.startswith("plugpkg")]:
        del sys.modules[name]

    def version():
        for name in [m for m in sys.modules if m.startswith("plugpkg")]:
            del sys.modules[name]
        importlib.invalidate_caches()
        return method_version(importlib.import_module("plugpkg.mymethod.method").My)
    return pkg, version


def test_version_follows_imported_modules_and_included_shaders(tmp_path, monkeypatch):
    pkg, version = _plugin(tmp_path, monkeypatch)
    v0 = version()
    shader = pkg / "helpers" / "shaders" / "shared.glsl"
    shader.write_text(shader.read_text().replace("2.0", "3.0"))
    v1 = version()
    assert v1 != v0                                           # an included shader outside the folder
    weights = pkg / "helpers" / "weights.py"
    weights.write_text(weights.read_text().replace("2.0", "4.0"))
    v2 = version()
    assert v2 != v1                                           # an imported module outside the folder


def test_version_ignores_prose(tmp_path, monkeypatch):
    pkg, version = _plugin(tmp_path, monkeypatch)
    v0 = version()
    method = pkg / "mymethod" / "method.py"
    method.write_text(method.read_text().replace("the manual.", "the manual, rewritten\n\nwith a table.")
                      .replace("The class.", "The class, described.") + "# a closing comment\n")
    (pkg / "mymethod" / "README.md").write_text("# mymethod\n\nmore words\n")
    (pkg / "mymethod" / "NOTES.md").write_text("measured: 1.0\n")
    shader = pkg / "helpers" / "shaders" / "shared.glsl"
    shader.write_text("/* a comment */\n" + shader.read_text() + "\n// another\n")
    assert version() == v0


def _edited(path: Path, edit):
    real = versioning.read_source

    def read(p):
        text = real(p)
        return edit(text) if Path(p).resolve() == path.resolve() else text
    return read


def test_runner_rerenders_after_a_shared_vpl_shader_edit_and_not_after_a_docstring_edit(tmp_path, monkeypatch):
    """The row cache keys on the method version: an edit to the VPL records shader that val_clustered
    includes from bench/gl re-renders its row; an edit to its manual alone renders nothing."""
    from bench.run.config import RunConfig
    from bench.run.serial import run
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))

    def once(out):
        cfg = RunConfig(scenes=["cornell_spot"], methods=["val_clustered"], width=32, height=24, frames=1, warmup=1,
                        out=tmp_path / out, references=False, progress=False)
        _, runner = run(cfg, log=lambda m: None)
        return runner.counts

    assert once("first")["ok"] == 1
    assert once("again")["cached"] == 1
    monkeypatch.setattr(versioning, "read_source", _edited(VPL_RECORDS, lambda t: t + "\n#define GIBENCH_EDIT 1\n"))
    assert once("shader-edited")["ok"] == 1
    monkeypatch.undo()
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))
    manual = ROOT / "methods/val_clustered/method.py"
    monkeypatch.setattr(versioning, "read_source",
                        _edited(manual, lambda t: t.replace('"""', '"""An edited first line of the manual.\n', 1)))
    assert versioning.read_source(manual).startswith('"""An edited')
    assert once("manual-edited")["cached"] == 1


def test_harness_version_ignores_prose(monkeypatch):
    v0 = versioning.harness_version()
    harness = ROOT / "bench/run/harness.py"
    monkeypatch.setattr(versioning, "read_source", _edited(harness, lambda t: t + "\n# a comment\n"))
    assert versioning.harness_version() == v0
    monkeypatch.setattr(versioning, "read_source", _edited(harness, lambda t: t + "\nEDITED = 1\n"))
    assert versioning.harness_version() != v0
