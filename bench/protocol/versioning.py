"""Versions of code: a method's version is a hash of the code its images depend on, so results of
edited code are never compared as if equal, and results of unedited code are never thrown away.

`method_version(cls)` hashes, each file by its path relative to its root and its normalised text:

* every `.py`, `.glsl`, `.toml` and `.json` file of the method's folder;
* every Python module those import, transitively, that lives in the method's own package tree
  or in gibench's source tree (`bench/`, `methods/`: a method that imports another method's
  module depends on it); third-party and standard-library modules are the environment, not the
  method's code;
* every shader those shaders `#include`, transitively, resolved as the loader resolves it
  (beside the including file, then `bench/gl/shaders/`);
* the whole GL core, `bench/gl/` (the shared passes every method reads).

Prose is not code: Python files are hashed as their token stream without comments, docstrings
or blank lines (so a manual in a docstring, a comment or a re-wrapped line changes nothing),
GLSL without comments and with white space folded; README.md and NOTES.md are not read.
`harness_version()` hashes the timing harness the same way (bench/run/harness.py and what it
imports from gibench, the GL core excluded: a method's version covers it).
"""
from __future__ import annotations

import ast
import hashlib
import importlib
import importlib.util
import io
import re
import subprocess
import tokenize
from pathlib import Path

_HASHED_SUFFIXES = {".py", ".glsl", ".toml", ".json"}
BENCH_DIR = Path(__file__).resolve().parent.parent          # bench/
SOURCE_ROOT = BENCH_DIR.parent                               # the checkout: bench/, methods/, ...
GL_CORE = BENCH_DIR / "gl"
SHARED_SHADER_DIR = GL_CORE / "shaders"
_INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"\s*$', re.M)
_GLSL_COMMENT = re.compile(r"//[^\n]*|/\*.*?\*/", re.S)


def read_source(path: Path) -> str:
    """The text of a source file (one place, so tests can present an edited file)."""
    return Path(path).read_text(encoding="utf-8", errors="replace")


# ---------------------------------------------------------------------------- normalised text
def _docstring_positions(tree: ast.AST) -> set:
    """(line, column) where each docstring expression starts."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = getattr(node, "body", [])
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
                    and isinstance(body[0].value.value, str):
                out.add((body[0].lineno, body[0].col_offset))
    return out


def python_code(text: str) -> str:
    """A Python file's tokens without comments, docstrings, blank lines or layout inside a line."""
    try:
        docstrings = _docstring_positions(ast.parse(text))
        tokens = list(tokenize.generate_tokens(io.StringIO(text).readline))
    except (SyntaxError, tokenize.TokenError, IndentationError):
        return text   # not Python we can read: hash it as it is
    out = []
    skip_line = None
    for tok in tokens:
        if tok.type in (tokenize.COMMENT, tokenize.NL, tokenize.ENCODING):
            continue
        if tok.type == tokenize.STRING and tok.start in docstrings:
            skip_line = tok.end[0]   # the docstring's statement ends with its NEWLINE
            continue
        if tok.type == tokenize.NEWLINE and skip_line is not None:
            skip_line = None
            continue
        if tok.type in (tokenize.INDENT, tokenize.DEDENT):
            out.append(tok.type == tokenize.INDENT and "<indent>" or "<dedent>")
            continue
        out.append(tok.string if tok.type != tokenize.NEWLINE else "\n")
    return " ".join(out)


def glsl_code(text: str) -> str:
    """A shader's text without comments, white space folded, blank lines dropped."""
    text = _GLSL_COMMENT.sub(" ", text)
    lines = (" ".join(line.split()) for line in text.splitlines())
    return "\n".join(line for line in lines if line)


_MEMO: dict = {}


def _memo(kind: str, path: Path, compute):
    """`compute(path)` memoised on the file's size and mtime (and on the reader, replaced in tests):
    the runner asks for a version per row, and the files rarely change within a process."""
    try:
        st = path.stat()
        key = (kind, str(path), st.st_mtime_ns, st.st_size, id(read_source))
    except OSError:
        return compute(path)
    if key not in _MEMO:
        _MEMO[key] = compute(path)
    return _MEMO[key]


def _normalised(path: Path) -> str:
    text = read_source(path)
    if path.suffix == ".py":
        return python_code(text)
    if path.suffix == ".glsl":
        return glsl_code(text)
    return text


def normalised(path: Path) -> str:
    return _memo("text", Path(path), _normalised)


# ---------------------------------------------------------------------------- what code depends on
def _module_file(name: str) -> Path | None:
    """The file of module `name` without importing it (None: not found, or a namespace)."""
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError, AttributeError):
        return None
    if spec is None or not spec.origin or spec.origin in ("built-in", "frozen"):
        return None
    return Path(spec.origin).resolve()


def _imported_modules(path: Path, package: str) -> set[str]:
    """Absolute names of the modules a Python file imports (relative imports resolved; `from X import
    Y` counts X and, where Y is a submodule, X.Y)."""
    return _memo(f"imports:{package}", Path(path), lambda p: _parse_imports(p, package))


def _parse_imports(path: Path, package: str) -> set[str]:
    try:
        tree = ast.parse(read_source(path))
    except SyntaxError:
        return set()
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[:len(parts) - node.level + 1]) if node.level <= len(parts) else ""
                module = f"{base}.{node.module}" if node.module else base
            else:
                module = node.module or ""
            if module:
                names.add(module)
                names.update(f"{module}.{alias.name}" for alias in node.names)
    return names


def _module_name(path: Path, roots: tuple) -> tuple[str, str] | None:
    """(module name, its package) of a file under one of `roots` (each a folder holding packages)."""
    for root in roots:
        try:
            rel = path.relative_to(root)
        except ValueError:
            continue
        parts = list(rel.with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        if is_package:
            parts = parts[:-1]
        name = ".".join(parts)
        return name, name if is_package else ".".join(parts[:-1])
    return None


def _included_shaders(path: Path) -> list[Path]:
    return _memo("includes", Path(path), _parse_includes)


def _parse_includes(path: Path) -> list[Path]:
    out = []
    for name in _INCLUDE.findall(read_source(path)):
        for base in (path.parent, SHARED_SHADER_DIR):
            candidate = (base / name).resolve()
            if candidate.is_file():
                out.append(candidate)
                break
    return out


def code_files(method_cls) -> list[Path]:
    """Every file a method's images depend on (see the module docstring), sorted."""
    module = importlib.import_module(method_cls.__module__)
    folder = Path(module.__file__).resolve().parent
    top = importlib.import_module(method_cls.__module__.split(".")[0])
    package_root = Path(top.__file__).resolve().parent.parent   # the folder holding the method's top package
    roots = tuple(dict.fromkeys((SOURCE_ROOT, package_root)))
    within = tuple(dict.fromkeys((SOURCE_ROOT / "bench", SOURCE_ROOT / "methods", package_root / top.__name__)))
    files: set = set()
    todo = [p for p in folder.rglob("*") if p.is_file() and p.suffix in _HASHED_SUFFIXES
            and "__pycache__" not in p.parts]
    todo += [p for p in GL_CORE.rglob("*") if p.is_file() and p.suffix in _HASHED_SUFFIXES
             and "__pycache__" not in p.parts]
    while todo:
        path = todo.pop().resolve()
        if path in files:
            continue
        files.add(path)
        if path.suffix == ".glsl":
            todo += _included_shaders(path)
        elif path.suffix == ".py":
            named = _module_name(path, roots)
            for name in _imported_modules(path, named[1] if named else ""):
                dep = _module_file(name)
                if dep is not None and dep.suffix == ".py" and any(dep.is_relative_to(w) for w in within):
                    todo.append(dep)
                    if dep.name == "__init__.py":
                        continue
                    init = dep.parent / "__init__.py"   # importing a module runs its package's __init__
                    if init.is_file():
                        todo.append(init)
    return sorted(files)


def hash_files(files, roots=(SOURCE_ROOT,)) -> str:
    h = hashlib.sha256()
    for path in sorted(Path(p) for p in files):
        label = next((str(path.relative_to(r)) for r in roots if path.is_relative_to(r)), path.name)
        h.update(label.encode() + b"\0" + normalised(path).encode() + b"\0")
    return h.hexdigest()[:16]


def method_version(method_cls) -> str:
    """Hash of the code the method's images depend on (its folder, the gibench modules and shaders
    it reaches, the GL core), prose excluded."""
    return hash_files(code_files(method_cls))


def harness_version() -> str:
    """Hash of the timing harness: a change in how frames are timed invalidates cached rows."""
    harness = BENCH_DIR / "run" / "harness.py"
    files = {harness}
    for name in _imported_modules(harness, "bench.run"):
        dep = _module_file(name)
        if dep is not None and dep.suffix == ".py" and dep.is_relative_to(BENCH_DIR) \
                and not dep.is_relative_to(GL_CORE):
            files.add(dep)
    return hash_files(files)


def git_commit(cwd: Path | None = None) -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=cwd or Path(__file__).parent, capture_output=True,
                             text=True, timeout=10)
        commit = out.stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=cwd or Path(__file__).parent,
                               capture_output=True, text=True, timeout=10).stdout.strip()
        return (commit + ("-dirty" if dirty else "")) if commit else "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"
