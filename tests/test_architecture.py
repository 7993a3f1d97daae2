"""The house's rules, checked from the code's own imports (DESIGN.md, "Layout").

Every Python file outside tests/ is parsed (imports anywhere in a file count, also inside
functions); an import of a gibench module becomes an edge from the file to the file that defines
the imported module.
"""
from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("bench", "methods", "reference", "reports", "studies")
MAX_LINES = 600


def _source_files() -> list[Path]:
    files = [p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py") if "__pycache__" not in p.parts]
    return sorted(files + sorted((ROOT / "scripts").glob("*.py")))


def _module_of(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _file_of(module: str) -> Path | None:
    base = ROOT.joinpath(*module.split("."))
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def _imports(path: Path) -> set[str]:
    """gibench modules a file imports (`from a import b` is module a.b when b is one, else a)."""
    module = _module_of(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - node.level + 1]
                origin = ".".join(base + ([node.module] if node.module else []))
            else:
                origin = node.module or ""
            names = [f"{origin}.{a.name}" if _file_of(f"{origin}.{a.name}") else origin for a in node.names]
        else:
            continue
        out.update(n for n in names if n.split(".")[0] in PACKAGES and _file_of(n) is not None)
    return out


@pytest.fixture(scope="module")
def graph() -> dict:
    return {_module_of(p): _imports(p) for p in _source_files()}


def _violations(graph: dict, where: str, allowed=None, forbidden=()) -> list[str]:
    """Imports of modules under `where` that leave `allowed` (prefixes) or enter `forbidden`."""
    out = []
    for module, deps in graph.items():
        if module != where and not module.startswith(where + "."):
            continue
        for dep in sorted(deps):
            inside = lambda prefixes: any(dep == p or dep.startswith(p + ".") for p in prefixes)
            if (allowed is not None and not inside(allowed)) or inside(forbidden):
                out.append(f"{module} imports {dep}")
    return out


def test_no_import_cycles(graph):
    names = sorted(graph)
    index = {n: i for i, n in enumerate(names)}
    edges = [(index[a], index[b]) for a, deps in graph.items() for b in deps if b in index and b != a]
    rows, cols = zip(*edges)
    adjacency = coo_matrix((np.ones(len(edges)), (rows, cols)), shape=(len(names), len(names)))
    count, labels = connected_components(adjacency, directed=True, connection="strong")
    cycles = [sorted(names[i] for i in np.flatnonzero(labels == k)) for k in range(count)
              if np.count_nonzero(labels == k) > 1]
    assert cycles == [], f"import cycles: {cycles}"


def test_methods_import_only_the_protocol_the_gl_core_and_the_scene_model(graph):
    bad = []
    for module in {m.split(".")[1] for m in graph if m.startswith("methods.") and m.count(".") >= 1}:
        bad += _violations(graph, f"methods.{module}",
                           allowed=("bench.protocol", "bench.gl", "bench.model", f"methods.{module}"))
    assert bad == []


def test_layers(graph):
    bad = []
    bad += _violations(graph, "bench.model", allowed=("bench.model",))                    # knows no GPU, no method
    bad += _violations(graph, "bench.protocol", allowed=("bench.protocol",))
    bad += _violations(graph, "bench.gl", allowed=("bench.gl", "bench.model", "bench.protocol.vocabulary"))  # no method
    bad += _violations(graph, "reference", allowed=("reference", "bench.model", "bench.protocol.vocabulary"))
    bad += _violations(graph, "bench.run", forbidden=("reports", "methods", "bench.stress", "bench.cli"))
    bad += _violations(graph, "bench.stress", forbidden=("reports", "methods", "bench.cli"))
    bad += _violations(graph, "bench.analysis", forbidden=("bench.run", "bench.gl", "bench.stress", "bench.cli",
                                                           "methods", "reports"))        # reads tables, runs nothing
    bad += _violations(graph, "bench.gate", forbidden=("bench.run", "bench.gl", "bench.stress", "bench.cli",
                                                       "methods", "reports"))
    bad += _violations(graph, "reports", forbidden=("bench.run", "bench.gl", "bench.stress", "bench.cli", "methods",
                                                    "reference"))                        # never renders
    bad += _violations(graph, "bench.history", forbidden=("bench.run", "bench.gl", "bench.stress", "bench.cli",
                                                          "methods", "reports"))         # reads run folders
    bad += _violations(graph, "bench.kit", forbidden=("reports", "methods", "bench.cli", "bench.stress"))
    assert bad == []


def test_no_source_file_is_longer_than_the_limit():
    long = {str(p.relative_to(ROOT)): n for p in _source_files()
            if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert long == {}, f"files over {MAX_LINES} lines: {long}"


def test_the_rules_see_a_violation(tmp_path):
    """The checks read real imports: a method importing the runner is caught."""
    graph = {"methods.x.method": {"bench.run.serial", "bench.gl.passes"}, "bench.run.serial": set()}
    assert _violations(graph, "methods.x", allowed=("bench.protocol", "bench.gl", "bench.model", "methods.x")) \
        == ["methods.x.method imports bench.run.serial"]
