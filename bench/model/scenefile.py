"""Scene files: a small TOML format that places mesh files, lights and named cameras.

`load_scene_file(path) -> Scene` reads a scene file (Python's `tomllib`), loads every mesh it
names with trimesh (OBJ/MTL, PLY, glTF/GLB, STL, OFF) or as a gibench mesh archive (`.npz`,
written by `scripts/import_real_scenes.py`), applies per-mesh transforms and albedo overrides,
and validates everything through `Scene.build`. Units are metres by convention (the file's own
units are used as they are; use `scale` to convert).

Complete example (`scenes/examples/two_quads.toml`)::

    name = "two_quads"                 # optional, default: the file name without .toml
    purpose = "a floor and a wall from one OBJ quad, with every kind of light"  # optional, one line
    default_albedo = 0.8               # optional: albedo of meshes/materials without one (0.8)

    [[mesh]]                           # one table per mesh file; at least one
    file = "quad.obj"                  # required, relative to this .toml file
    scale = 2.0                        # number, or [sx, sy, sz] (non-uniform); default 1
    rotate_deg = [-90, 0, 0]           # degrees about the fixed X, then Y, then Z axis; default 0
    translate = [0, 0, 0]              # metres, applied last; default 0
    albedo = [0.8, 0.8, 0.8]           # optional: overrides every material of this mesh

    [[mesh]]
    file = "quad.obj"
    scale = [2.0, 2.0, 1.0]
    translate = [0, 1, -1]
    crease_angle_deg = 45              # normals without file normals: smooth below this angle
    file_normals = true                # use the file's vertex normals when it has them
    exclude_materials = []             # drop the triangles of these material names
    [mesh.materials]                   # per material name (OBJ usemtl), overrides the MTL Kd
    quad_white = [0.2, 0.8, 0.2]

    [[light]]                          # at least one light
    type = "point"
    position = [0.3, 1.5, 0.5]
    intensity = [4, 4, 4]              # W/sr; a number means grey

    [[light]]
    type = "spot"                      # Mitsuba's `spot`
    position = [0, 1.9, 1.5]
    target = [0, 0, -0.5]
    intensity = 10                     # W/sr at the beam centre
    cutoff_angle_deg = 30              # optional (20)
    beam_width_deg = 22.5              # optional (3/4 of the cutoff)

    [[light]]
    type = "directional"
    direction = [0.3, -1, -0.2]        # the direction the light travels in
    irradiance = 0.5                   # W/m^2 on a surface facing the light

    [camera.main]                      # named cameras, at least one: [camera.NAME]
    eye = [0, 1, 3]
    target = [0, 0.7, 0]
    up = [0, 1, 0]                     # optional (+Y)
    fov_y_deg = 50                     # optional (45): the VERTICAL field of view

    [animation]                        # optional: the scene in motion (bench.model.animation)
    frames = 24                        # frames of the sequence (>= 2); keys interpolate linearly
    [[animation.light]]
    index = 0                          # the [[light]] table, 0 = the first
    keys = [{frame = 0, position = [0.3, 1.5, 0.5]}, {frame = 23, position = [-0.3, 1.5, 0.5]}]
    [[animation.camera]]
    name = "main"                      # eye, target, fov_y_deg
    keys = [{frame = 0, eye = [0, 1, 3]}, {frame = 23, eye = [1, 1, 3], fov_y_deg = 40}]
    [[animation.mesh]]
    index = 1                          # the [[mesh]] table: translate, rotate_deg, scale about its centre
    keys = [{frame = 0, translate = [0, 0, 0]}, {frame = 23, translate = [0, 0.5, 0]}]

Transform order: scale, then rotate, then translate (p' = R S p + t). Normals follow the
inverse transpose; a mirroring scale flips the winding so faces keep their orientation.

`load_scene_file` gives the scene at rest (its [animation] checked), `load_sequence_file` the
Sequence: the static scene of each frame and what changed between frames.

Albedo (linear RGB diffuse reflectance, per triangle), first match wins: the mesh's `albedo`;
its `[mesh.materials]` entry; the material's diffuse colour in the file, i.e. the *float* MTL
`Kd` (trimesh's `material.kwargs['kd']`, not the uint8 `material.diffuse`), a glTF
`baseColorFactor` (stored as uint8 by trimesh), or the per-triangle albedo of an `.npz`;
else `default_albedo`. Textures are ignored: albedo is Kd only. A material that repeats `Kd`
(the conference room's table) uses its first `Kd` line (trimesh keeps the last). A Kd outside
[0, 1] is an error that names the material (override it).

Mesh files are read and cleaned by `bench.model.meshfile.read_mesh` (welding, duplicate
triangles, shading normals from `file_normals` / `crease_angle_deg`, zero-area triangles,
trimesh caveats: its docstring).

The scene name and the camera names are folder names in run folders: letters, digits and
`_ . + = -` only (`bench.model.scene.check_path_name`; `../x` or `[camera."a/b"]` is an error).
An OBJ's `mtllib` must name a file that exists (`bench.model.meshfile.material_library`). A mesh
`file` that resolves (symbolic links followed) outside the scene file's folder is an error unless
the file sets `allow_meshes_outside = true` at its top level (default false).

Every bad input raises `SceneError` with a one-line message naming the file and the culprit:
missing or unreadable mesh or material library, a file that is not UTF-8 text, non-finite vertex,
no light, no camera, unknown key (naming the key and its table), wrong type.
"""
from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np

from bench.model.meshfile import DEFAULT_ALBEDO, DEFAULT_CREASE_ANGLE_DEG, read_mesh, transform_matrix, transformed
from bench.model.scene import (MAX_MAGNITUDE, Camera, DirectionalLight, PointLight, Scene, SceneError, SpotLight,
                               check_path_name, check_scene_name)

# ---------------------------------------------------------------------------- TOML schema
_TOP_KEYS = ("name", "purpose", "default_albedo", "allow_meshes_outside", "mesh", "light", "camera", "animation")
_ANIMATION_KEYS = ("frames", "camera", "light", "mesh")
_TRACK_TARGET = {"camera": "name", "light": "index", "mesh": "index"}   # what a track of each kind names
_MESH_KEYS = ("file", "translate", "rotate_deg", "scale", "albedo", "materials", "exclude_materials",
              "crease_angle_deg", "file_normals")
_LIGHT_KEYS = {
    "point": ("type", "position", "intensity"),
    "spot": ("type", "position", "target", "intensity", "cutoff_angle_deg", "beam_width_deg"),
    "directional": ("type", "direction", "irradiance"),
}
_LIGHT_REQUIRED = {"point": ("position", "intensity"), "spot": ("position", "target", "intensity"),
                   "directional": ("direction", "irradiance")}
_CAMERA_KEYS = ("eye", "target", "up", "fov_y_deg")


class _Ctx:
    """Builds one-line error messages: '<file>: <table>: <problem>'."""

    def __init__(self, path: Path):
        self.path = path

    def error(self, where: str, problem: str) -> SceneError:
        return SceneError(f"scene file '{self.path}': {where}: {problem}")

    def keys(self, table: dict, allowed, where: str) -> None:
        for key in table:
            if key not in allowed:
                raise self.error(where, f"unknown key '{key}' (allowed: {', '.join(allowed)})")

    def require(self, table: dict, key: str, where: str):
        if key not in table:
            raise self.error(where, f"missing key '{key}'")
        return table[key]

    @staticmethod
    def _is_number(x) -> bool:
        return isinstance(x, (int, float)) and not isinstance(x, bool)

    def number(self, value, key: str, where: str) -> float:
        if not self._is_number(value):
            raise self.error(where, f"'{key}' must be a number, got {type(value).__name__} {value!r}")
        if not math.isfinite(value):
            raise self.error(where, f"'{key}' must be finite, got {value!r}")
        if abs(value) > MAX_MAGNITUDE:
            raise self.error(where, f"'{key}' = {value!r} is beyond +-{MAX_MAGNITUDE:g}")
        return float(value)

    def vec3(self, value, key: str, where: str) -> np.ndarray:
        if not (isinstance(value, list) and len(value) == 3 and all(self._is_number(x) for x in value)):
            raise self.error(where, f"'{key}' must be a list of 3 numbers, got {value!r}")
        if not all(math.isfinite(x) for x in value):
            raise self.error(where, f"'{key}' must be finite, got {value!r}")
        if max(abs(x) for x in value) > MAX_MAGNITUDE:
            raise self.error(where, f"'{key}' = {value!r} is beyond +-{MAX_MAGNITUDE:g}")
        return np.array(value, dtype=np.float64)

    def rgb(self, value, key: str, where: str, low=0.0, high=None) -> np.ndarray:
        if self._is_number(value):
            arr = np.full(3, self.number(value, key, where))
        elif isinstance(value, list):
            arr = self.vec3(value, key, where)
        else:
            raise self.error(where, f"'{key}' must be a number or a list of 3 numbers, got {type(value).__name__} {value!r}")
        if arr.min() < low or (high is not None and arr.max() > high):
            bounds = f"[{low:g}, {high:g}]" if high is not None else f">= {low:g}"
            raise self.error(where, f"'{key}' = {arr.tolist()} must be {bounds}")
        return arr

    def string(self, value, key: str, where: str) -> str:
        if not isinstance(value, str):
            raise self.error(where, f"'{key}' must be a string, got {type(value).__name__} {value!r}")
        return value

    def table(self, value, key: str, where: str) -> dict:
        if not isinstance(value, dict):
            raise self.error(where, f"'{key}' must be a table, got {type(value).__name__}")
        return value

    def table_list(self, value, key: str, where: str) -> list:
        if not (isinstance(value, list) and all(isinstance(v, dict) for v in value)):
            raise self.error(where, f"'{key}' must be an array of tables ([[{key}]]), got {type(value).__name__}")
        return value


def _parse_mesh(ctx: _Ctx, base: Path, index: int, table: dict, default_albedo, allow_outside: bool = False) -> tuple:
    where = f"[[mesh]] #{index + 1}" + (f" ('{table['file']}')" if isinstance(table.get("file"), str) else "")
    ctx.keys(table, _MESH_KEYS, where)
    file = ctx.string(ctx.require(table, "file", where), "file", where)
    translate = ctx.vec3(table.get("translate", [0, 0, 0]), "translate", where)
    rotate = ctx.vec3(table.get("rotate_deg", [0, 0, 0]), "rotate_deg", where)
    scale_value = table.get("scale", 1.0)
    scale = ctx.vec3(scale_value, "scale", where) if isinstance(scale_value, list) else \
        np.full(3, ctx.number(scale_value, "scale", where))
    if np.any(scale == 0):
        raise ctx.error(where, f"'scale' must not be zero, got {scale_value!r}")
    albedo = ctx.rgb(table["albedo"], "albedo", where, 0.0, 1.0) if "albedo" in table else None
    crease = ctx.number(table.get("crease_angle_deg", DEFAULT_CREASE_ANGLE_DEG), "crease_angle_deg", where)
    if not 0 <= crease <= 180:
        raise ctx.error(where, f"'crease_angle_deg' must be in [0, 180], got {crease:g}")
    use_file_normals = table.get("file_normals", True)
    if not isinstance(use_file_normals, bool):
        raise ctx.error(where, f"'file_normals' must be true or false, got {use_file_normals!r}")
    overrides = {}
    for name, value in ctx.table(table.get("materials", {}), "materials", where).items():
        overrides[name] = ctx.rgb(value, f"materials.{name}", where, 0.0, 1.0)
    exclude = table.get("exclude_materials", [])
    if not (isinstance(exclude, list) and all(isinstance(e, str) for e in exclude)):
        raise ctx.error(where, f"'exclude_materials' must be a list of strings, got {exclude!r}")

    mesh_path = (base / file) if not Path(file).is_absolute() else Path(file)
    if not allow_outside and not mesh_path.resolve().is_relative_to(base.resolve()):
        raise ctx.error(where, f"mesh file '{file}' is outside the scene file's folder; set "
                               f"allow_meshes_outside = true at the top level to use it")
    try:
        mesh = read_mesh(mesh_path, crease_angle_deg=crease, file_normals=use_file_normals)
    except SceneError as exc:
        raise ctx.error(where, str(exc)) from None
    for name in list(overrides) + list(exclude):
        if name not in mesh.material_names:
            known = ", ".join(repr(n) for n in mesh.material_names if n) or "none"
            raise ctx.error(where, f"material '{name}' is not in the mesh file (its materials: {known})")
    if exclude:
        mesh = mesh.without_materials(exclude)
        if mesh.triangle_count == 0:
            raise ctx.error(where, "exclude_materials removes every triangle")
    try:
        tri_albedo = mesh.triangle_albedo(default_albedo, overrides, albedo, where="")
    except SceneError as exc:
        raise ctx.error(where, str(exc)) from None
    mesh = transformed(mesh, transform_matrix(translate, rotate, scale))
    return mesh, tri_albedo


def _parse_light(ctx: _Ctx, index: int, table: dict):
    where = f"[[light]] #{index + 1}"
    kind = ctx.string(ctx.require(table, "type", where), "type", where)
    if kind not in _LIGHT_KEYS:
        raise ctx.error(where, f"unknown light type '{kind}' (known: {', '.join(_LIGHT_KEYS)})")
    where = f"[[light]] #{index + 1} ({kind})"
    ctx.keys(table, _LIGHT_KEYS[kind], where)
    for key in _LIGHT_REQUIRED[kind]:
        ctx.require(table, key, where)
    try:
        if kind == "point":
            return PointLight(ctx.vec3(table["position"], "position", where),
                              ctx.rgb(table["intensity"], "intensity", where))
        if kind == "spot":
            kwargs = {}
            if "cutoff_angle_deg" in table:
                kwargs["cutoff_angle_deg"] = ctx.number(table["cutoff_angle_deg"], "cutoff_angle_deg", where)
            if "beam_width_deg" in table:
                kwargs["beam_width_deg"] = ctx.number(table["beam_width_deg"], "beam_width_deg", where)
            return SpotLight(ctx.vec3(table["position"], "position", where), ctx.vec3(table["target"], "target", where),
                             ctx.rgb(table["intensity"], "intensity", where), **kwargs)
        return DirectionalLight(ctx.vec3(table["direction"], "direction", where),
                                ctx.rgb(table["irradiance"], "irradiance", where))
    except SceneError as exc:
        if str(exc).startswith("scene file"):
            raise
        raise ctx.error(where, str(exc)) from None


def _parse_camera(ctx: _Ctx, name: str, table) -> Camera:
    where = f"[camera.{name}]"
    if not isinstance(table, dict):
        raise ctx.error(where, f"a camera must be a table ([camera.{name}] with eye, target, ...), got {type(table).__name__}")
    ctx.keys(table, _CAMERA_KEYS, where)
    kwargs = dict(eye=ctx.vec3(ctx.require(table, "eye", where), "eye", where),
                  target=ctx.vec3(ctx.require(table, "target", where), "target", where))
    if "up" in table:
        kwargs["up"] = ctx.vec3(table["up"], "up", where)
    if "fov_y_deg" in table:
        kwargs["fov_y_deg"] = ctx.number(table["fov_y_deg"], "fov_y_deg", where)
    try:
        return Camera(**kwargs)
    except SceneError as exc:
        raise ctx.error(where, str(exc)) from None


def load_scene_file(path) -> Scene:
    """Read a TOML scene file (format in the module docstring) and return a validated Scene (with an
    [animation] table: the scene at rest, the animation checked)."""
    scene, animation = _read(Path(path))
    if animation is not None:
        _sequence(Path(path), scene, *animation)   # a bad animation is an error of the file whatever reads it
    return scene


def load_sequence_file(path):
    """Read a TOML scene file with an [animation] table: a bench.model.animation.Sequence."""
    scene, animation = _read(Path(path))
    if animation is None:
        raise SceneError(f"scene file '{path}': no [animation] table (a static scene: load it with load_scene_file)")
    return _sequence(Path(path), scene, *animation)


def _sequence(path: Path, scene: Scene, doc_animation: dict, mesh_vertices: list):
    """The Sequence an [animation] table describes (format in the module docstring)."""
    from bench.model.animation import Sequence
    ctx, where = _Ctx(path), "[animation]"
    anim = ctx.table(doc_animation, "animation", "top level")
    ctx.keys(anim, _ANIMATION_KEYS, where)
    frames = ctx.require(anim, "frames", where)
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 2:
        raise ctx.error(where, f"'frames' must be an integer >= 2, got {frames!r}")
    tracks, groups = [], {}
    for kind, target_key in _TRACK_TARGET.items():
        for i, table in enumerate(ctx.table_list(anim.get(kind, []), kind, where)):
            here = f"[[animation.{kind}]] #{i + 1}"
            ctx.keys(table, (target_key, "keys"), here)
            target = ctx.require(table, target_key, here)
            if kind == "camera":
                target = ctx.string(target, target_key, here)
            elif isinstance(target, bool) or not isinstance(target, int):
                raise ctx.error(here, f"'{target_key}' must be an integer (0 = the first [[{kind}]] table), got {target!r}")
            if kind == "mesh":
                if not 0 <= target < len(mesh_vertices):
                    raise ctx.error(here, f"'index' {target} names no [[mesh]] table (0 .. {len(mesh_vertices) - 1})")
                groups[f"mesh{target}"] = mesh_vertices[target]
                target = f"mesh{target}"
            keys = {}
            for key in ctx.table_list(ctx.require(table, "keys", here), "keys", here):
                frame = key.get("frame")
                if frame in keys:
                    raise ctx.error(here, f"two keys at frame {frame}")
                keys[frame] = {k: v for k, v in key.items() if k != "frame"}
            tracks.append((kind, target, [(f, v) for f, v in keys.items()]))
    try:
        return Sequence.build(scene.name, scene, frames, tracks, groups, purpose=scene.purpose)
    except SceneError as exc:
        raise SceneError(f"scene file '{path}': {exc}") from None


def _read(path: Path) -> tuple:
    """(the Scene, None or (its [animation] table, the vertex indices of each [[mesh]]))."""
    ctx = _Ctx(path)
    try:
        with open(path, "rb") as fh:
            doc = tomllib.load(fh)
    except FileNotFoundError:
        raise SceneError(f"scene file '{path}' not found") from None
    except UnicodeDecodeError as exc:   # tomllib decodes the whole file as UTF-8 first
        raise SceneError(f"scene file '{path}' is not UTF-8 text (byte {exc.start}: "
                         f"0x{exc.object[exc.start]:02x})") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"scene file '{path}': invalid TOML ({' '.join(str(exc).split())})") from None
    except OSError as exc:
        raise SceneError(f"scene file '{path}' is unreadable ({exc.strerror})") from None

    ctx.keys(doc, _TOP_KEYS, "top level")
    name = ctx.string(doc.get("name", path.stem), "name", "top level")
    allow_outside = doc.get("allow_meshes_outside", False)
    if not isinstance(allow_outside, bool):
        raise ctx.error("top level", f"'allow_meshes_outside' must be true or false, got {allow_outside!r}")
    purpose = ctx.string(doc.get("purpose", ""), "purpose", "top level")
    default_albedo = ctx.rgb(doc.get("default_albedo", DEFAULT_ALBEDO), "default_albedo", "top level", 0.0, 1.0)
    meshes = ctx.table_list(doc.get("mesh", []), "mesh", "top level")
    lights = ctx.table_list(doc.get("light", []), "light", "top level")
    cameras = doc.get("camera", {})
    if not isinstance(cameras, dict):
        raise ctx.error("top level", f"'camera' must be a table of named cameras ([camera.NAME]), got {type(cameras).__name__}")
    if not name:
        raise ctx.error("top level", "'name' must not be empty")
    try:
        check_scene_name(name)
    except SceneError as exc:
        raise ctx.error("top level", str(exc)) from None
    if not meshes:
        raise ctx.error("top level", "no mesh (add a [[mesh]] table with file = ...)")
    if not lights:
        raise ctx.error("top level", "no light (add a [[light]] table)")
    if not cameras:
        raise ctx.error("top level", "no camera (add a [camera.main] table)")

    for cam in cameras:   # before any mesh is read: a camera name is a folder of the run
        try:
            check_path_name(cam, "camera name")
        except SceneError as exc:
            raise ctx.error("[camera]", str(exc)) from None
    parsed_lights = [_parse_light(ctx, i, t) for i, t in enumerate(lights)]
    parsed_cameras = {cam: _parse_camera(ctx, cam, t) for cam, t in cameras.items()}
    base = path.parent
    verts, norms, faces, albedo = [], [], [], []
    offset = dropped_duplicates = 0
    mesh_vertices: list = []   # each [[mesh]]'s vertices: an [animation] moves them as one group
    for i, table in enumerate(meshes):
        mesh, tri_albedo = _parse_mesh(ctx, base, i, table, default_albedo, allow_outside)
        verts.append(mesh.vertices)
        norms.append(mesh.normals)
        faces.append(mesh.faces + offset)
        albedo.append(tri_albedo)
        mesh_vertices.append(np.arange(offset, offset + len(mesh.vertices), dtype=np.int64))
        offset += len(mesh.vertices)
        dropped_duplicates += mesh.dropped_duplicates
    source = f"scene file {path}"
    if dropped_duplicates:
        source += f" ({dropped_duplicates} duplicate triangles dropped)"
    try:
        scene = Scene.build(name, np.concatenate(verts), np.concatenate(faces), np.concatenate(albedo),
                            parsed_lights, parsed_cameras, normals=np.concatenate(norms),
                            purpose=purpose, source=source)
    except SceneError as exc:
        raise SceneError(f"scene file '{path}': {exc}") from None
    return scene, ((doc["animation"], mesh_vertices) if "animation" in doc else None)
