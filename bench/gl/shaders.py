"""Shader loading: one `.glsl` file per program, stages behind `#if defined <STAGE>_SHADER`.

`#include "name.glsl"` is resolved relative to the including file, then in
`bench/gl/shaders/`; each file is included once. Constants reach GLSL only as injected
`#define`s (`defines=`) or uniforms, so a value is never written in both languages; the
injector writes 0 and False as `0` (never drops them).
"""
from __future__ import annotations

import re
from pathlib import Path

import moderngl
import numpy as np

from .context import GLError

SHARED_SHADER_DIR = Path(__file__).parent / "shaders"
GLSL_VERSION = "#version 450 core"

_STAGES = {
    "vertex_shader": "VERTEX_SHADER",
    "tess_control_shader": "TESS_CONTROL_SHADER",
    "tess_evaluation_shader": "TESS_EVALUATION_SHADER",
    "geometry_shader": "GEOMETRY_SHADER",
    "fragment_shader": "FRAGMENT_SHADER",
}
_INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"\s*$', re.M)

# Binding points shared by the GL core and methods, injected into every program.
GLOBAL_DEFINES = {
    "BINDING_TRIANGLE_ALBEDO": 0,
    "BINDING_LIGHTS": 1,
    "BINDING_SHADOW_LAYERS": 2,
    "PI": np.pi,
    "INV_PI": 1.0 / np.pi,
}


def glsl_literal(value) -> str:
    """A GLSL literal for a Python value (bool -> 0/1, int, float with a decimal point)."""
    if isinstance(value, (bool, np.bool_)):
        return "1" if value else "0"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        v = float(value)
        if not np.isfinite(v):
            raise GLError(f"cannot inject non-finite float {v} into GLSL")
        text = repr(v)
        if "e" not in text and "." not in text:
            text += ".0"
        return text
    if isinstance(value, str):
        return value
    raise GLError(f"cannot inject {type(value).__name__} value {value!r} as a GLSL #define")


def define_block(defines: dict | None) -> str:
    merged = dict(GLOBAL_DEFINES)
    merged.update(defines or {})
    lines = []
    for name, value in merged.items():
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
            raise GLError(f"invalid #define name {name!r}")
        lines.append(f"#define {name} {glsl_literal(value)}")
    return "\n".join(lines) + "\n"


def expand_includes(path: Path, seen: set | None = None) -> str:
    path = Path(path)
    if not path.is_file():
        raise GLError(f"shader file not found: {path}")
    seen = set() if seen is None else seen
    seen.add(path.resolve())
    text = path.read_text()

    def replace(match):
        name = match.group(1)
        for base in (path.parent, SHARED_SHADER_DIR):
            candidate = (base / name).resolve()
            if candidate.is_file():
                if candidate in seen:
                    return ""
                return expand_includes(candidate, seen) + "\n"
        raise GLError(f"{path.name}: #include \"{name}\" not found next to it or in {SHARED_SHADER_DIR}")

    return _INCLUDE.sub(replace, text)


def stage_sources(path: Path, defines: dict | None = None) -> dict:
    """Per-stage complete sources (moderngl keyword -> source) for a .glsl program file."""
    body = expand_includes(path)
    header = GLSL_VERSION + "\n" + define_block(defines)
    out = {}
    for keyword, macro in _STAGES.items():
        if re.search(rf"\b{macro}\b", body):
            out[keyword] = header + f"#define {macro}\n#line 1\n" + body
    if not out:
        raise GLError(f"{path}: no shader stage found (expected `#if defined VERTEX_SHADER` ...)")
    return out


def load_program(ctx: moderngl.Context, path, defines: dict | None = None, varyings=(),
                 varyings_capture_mode: str = "interleaved") -> moderngl.Program:
    """Compile and link the program in `path` with the given #defines."""
    path = Path(path)
    sources = stage_sources(path, defines)
    try:
        prog = ctx.program(**sources, varyings=tuple(varyings), varyings_capture_mode=varyings_capture_mode)
    except Exception as exc:
        raise GLError(f"{path.name}: {exc}") from None
    return prog


def load_compute(ctx: moderngl.Context, path, defines: dict | None = None) -> moderngl.ComputeShader:
    path = Path(path)
    body = expand_includes(path)
    src = GLSL_VERSION + "\n" + define_block(defines) + "#define COMPUTE_SHADER\n#line 1\n" + body
    try:
        return ctx.compute_shader(src)
    except Exception as exc:
        raise GLError(f"{path.name}: {exc}") from None


def has_member(prog, name: str) -> bool:
    """True if the program (or compute shader) has an active uniform/attribute `name`."""
    return prog.get(name, None) is not None


def set_uniforms(prog, **values) -> None:
    """Set the uniforms the program actually uses (the compiler drops unused ones)."""
    for name, value in values.items():
        member = prog.get(name, None)
        if member is None:
            continue
        if isinstance(value, np.ndarray):
            if value.dtype.kind in "iu":
                member.write(np.ascontiguousarray(value).astype(value.dtype).tobytes())
            else:
                # GLSL matrices are column-major: numpy row-major M is written as M.T
                arr = value.T if value.ndim == 2 else value
                member.write(np.ascontiguousarray(arr, dtype=np.float32).tobytes())
        else:
            member.value = value
