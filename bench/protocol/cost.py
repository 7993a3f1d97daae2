"""What a method's cost scales with: the facts a cost model reads (`CostFacts`) and the form of a
method's declaration (`MethodBase.cost_terms`).

A method declares, beside its parameters, the work counts its time grows with (pixels x VPLs,
VPLs x triangles, lightmap texels, ...) as a dict {term name: count} computed from its resolved
parameters and `CostFacts`; every row also has the terms `pixels` and `triangles`. The run's cost
model (bench.run.cost) fits one non-negative coefficient per term and phase (frame, prepare) from
measured rows, so a declaration says only *what* the cost scales with, never how much it is.
A method whose guard will skip the row before rendering (a triangle or surfel limit) returns
`None` with nothing to fit: the plan records it as skipped by its guard, costing nothing.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class CostFacts:
    """A row's size: its image and its scene's geometry (from SceneFacts or a manifest's scene_facts)."""
    width: int
    height: int
    triangles: int
    area_m2: float
    radius: float

    @property
    def pixels(self) -> int:
        return int(self.width) * int(self.height)

    @classmethod
    def of(cls, facts, width: int, height: int) -> "CostFacts":
        """From a SceneFacts or the dict a manifest records of it (`scene_facts`)."""
        get = facts.get if isinstance(facts, dict) else (lambda k: getattr(facts, k))
        return cls(width=int(width), height=int(height), triangles=int(get("triangle_count")),
                   area_m2=float(get("total_area_m2")), radius=float(get("scene_radius")))


def base_terms(size: CostFacts) -> dict:
    """The terms every row has: a pass over the image, a pass over the scene."""
    return {"pixels": float(size.pixels), "triangles": float(size.triangles)}
