"""The perturbations the stress suite runs (bench.stress.suite): scene variants built with
bench.stress.perturb, and each method's parameters at the ends of their declared ranges."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from bench.stress import perturb


@dataclass(frozen=True)
class Variant:
    """One scene perturbation: `build(scene, view) -> Scene`."""
    name: str
    family: str
    kind: str                   # "invariance" or "robustness"
    build: Callable
    quick: bool = False


def scene_variants(quick: bool) -> list[Variant]:
    out = []
    for s in (1e-4, 1e-2, 1e2, 1e4):
        out.append(Variant(f"scale={s:.0e}", "scale", "invariance",
                           lambda sc, v, s=s: perturb.scale(sc, s), quick=s in (1e-4, 1e4)))
    for k in (1e3, 1e4, 1e5):
        out.append(Variant(f"translate={k:.0e}R", "translate", "invariance",
                           lambda sc, v, k=k: perturb.translate(sc, k), quick=k == 1e4))
    for name, fn in perturb.DEGENERATE.items():
        out.append(Variant(name, "degenerate", "invariance", lambda sc, v, fn=fn: fn(sc),
                           quick=name in ("sliver", "t_junction")))
    out.append(Variant("grazing_camera", "grazing", "robustness", lambda sc, v: perturb.grazing_camera(sc, v), quick=True))
    out.append(Variant("grazing_light", "grazing", "robustness", lambda sc, v: perturb.grazing_light(sc)))
    return [v for v in out if v.quick or not quick]


def scene_variant(name: str) -> Variant:
    """The scene variant called `name` (of the full suite); ValueError, one line, if none is."""
    for variant in scene_variants(False):
        if variant.name == name:
            return variant
    raise ValueError(f"no stress perturbation called {name!r}")


def param_variants(cls, quick: bool) -> list[tuple[str, dict]]:
    """(name, overrides) of `cls`'s parameters at the ends of their declared ranges.

    Full: every numeric Param at its low and high end, every other choice, the other boolean.
    Quick: the quality knobs (the counts a user turns down first) at their low end."""
    out = []
    for pname, p in cls.params.items():
        if quick:
            if p.quality and p.low is not None and p.low != p.default:
                out.append((pname, p.low))
            continue
        if p.choices is not None:
            out += [(pname, c) for c in p.choices if c != p.default]
        elif isinstance(p.default, bool):
            out.append((pname, not p.default))
        else:
            for end in (p.low, p.high):
                if end is not None and end != p.default:
                    out.append((pname, int(end) if isinstance(p.default, int) else float(end)))
    return [(f"params:{k}={v:g}" if isinstance(v, float) else f"params:{k}={v}", {k: v}) for k, v in out]
