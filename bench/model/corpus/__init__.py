"""The scene corpus: procedural scenes and the real scenes shipped in `scenes/`.

    list_scenes() -> list[CorpusEntry]     name, purpose, triangle count (cheap: nothing is built)
    load_scene(name_or_path, **options) -> Scene

`load_scene` takes a corpus name (options as keyword arguments, or inline as
`"cornell_tiled:n=8"`, several separated by ':'), or the path of a TOML scene file
(`bench.model.scenefile`). All procedural scenes are in metres and deterministic; each has a camera
named "main". A scene built with non-default options is named after them
(`cornell_tiled-n8`), so results of different variants never mix.
"""
from __future__ import annotations

import inspect
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from bench.model.corpus import procedural, real
from bench.model.corpus.geometry import assemble
from bench.model.scene import Scene, SceneError


@dataclass(frozen=True)
class CorpusEntry:
    name: str
    purpose: str
    triangle_count: int
    kind: str            # "procedural" or "real"
    licence: str = ""    # real scenes: their licence (see scenes/README.md)


@dataclass(frozen=True)
class _Generator:
    name: str
    purpose: str
    plan: Callable
    kind: str = "procedural"
    licence: str = ""
    defaults: tuple = ()  # (option, value) pairs that differ from the plan function's defaults

    def options(self) -> dict:
        sig = inspect.signature(self.plan)
        opts = {k: p.default for k, p in sig.parameters.items()}
        opts.update(dict(self.defaults))
        return opts


_NC = "non-commercial"
SCENES: dict[str, _Generator] = {g.name: g for g in (
    _Generator("cornell_spot", "closed Cornell box lit by a spot aimed at the ceiling: most light on screen is indirect",
               procedural.plan_cornell_spot),
    _Generator("cornell_tiled", "the closed Cornell box tiled n x n (option n, default 4): triangle-count scaling, same image",
               procedural.plan_cornell_tiled),
    _Generator("rooms", "three rooms joined by offset doors: occlusion and long-range bounce, light and camera in different rooms",
               procedural.plan_rooms),
    _Generator("hidden_bounce", "the only directly lit surfaces are behind the camera: all visible light is a bounce from off screen",
               procedural.plan_hidden_bounce),
    _Generator("big_floor", "floor and back wall of 2 huge triangles each, beside dense small geometry lit by the floor's bounce",
               procedural.plan_big_floor),
    _Generator("lit_wall_corner", "a lit wall meeting an unlit floor, corner in view: every sender of the bounce is on screen",
               procedural.plan_lit_wall_corner),
    _Generator("sphere_inside", "inside a closed diffuse sphere: one-bounce radiance is exactly rho^2 I / (pi R^2) everywhere",
               procedural.plan_sphere_inside),
    _Generator("highpoly_10k", "noise-displaced terrain in a room, ~10k triangles (high-poly series)",
               procedural.plan_highpoly, defaults=(("triangles", 10_000),)),
    _Generator("highpoly_100k", "noise-displaced terrain in a room, ~100k triangles (high-poly series)",
               procedural.plan_highpoly, defaults=(("triangles", 100_000),)),
    _Generator("highpoly_1m", "noise-displaced terrain in a room, ~1M triangles (high-poly series)",
               procedural.plan_highpoly, defaults=(("triangles", 1_000_000),)),
    _Generator("highpoly_4m", "noise-displaced terrain in a room, ~4M triangles (high-poly series)",
               procedural.plan_highpoly, defaults=(("triangles", 4_000_000),)),
    _Generator("highpoly_10m", "noise-displaced terrain in a room, ~10M triangles (high-poly series)",
               procedural.plan_highpoly, defaults=(("triangles", 10_000_000),)),
    _Generator("cornell_box", "McGuire's CornellBox-Original (real), ceiling emitter replaced by a spot light",
               real.plan_cornell_box, "real", "CC BY 3.0 (McGuire)"),
    _Generator("sponza", "Dabrovic Sponza atrium (real), sun from above and one lamp: open, lots of bounce",
               real.plan_sponza, "real", f"CC BY-NC ({_NC})"),
    _Generator("sibenik", "Sibenik cathedral interior (real), point lights inside: closed, high occlusion",
               real.plan_sibenik, "real", f"CC BY-NC ({_NC})"),
    _Generator("conference", "LBNL conference room (real, scaled 0.004 m/unit), ceiling point lights, 62% of triangles tiny",
               real.plan_conference, "real", "public domain"),
    _Generator("holodeck", "G3D holodeck (real, cm -> m): closed room, dark gridded walls, point lights",
               real.plan_holodeck, "real", "CC BY 3.0"),
    _Generator("lost_empire", "Minecraft underground city (real): enclosed, voxel geometry, point lights",
               real.plan_lost_empire, "real", "CC BY 3.0 (McGuire)"),
    _Generator("bunny", "Stanford bunny (real) on a ground plane under a spot light",
               real.plan_bunny, "real", f"Stanford terms ({_NC})"),
    _Generator("teapot", "McGuire's watertight Utah teapot (real) on a ground plane under a spot light",
               real.plan_teapot, "real", "CC0"),
)}


def list_scenes() -> list[CorpusEntry]:
    """Every corpus scene with its default-option triangle count (computed without building)."""
    out = []
    for gen in SCENES.values():
        plan = gen.plan(**gen.options())
        out.append(CorpusEntry(gen.name, gen.purpose, plan.triangle_count, gen.kind, gen.licence))
    return out


def _parse_inline(spec: str) -> tuple[str, dict]:
    name, *items = spec.split(":")
    options = {}
    for item in items:
        if "=" not in item:
            raise SceneError(f"scene spec '{spec}': expected NAME:KEY=VALUE[:KEY=VALUE...], got '{item}'")
        key, value = item.split("=", 1)
        try:
            options[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            options[key.strip()] = value
    return name, options


def _check_options(gen: _Generator, options: dict) -> dict:
    allowed = gen.options()
    merged = dict(allowed)
    for key, value in options.items():
        if key not in allowed:
            names = ", ".join(allowed) or "none"
            raise SceneError(f"scene '{gen.name}' has no option '{key}' (options: {names})")
        default = allowed[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise SceneError(f"scene '{gen.name}': option {key}={value!r} must be a finite number")
        if isinstance(default, int) and not isinstance(default, bool):
            if float(value) != int(value):
                raise SceneError(f"scene '{gen.name}': option {key}={value!r} must be an integer")
            value = int(value)
        else:
            value = float(value)
        merged[key] = value
    return merged


def _variant_name(gen: _Generator, options: dict) -> str:
    defaults = gen.options()
    changed = [(k, v) for k, v in options.items() if v != defaults[k]]
    if not changed:
        return gen.name
    return gen.name + "".join(f"-{k}{v:g}" for k, v in changed)


def load_scene(name_or_path, **options) -> Scene:
    """A corpus scene by name (with options), or a TOML scene file by path."""
    text = str(name_or_path)
    if isinstance(name_or_path, Path) or text.endswith(".toml"):
        if options:
            raise SceneError(f"scene file '{text}': options {sorted(options)} only apply to corpus scenes")
        from bench.model.scenefile import load_scene_file
        return load_scene_file(text)
    name, inline = _parse_inline(text)
    if name not in SCENES:
        if Path(text).is_file():
            raise SceneError(f"scene '{text}': scene files must end in .toml")
        raise SceneError(f"unknown scene '{name}'; known: {', '.join(SCENES)} (or a .toml scene file)")
    gen = SCENES[name]
    opts = _check_options(gen, {**inline, **options})
    plan = gen.plan(**opts)
    vertices, faces, normals, albedo = assemble(plan.parts)
    dup = sum(p.dropped_duplicates() for p in plan.parts if hasattr(p, "dropped_duplicates"))
    source = f"bench.model.corpus ({gen.kind}) {gen.plan.__module__}.{gen.plan.__name__}({', '.join(f'{k}={v!r}' for k, v in opts.items())})"
    if plan.notes:
        source += f"; {plan.notes}"
    if dup:
        source += f"; {dup} duplicate triangles dropped at import"
    return Scene.build(_variant_name(gen, opts), vertices, faces, albedo, plan.lights, plan.cameras,
                       normals=normals, purpose=gen.purpose, source=source)


def scene_names() -> list[str]:
    return list(SCENES)


__all__ = ["CorpusEntry", "SCENES", "list_scenes", "load_scene", "scene_names"]
