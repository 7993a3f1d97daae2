"""GL core: the headless context factory, shader loader, GPU scene and shared passes.

Knows no method. Entry points:
  create_context() -> moderngl.Context         (the only place a context is created)
  GpuScene(ctx, scene, seed)                   (buffers; .view(camera, w, h) -> View)
  SharedPasses(gpu, view, needs)               (gbuffer, shadow_map, direct, rsm)
  StageProfiler(ctx, stages)                   (per-stage GPU timer queries)
  render_gbuffer / render_direct               (one-shot conveniences for tests and calibration)
"""
from .context import GLError, check_gl, create_context, gl_info
from .gpu_scene import GpuScene
from .passes import (Frame, SharedPasses, frame_random, read_rgb, read_rgba, render_direct,
                     render_gbuffer, SHARED_STAGES)
from .profiler import StageProfiler
from .shaders import load_compute, load_program, set_uniforms

__all__ = ["GLError", "check_gl", "create_context", "gl_info", "GpuScene", "Frame", "SharedPasses",
           "frame_random", "read_rgb", "read_rgba", "render_direct", "render_gbuffer", "SHARED_STAGES",
           "StageProfiler", "load_compute", "load_program", "set_uniforms"]
