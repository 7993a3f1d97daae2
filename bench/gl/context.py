"""The one headless OpenGL context factory, and GL error checking.

Every GL context in gibench comes from `create_context()`: EGL (Mesa llvmpipe on a machine
without a GPU, the vendor driver on one with a GPU), core profile 4.5. An EGL context has no
default framebuffer, so nothing may draw before binding an FBO; moderngl does not raise on
GL errors during draws, so callers check with `check_gl`.
"""
from __future__ import annotations

import moderngl

GL_REQUIRED_VERSION = 450


# Mesa's llvmpipe silently stops a shader invocation after 65535 loop iterations in total,
# counting every loop of the invocation together (gallivm's loop limiter; measured: a loop of
# 70000 runs 65535 times, and nested 256 x 256 loops run 65027). A shader loop over an
# unbounded number of items (VPLs, triangles) is therefore split across draws of at most
# LOOP_CHUNK items each, leaving head-room for the shader's other loops. Harmless on a GPU.
LOOP_CHUNK = 16384


def loop_chunks(count: int, chunk: int = LOOP_CHUNK):
    """(first, end) item ranges of at most `chunk` items covering range(count)."""
    return [(first, min(count, first + chunk)) for first in range(0, int(count), int(chunk))]


class GLError(RuntimeError):
    """A GL error reported by glGetError after an operation."""


_contexts: list = []


def create_context(shared: bool = True) -> moderngl.Context:
    """Return the process's headless GL 4.5 context (created on first use).

    `shared=False` creates a fresh one (tests that need isolation); the caller releases it.
    """
    if shared and _contexts:
        return _contexts[0]
    try:
        ctx = moderngl.create_standalone_context(backend="egl", require=GL_REQUIRED_VERSION)
    except Exception as exc:  # moderngl raises plain Exception for EGL failures
        raise GLError(
            f"cannot create a headless OpenGL {GL_REQUIRED_VERSION // 100}.{GL_REQUIRED_VERSION % 100 // 10} "
            f"EGL context ({exc}); install libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1") from None
    if shared:
        _contexts.append(ctx)
    return ctx


def check_gl(ctx: moderngl.Context, what: str) -> None:
    """Raise GLError naming `what` if the context has a pending GL error."""
    err = ctx.error
    if err != "GL_NO_ERROR":
        raise GLError(f"GL error {err} after {what}")


def gl_info(ctx: moderngl.Context) -> dict:
    info = ctx.info
    return {"gl_renderer": info.get("GL_RENDERER", ""), "gl_version": info.get("GL_VERSION", ""),
            "gl_vendor": info.get("GL_VENDOR", "")}


def park(ctx: moderngl.Context) -> None:
    """Bind a private 1x1 framebuffer. Call before releasing framebuffers: moderngl re-binds
    `ctx.fbo` (the last used one) when creating a framebuffer, and re-binding a deleted one
    raises GL_INVALID_OPERATION. The EGL context has no default framebuffer to fall back to."""
    fbo = ctx.extra.get("gibench_parking_fbo") if ctx.extra else None
    if fbo is None:
        if ctx.extra is None:
            ctx.extra = {}
        tex = ctx.texture((1, 1), 4)
        fbo = ctx.framebuffer([tex])
        ctx.extra["gibench_parking_fbo"] = fbo
    fbo.use()
