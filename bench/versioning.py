"""Versions of code: a method's version is a hash of its sources and shaders, so results of
edited code are never compared as if equal."""
from __future__ import annotations

import hashlib
import importlib
import subprocess
from pathlib import Path

_HASHED_SUFFIXES = {".py", ".glsl", ".toml", ".json"}


def folder_hash(folder: Path, extra: tuple = ()) -> str:
    h = hashlib.sha256()
    files = sorted(p for p in Path(folder).rglob("*") if p.is_file() and p.suffix in _HASHED_SUFFIXES
                   and "__pycache__" not in p.parts)
    for p in list(files) + [Path(e) for e in extra]:
        h.update(str(p.relative_to(folder) if p.is_relative_to(folder) else p.name).encode())
        h.update(p.read_bytes())
    return h.hexdigest()[:16]


def method_version(method_cls) -> str:
    """Hash of the method's folder (sources + shaders) and of the shared GL core it runs on."""
    module = importlib.import_module(method_cls.__module__)
    folder = Path(module.__file__).parent
    gl_core = Path(__file__).parent / "gl"
    h = hashlib.sha256((folder_hash(folder) + folder_hash(gl_core)).encode())
    return h.hexdigest()[:16]


def harness_version() -> str:
    """Hash of the timing harness: a change in how frames are timed invalidates cached rows."""
    return hashlib.sha256((Path(__file__).parent / "harness.py").read_bytes()).hexdigest()[:16]


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
