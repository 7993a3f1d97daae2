"""Per-stage timing: GL timer queries on a GPU, finish-fenced wall time on software GL.

GL allows one active GL_TIME_ELAPSED query at a time, so stages never nest. Queries are read
after the frame (`collect()`), never inside a timed region, because reading one blocks.

Mesa's llvmpipe answers timer queries from its rasteriser threads only: vertex, tessellation
and geometry work runs in the draw call on the submitting thread and is not counted (a
geometry-shader pass over 1M triangles reads 0.2 ms by query and 125 ms by glFinish wall time).
On a software renderer each stage is therefore timed as CPU wall time between two
`ctx.finish()` calls (clock `finish_wall`), which is exact there because the "GPU" is the CPU.
On a hardware GPU the default is the timer query (clock `gl_query`), which adds no sync.
`GIBENCH_STAGE_CLOCK=gl_query|finish_wall` overrides the choice; the clock used is recorded.
"""
from __future__ import annotations

import os
import time
from contextlib import contextmanager

import moderngl

CLOCKS = ("gl_query", "finish_wall")
SOFTWARE_RENDERERS = ("llvmpipe", "softpipe", "swrast", "lavapipe")


def default_clock(ctx: moderngl.Context) -> str:
    forced = os.environ.get("GIBENCH_STAGE_CLOCK", "").strip()
    if forced:
        if forced not in CLOCKS:
            raise ValueError(f"GIBENCH_STAGE_CLOCK={forced!r} not one of {list(CLOCKS)}")
        return forced
    renderer = str(ctx.info.get("GL_RENDERER", "")).lower()
    return "finish_wall" if any(s in renderer for s in SOFTWARE_RENDERERS) else "gl_query"


class StageProfiler:
    def __init__(self, ctx: moderngl.Context, stages: tuple = (), clock: str | None = None):
        self.ctx = ctx
        self.declared = tuple(stages)
        self.clock = clock or default_clock(ctx)
        if self.clock not in CLOCKS:
            raise ValueError(f"stage clock {self.clock!r} not one of {list(CLOCKS)}")
        self._queries: dict[str, list] = {}  # stage -> pool of queries, reused frame to frame
        self._used: list[tuple[str, int]] = []
        self._wall_ms: list[tuple[str, float]] = []
        self._active: str | None = None
        self.enabled = True

    @contextmanager
    def stage(self, name: str):
        if self.declared and name not in self.declared:
            raise ValueError(f"stage '{name}' is not declared (declared: {list(self.declared)})")
        if self._active is not None:
            raise RuntimeError(f"stage '{name}' started inside stage '{self._active}': GL timer queries cannot nest")
        if not self.enabled:
            yield
            return
        self._active = name
        if self.clock == "finish_wall":
            self.ctx.finish()  # earlier work must not be billed to this stage
            t0 = time.perf_counter()
            try:
                yield
                self.ctx.finish()
            finally:
                self._active = None
            self._wall_ms.append((name, (time.perf_counter() - t0) * 1e3))
            return
        pool = self._queries.setdefault(name, [])
        slot = sum(1 for used, _ in self._used if used == name)
        if slot == len(pool):
            pool.append(self.ctx.query(time=True))
        query = pool[slot]
        try:
            with query:
                yield
        finally:
            self._active = None
        self._used.append((name, slot))

    def begin_frame(self) -> None:
        self._used = []
        self._wall_ms = []

    def collect(self) -> dict[str, float]:
        """Milliseconds per stage used in this frame (sums a stage entered several times)."""
        out: dict[str, float] = {}
        for name, slot in self._used:
            out[name] = out.get(name, 0.0) + self._queries[name][slot].elapsed / 1e6
        for name, ms in self._wall_ms:
            out[name] = out.get(name, 0.0) + ms
        return out

    def release(self) -> None:
        # moderngl Query objects have no release(); dropping them lets moderngl free them.
        self._queries.clear()
