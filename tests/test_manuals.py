"""Each parameter is documented once, in its Param declaration: the tables of the manuals and READMEs
are generated from the declarations and checked against them (bench.protocol.manual)."""
from __future__ import annotations

import sys
import types

import pytest

from bench.cli import main
from bench.protocol import manual
from bench.protocol.method import MethodBase, Param
from bench.protocol.registry import list_methods, load_method


@pytest.mark.parametrize("name", list_methods())
def test_every_manual_and_readme_table_matches_the_declarations(name):
    cls = load_method(name)
    assert manual.check(cls) == []
    table = manual.param_table(cls)
    for pname, p in cls.params.items():
        assert f"| {pname} " in table and manual.format_value(p.default) in table


def _fake_method(tmp_path, monkeypatch, doc_table: str, readme_table: str):
    folder = tmp_path / "fakepkg"
    folder.mkdir()
    source = folder / "method.py"
    source.write_text(f'"""fake: a manual.\n\n{doc_table}\n"""\n')
    (folder / "README.md").write_text(f"# fake\n\n{readme_table}\n")
    module = types.ModuleType("fakepkg.method")
    module.__file__ = str(source)
    monkeypatch.setitem(sys.modules, "fakepkg.method", module)

    class Fake(MethodBase):
        name = "fake"
        params = {"count": Param(16, "samples per pixel", 1, 4096), "mode": Param("a", "which way", choices=("a", "b"))}
    Fake.__module__ = "fakepkg.method"
    return Fake, source


def test_a_stale_table_is_found_and_rewritten(tmp_path, monkeypatch):
    stale = f"{manual.BEGIN}\n| parameter | default |\n| count | 8 |\n{manual.END}"
    cls, source = _fake_method(tmp_path, monkeypatch, stale, stale)
    problems = manual.check(cls)
    assert len(problems) == 2 and all("differs from the Param declarations" in p for p in problems)
    assert set(manual.write(cls)) == {source, source.parent / "README.md"}
    assert manual.check(cls) == []
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in source.read_text().splitlines()
            if line.startswith(("| count", "| mode"))]
    assert rows == [["count", "16", "1 .. 4096", "samples per pixel"], ["mode", "a", "a, b", "which way"]]


def test_a_missing_table_is_reported(tmp_path, monkeypatch):
    cls, _ = _fake_method(tmp_path, monkeypatch, "no table here", "nor here")
    assert [p.split(":")[1].strip().split()[0] for p in manual.check(cls)] == ["the", "README.md"]
    assert manual.write(cls) == []   # no markers: nothing to replace


def test_stress_limit_lines_are_read_once():
    text = ("Stress limit params:n=4096: over the case timeout (a: b)\n"
            "  - Stress limit translate=*: float32 positions\nnot a Stress limit line\n")
    assert manual.stress_limits(text) == {"params:n=4096": "over the case timeout (a: b)",
                                          "translate=*": "float32 positions"}


def test_manuals_command_checks_every_method(capsys):
    assert main(["manuals"]) == 0
    assert capsys.readouterr().err == ""
