"""Per-stage GPU timing with GL timer queries.

GL allows one active GL_TIME_ELAPSED query at a time, so stages never nest. Queries are read
after the frame (`collect()`), never inside a timed region, because reading one blocks.
"""
from __future__ import annotations

from contextlib import contextmanager

import moderngl


class StageProfiler:
    def __init__(self, ctx: moderngl.Context, stages: tuple = ()):
        self.ctx = ctx
        self.declared = tuple(stages)
        self._queries: dict[str, list] = {}  # stage -> pool of queries, reused frame to frame
        self._used: list[tuple[str, int]] = []
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
        pool = self._queries.setdefault(name, [])
        slot = sum(1 for used, _ in self._used if used == name)
        if slot == len(pool):
            pool.append(self.ctx.query(time=True))
        query = pool[slot]
        self._active = name
        try:
            with query:
                yield
        finally:
            self._active = None
        self._used.append((name, slot))

    def begin_frame(self) -> None:
        self._used = []

    def collect(self) -> dict[str, float]:
        """Milliseconds per stage used in this frame (sums a stage entered several times)."""
        out: dict[str, float] = {}
        for name, slot in self._used:
            out[name] = out.get(name, 0.0) + self._queries[name][slot].elapsed / 1e6
        return out

    def release(self) -> None:
        # moderngl Query objects have no release(); dropping them lets moderngl free them.
        self._queries.clear()
