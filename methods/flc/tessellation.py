"""Measure the GL tessellator once per context: the largest sub-triangle area, as a fraction of
the patch's area, for every uniform level 1..64 of the `triangles, equal_spacing` domain.

The divergent pass of FLC needs every piece of a tessellated divergent triangle to be regular
(area <= S_bar_N). The concentric-ring pattern of GL's triangle tessellation gives pieces of
unequal areas, and area ratios are affine invariant, so one measurement per level (a probe
program whose geometry shader records each piece's area fraction in a storage buffer) tells the
tessellation control shader which level suffices for any patch.
"""
from __future__ import annotations

from pathlib import Path

import moderngl
import numpy as np

from bench.gl import check_gl, load_program
from bench.gl.context import park

SHADERS = Path(__file__).parent / "shaders"
MAX_TESS_LEVEL = 64  # GL_MAX_TESS_GEN_LEVEL's guaranteed minimum
PROBE_BINDING = 3


def measure_fmax(ctx: moderngl.Context, max_level: int = MAX_TESS_LEVEL) -> np.ndarray:
    """fmax[n - 1] = largest piece / patch area at uniform level n (cached on the context)."""
    key = f"flc_tess_fmax_{max_level}"
    if ctx.extra and key in ctx.extra:
        return ctx.extra[key]
    prog = load_program(ctx, SHADERS / "tess_probe.glsl",
                        {"TESS_MAX_LEVEL": max_level, "BINDING_PROBE": PROBE_BINDING})
    vao = ctx.vertex_array(prog, [])
    out = ctx.buffer(np.zeros(2 * max_level, dtype=np.uint32).tobytes())
    try:
        park(ctx)  # nothing is processed without a bound framebuffer
        ctx.patch_vertices = 3
        out.bind_to_storage_buffer(PROBE_BINDING)
        vao.render(moderngl.PATCHES, vertices=3, instances=max_level)
        ctx.memory_barrier()
        check_gl(ctx, "tessellation probe")
        data = np.frombuffer(out.read(), dtype=np.uint32).reshape(2, max_level)
    finally:
        for obj in (vao, out, prog):
            obj.release()
    fmax = data[0].view(np.float32).astype(np.float64)
    totals = data[1] / 16777216.0
    if np.any(fmax <= 0) or not np.allclose(totals, 1.0, atol=1e-3):
        raise RuntimeError(f"flc: tessellation probe pieces do not tile the patch "
                           f"(area sums {totals.min():.4f}..{totals.max():.4f})")
    if ctx.extra is None:
        ctx.extra = {}
    ctx.extra[key] = fmax
    return fmax
