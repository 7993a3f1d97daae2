"""The method protocol: what a GI method plugin implements, and the small types it uses.

A method never reads files, never times itself and never writes results: the runner does.
`prepare(gpu, scene, facts, params, view)` is untimed (allocations at the view's resolution,
precomputation); `render(frame, prof)` is timed. It receives a `Frame` (the shared GL passes already built for this view) and a `StageProfiler`
whose `stage(name)` context manager wraps each of its GPU stages in a timer query.

Shared passes are read-only: the runner renders a view's GBuffer, shadow maps, direct light and
RSM once and lends them to every method and rung of the view (their measured cost is added to
each method's frame time). A method must never write their textures, buffers or texture
parameters (no framebuffer, image binding or mipmap build on them). A method that has to
declares `reuses_shared_passes = False` and gets passes of its own, rendered in each frame.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np


class SkipRow(Exception):
    """Raised by a method's prepare() when the scene is outside what it handles by design
    (e.g. `manylights` above its triangle budget). The row is recorded as `skipped: <reason>`."""


class ParamError(ValueError):
    """A parameter value outside its declared range (one-line message naming method and parameter)."""


@dataclass(frozen=True)
class Param:
    """One knob of a method: default, inclusive range, documentation.

    `quality=True` marks the knobs a time-vs-error sweep turns (`sweep` lists the values).
    `choices` replaces the numeric range for string/enum parameters.
    """
    default: Any
    doc: str
    low: float | None = None
    high: float | None = None
    choices: tuple | None = None
    quality: bool = False
    sweep: tuple = ()

    def check(self, method: str, name: str, value):
        if self.choices is not None:
            if value not in self.choices:
                raise ParamError(f"method '{method}': parameter '{name}'={value!r} not one of {list(self.choices)}")
            return value
        if isinstance(self.default, bool):
            if not isinstance(value, (bool, np.bool_)):
                raise ParamError(f"method '{method}': parameter '{name}'={value!r} must be true or false")
            return bool(value)
        if isinstance(self.default, int) and not isinstance(self.default, bool):
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            if not isinstance(value, (int, np.integer)):
                raise ParamError(f"method '{method}': parameter '{name}'={value!r} must be an integer")
            value = int(value)
        elif isinstance(self.default, float):
            if not isinstance(value, (int, float, np.integer, np.floating)) or isinstance(value, bool):
                raise ParamError(f"method '{method}': parameter '{name}'={value!r} must be a number")
            value = float(value)
            if not np.isfinite(value):
                raise ParamError(f"method '{method}': parameter '{name}'={value!r} must be finite")
        if self.low is not None and value < self.low or self.high is not None and value > self.high:
            raise ParamError(f"method '{method}': parameter '{name}'={value!r} outside [{self.low}, {self.high}]")
        return value


def resolve_params(method_cls, overrides: dict | None) -> dict:
    """Defaults of `method_cls.params` updated by `overrides`, each value range-checked."""
    overrides = dict(overrides or {})
    unknown = sorted(set(overrides) - set(method_cls.params))
    if unknown:
        raise ParamError(f"method '{method_cls.name}': unknown parameter(s) {unknown}; known: {sorted(method_cls.params)}")
    out = {}
    for name, p in method_cls.params.items():
        out[name] = p.check(method_cls.name, name, overrides.get(name, p.default))
    return out


@dataclass
class FrameOutput:
    """What a method returns for one frame: linear RGB radiance, either numpy float32 HxWx3
    (row 0 at the top) or GL textures that the runner reads back outside the timed region.

    `direct` is usually the shared direct pass; `indirect` the method's one-bounce estimate.
    `skipped_stages` lists the stages this frame did not need (recorded as skipped).
    """
    direct: np.ndarray | None
    indirect: np.ndarray | None
    skipped_stages: tuple = ()
    extra: dict = field(default_factory=dict)

    @property
    def combined(self) -> np.ndarray:
        if self.direct is None:
            return self.indirect
        if self.indirect is None:
            return self.direct
        return self.direct + self.indirect


@runtime_checkable
class Method(Protocol):
    name: ClassVar[str]
    summary: ClassVar[str]
    stages: ClassVar[tuple]
    params: ClassVar[dict]
    needs: ClassVar[frozenset]

    def prepare(self, gpu, scene, facts, params: dict, view) -> None: ...

    def render(self, frame, prof) -> FrameOutput: ...

    def release(self) -> None: ...


class MethodBase:
    """Convenience base: empty params/stages/needs, no-op release. Subclasses set the ClassVars."""
    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    stages: ClassVar[tuple] = ()
    params: ClassVar[dict] = {}
    needs: ClassVar[frozenset] = frozenset()
    # Quality ladder: 3-5 parameter-override dicts ordered fast -> accurate, one of them {} (the
    # defaults). `gibench run` renders every rung (time-vs-error curve); empty = defaults only.
    ladder: ClassVar[tuple] = ()
    # True: the method only reads the shared passes, so the runner may lend it the view's passes,
    # rendered and measured once (bench.run.harness.SharedViewPasses). False: a method that writes
    # them gets passes of its own, rendered in each of its frames.
    reuses_shared_passes: ClassVar[bool] = True

    @classmethod
    def frames_identical(cls, params: dict) -> bool:
        """Whether every frame of a view gives the same image at these (resolved) parameters: no
        per-frame random stream, no temporal state. The error frames then render two frames, check
        them bit for bit (a false declaration fails the row) and count the rest as copies
        (bench.run.harness). False unless a method says so."""
        return False

    # Kinds of motion ("camera", "light", "geometry") this method cannot follow, with why: a
    # sequence that moves one of them skips its row with that reason (bench.run.sequence).
    cannot_follow: ClassVar[dict] = {}

    def update(self, gpu, scene, facts, params: dict, view, changes: frozenset) -> None:
        """Follow a scene in motion: `changes` ({"camera", "light", "geometry"}) moved since the last
        frame, and `gpu`, `scene`, `facts`, `view` are the new frame's. Called inside the frame's
        clock (its cost is the frame's). The default keeps nothing: release and prepare again, the
        honest cost of a method that precomputes for one state; a method that can do less (or keeps
        temporal state across frames) overrides it."""
        self.release()
        self.prepare(gpu, scene, facts, params, view)

    @classmethod
    def cost_terms(cls, params: dict, size) -> dict | None:
        """What a frame and the preparation of this method cost scales with, beyond the pixels and
        triangles every row has: {term: work count} from the resolved `params` and `size`
        (bench.protocol.cost.CostFacts), e.g. {"pixel_vpls": pixels x VPLs}. The run's cost model
        fits a coefficient per term from measured rows (bench.run.cost). None: the method's own
        guard will skip this row before rendering. Nothing beyond the base terms unless a method
        says so."""
        return {}

    def prepare(self, gpu, scene, facts, params: dict, view) -> None:
        self.params = params

    def release(self) -> None:
        pass
