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

Transform order: scale, then rotate, then translate (p' = R S p + t). Normals follow the
inverse transpose; a mirroring scale flips the winding so faces keep their orientation.

Albedo (linear RGB diffuse reflectance, per triangle), first match wins: the mesh's `albedo`;
its `[mesh.materials]` entry; the material's diffuse colour in the file, i.e. the *float* MTL
`Kd` (trimesh's `material.kwargs['kd']`, not the uint8 `material.diffuse`), a glTF
`baseColorFactor` (stored as uint8 by trimesh), or the per-triangle albedo of an `.npz`;
else `default_albedo`. Textures are ignored: albedo is Kd only. A material that repeats `Kd`
(the conference room's table) uses its first `Kd` line (trimesh keeps the last). A Kd outside
[0, 1] is an error that names the material (override it).

Mesh cleaning (what `read_mesh` does, identical for the corpus importer):
* vertices at the same position are welded; triangles that repeat another one (same three
  positions, either winding) are dropped (`MeshData.dropped_duplicates`, noted in
  `Scene.source`);
* shading normals: the file's vertex normals where it has them (`file_normals`), otherwise
  area-weighted normals of the neighbouring faces within `crease_angle_deg` of the face
  (two-sided: neighbours facing the other way count with their sign flipped); 0 gives flat
  shading, 90 or more smooth shading everywhere;
* zero-area triangles are dropped by `Scene.build` and counted in `Scene.dropped_degenerate`.

trimesh 5.2.0 caveats honoured (see the staged scenes' README): files are loaded with
`force='scene'` and the geometries concatenated (trimesh groups faces per material, so the
albedo is taken per geometry), `process=False`, textures skipped. Files that use negative OBJ
face indices interleaved with vertices, or a TAB after `v`/`vt`, load wrongly in trimesh:
normalise them first.

The scene name is a folder name in run folders: letters, digits and `_ . + = -` only
(`bench.model.scene.SCENE_NAME_PATTERN`; `../x` is an error). A mesh `file` that resolves (symbolic
links followed) outside the scene file's folder is an error unless the file sets `allow_meshes_outside = true` at its top level (default false).

Every bad input raises `SceneError` with a one-line message naming the file and the culprit:
missing or unreadable mesh, non-finite vertex, no light, no camera, unknown key (naming the key
and its table), wrong type.
"""
from __future__ import annotations

import json
import math
import tomllib
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.model.scene import (MAX_MAGNITUDE, Camera, DirectionalLight, PointLight, Scene, SceneError, SpotLight,
                         check_scene_name)

MESH_SUFFIXES = (".obj", ".ply", ".gltf", ".glb", ".stl", ".off", ".npz")
_TEXT_SUFFIXES = (".obj", ".gltf", ".off")  # formats with no binary variant: must be UTF-8 text
NPZ_FORMAT = "gibench-mesh"
NPZ_VERSION = 1
DEFAULT_CREASE_ANGLE_DEG = 45.0
DEFAULT_ALBEDO = 0.8
_ALBEDO_SCALE = 65535.0  # uint16 fixed point of the albedo in .npz archives


# ---------------------------------------------------------------------------- mesh data
@dataclass
class MeshData:
    """A cleaned triangle mesh with named materials (file units, float64)."""
    vertices: np.ndarray          # (V,3)
    faces: np.ndarray             # (T,3) int64
    normals: np.ndarray           # (V,3) unit shading normals
    material_index: np.ndarray    # (T,) int64 into material_names
    material_names: list
    material_kd: np.ndarray       # (M,3) diffuse albedo per material; NaN rows: none in the file
    albedo: np.ndarray | None = None  # (T,3) per-triangle albedo when the source stores one (.npz)
    dropped_duplicates: int = 0
    meta: dict = field(default_factory=dict)

    @property
    def triangle_count(self) -> int:
        return int(len(self.faces))

    def triangle_albedo(self, default=DEFAULT_ALBEDO, overrides: dict | None = None,
                        mesh_albedo=None, where: str = "") -> np.ndarray:
        """Per-triangle albedo: `mesh_albedo`, else `overrides[material]`, else the file's, else default."""
        t = self.triangle_count
        if mesh_albedo is not None:
            return np.broadcast_to(np.asarray(mesh_albedo, float), (t, 3)).copy()
        kd = np.array(self.material_kd, dtype=np.float64).reshape(-1, 3)
        no_kd = np.flatnonzero(np.isnan(kd).any(axis=1))
        if self.albedo is not None:
            out = np.array(self.albedo, dtype=np.float64)
            out[np.isin(self.material_index, no_kd)] = default
        else:
            kd[no_kd] = np.broadcast_to(np.asarray(default, float), (3,))
            out = kd[self.material_index] if len(kd) else np.tile(np.asarray(default, float), (t, 1))
        for name, value in (overrides or {}).items():
            out[self.material_index == self.material_names.index(name)] = value
        bad = (out < 0).any(1) | (out > 1).any(1)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            mat = self.material_names[int(self.material_index[i])] if self.material_names else ""
            raise SceneError(f"{where}material '{mat}' has albedo {out[i].tolist()} outside [0, 1]; "
                             f"override it in [mesh.materials]")
        return out

    def without_materials(self, names) -> "MeshData":
        """A copy without the triangles of the named materials (and the vertices only they used)."""
        drop = [self.material_names.index(n) for n in names]
        keep = ~np.isin(self.material_index, drop)
        used, faces = np.unique(self.faces[keep], return_inverse=True)
        return MeshData(self.vertices[used], faces.reshape(-1, 3), self.normals[used], self.material_index[keep],
                        self.material_names, self.material_kd,
                        None if self.albedo is None else self.albedo[keep],
                        self.dropped_duplicates, dict(self.meta))


def _first_kd_overrides(obj_path: Path) -> dict:
    """Materials whose MTL block has several `Kd` lines -> the first one (trimesh keeps the last)."""
    mtl_name = None
    with open(obj_path, "rb") as fh:
        for raw in fh:
            if raw.startswith(b"mtllib"):
                parts = raw.decode("utf-8", "replace").split(None, 1)
                mtl_name = parts[1].strip() if len(parts) > 1 else None
                break  # trimesh reads only the first mtllib too
    if not mtl_name or not (obj_path.parent / mtl_name).is_file():
        return {}
    kd_lines: dict[str, list] = {}
    current = None
    for line in (obj_path.parent / mtl_name).read_text("utf-8", "replace").splitlines():
        words = line.split("#", 1)[0].split()
        if not words:
            continue
        if words[0] == "newmtl" and len(words) > 1:
            current = words[1]
        elif words[0] == "Kd" and current is not None and len(words) >= 4:
            try:
                kd_lines.setdefault(current, []).append([float(w) for w in words[1:4]])
            except ValueError:
                continue
    return {name: lines[0] for name, lines in kd_lines.items() if len(lines) > 1}


def _material_colour(material) -> tuple[str, np.ndarray]:
    """(name, float RGB or NaNs) of a trimesh material."""
    nan = np.full(3, np.nan)
    if material is None:
        return "", nan
    name = str(getattr(material, "name", None) or "")
    kwargs = getattr(material, "kwargs", None) or {}
    kd = kwargs.get("kd")
    if kd is not None:
        try:
            arr = np.asarray(kd, dtype=np.float64).reshape(-1)[:3]
            if arr.shape == (3,):
                return name, arr
        except (TypeError, ValueError):
            pass
    base = getattr(material, "baseColorFactor", None)
    if base is not None:
        arr = np.asarray(base).reshape(-1)[:3]
        return name, arr.astype(np.float64) / (255.0 if arr.dtype == np.uint8 else 1.0)
    return name, nan


def read_mesh(path, crease_angle_deg: float = DEFAULT_CREASE_ANGLE_DEG, file_normals: bool = True,
              drop_duplicates: bool = True) -> MeshData:
    """Load a mesh file (trimesh formats or a gibench .npz) into a cleaned MeshData."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"mesh file '{path}' not found")
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise SceneError(f"mesh file '{path}': unsupported format '{suffix}' (supported: {', '.join(MESH_SUFFIXES)})")
    if suffix == ".npz":
        return read_mesh_npz(path)
    if suffix in _TEXT_SUFFIXES:
        try:
            path.read_bytes().decode("utf-8")
        except UnicodeDecodeError as exc:
            raise SceneError(f"mesh file '{path}' is not a {suffix} file: byte {exc.start} is not UTF-8 text") from None
        except OSError as exc:
            raise SceneError(f"mesh file '{path}' is unreadable ({exc.strerror})") from None
    import trimesh
    try:
        loaded = trimesh.load(str(path), force="scene", process=False)
    except ImportError:  # trimesh's fallbacks for undecodable text import optional modules
        raise SceneError(f"mesh file '{path}' is not a valid {suffix} file (trimesh cannot parse it)") from None
    except Exception as exc:  # trimesh raises many types for a bad file
        msg = " ".join(str(exc).split()) or type(exc).__name__
        raise SceneError(f"mesh file '{path}' is unreadable ({type(exc).__name__}: {msg})") from None
    kd_first = _first_kd_overrides(path) if suffix == ".obj" else {}

    names: list[str] = []
    kds: list[np.ndarray] = []
    verts, faces, mats, fnormals, has_fn = [], [], [], [], []
    offset = 0
    for node in loaded.graph.nodes_geometry:
        transform, geom_name = loaded.graph[node]
        geom = loaded.geometry[geom_name]
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            continue
        v = np.asarray(geom.vertices, dtype=np.float64)
        bad = ~np.all(np.isfinite(v), axis=1)
        if bad.any():  # before the transform, whose arithmetic on NaN / Inf would only warn
            i = int(np.flatnonzero(bad)[0])
            raise SceneError(f"mesh file '{path}': non-finite vertex {offset + i} {v[i].tolist()} "
                             f"({int(bad.sum())} in this part)")
        transform = np.asarray(transform, dtype=np.float64)
        v = v @ transform[:3, :3].T + transform[:3, 3]
        has_normals = bool(file_normals) and "vertex_normals" in geom._cache
        if has_normals:
            n = np.asarray(geom.vertex_normals, dtype=np.float64) @ np.linalg.inv(transform[:3, :3])
        else:
            n = np.zeros_like(v)
        name, kd = _material_colour(getattr(geom.visual, "material", None))
        if name in kd_first:
            kd = np.asarray(kd_first[name], dtype=np.float64)
        if name in names:
            mi = names.index(name)
        else:
            names.append(name)
            kds.append(kd)
            mi = len(names) - 1
        f = np.asarray(geom.faces, dtype=np.int64)
        if np.linalg.slogdet(transform[:3, :3])[0] < 0:
            f = f[:, ::-1]
        verts.append(v)
        fnormals.append(n)
        faces.append(f + offset)
        mats.append(np.full(len(f), mi, dtype=np.int64))
        has_fn.append(np.full(len(f), has_normals))
        offset += len(v)
    if not faces:
        raise SceneError(f"mesh file '{path}' contains no triangles")
    vertices = np.concatenate(verts)
    bad = ~np.all(np.isfinite(vertices), axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise SceneError(f"mesh file '{path}': non-finite vertex {i} {vertices[i].tolist()} ({int(bad.sum())} in all)")
    mesh = clean_mesh(vertices, np.concatenate(faces), np.concatenate(mats), np.concatenate(fnormals),
                      np.concatenate(has_fn), crease_angle_deg, drop_duplicates)
    mesh.material_names = names
    mesh.material_kd = np.array(kds, dtype=np.float64).reshape(-1, 3)
    mesh.meta.update(source=str(path), loader=f"trimesh {trimesh.__version__}")
    return mesh


def clean_mesh(vertices, faces, material_index, file_normals=None, has_file_normals=None,
               crease_angle_deg: float = DEFAULT_CREASE_ANGLE_DEG, drop_duplicates: bool = True) -> MeshData:
    """Weld coincident vertices, drop repeated triangles, compute per-corner shading normals and
    split vertices where their normals differ. Triangle order is kept (minus the dropped ones)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    material_index = np.asarray(material_index, dtype=np.int64)
    _, first, weld = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
    weld = weld.reshape(-1)
    wfaces = weld[faces]
    dropped = 0
    if drop_duplicates:
        key = np.sort(wfaces, axis=1)
        _, keep = np.unique(key, axis=0, return_index=True)
        keep = np.sort(keep)
        dropped = len(faces) - len(keep)
        faces, wfaces, material_index = faces[keep], wfaces[keep], material_index[keep]
        if has_file_normals is not None:
            has_file_normals = np.asarray(has_file_normals)[keep]
    positions = vertices[first]
    corner_normals = crease_normals(positions, wfaces, crease_angle_deg)
    if file_normals is not None and has_file_normals is not None and np.any(has_file_normals):
        fn = np.asarray(file_normals, dtype=np.float64)[faces]  # (T,3,3)
        length = np.linalg.norm(fn, axis=2)
        usable = np.asarray(has_file_normals)[:, None] & (length > 1e-12) & np.isfinite(length)
        corner_normals = np.where(usable[..., None], fn / np.maximum(length, 1e-300)[..., None], corner_normals)
    # One output vertex per (position, normal) pair, numbered in order of first use.
    quant = np.round(corner_normals.reshape(-1, 3) * 1e6).astype(np.int64)
    key = np.concatenate([wfaces.reshape(-1, 1), quant], axis=1)
    _, first_corner, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    rank = np.empty(len(first_corner), dtype=np.int64)
    order = np.argsort(first_corner, kind="stable")
    rank[order] = np.arange(len(first_corner))
    corner_vertex = wfaces.reshape(-1)[first_corner[order]]
    out_vertices = positions[corner_vertex]
    out_normals = corner_normals.reshape(-1, 3)[first_corner[order]]
    out_faces = rank[inverse].reshape(-1, 3)
    return MeshData(out_vertices, out_faces, out_normals, material_index, [], np.zeros((0, 3)),
                    dropped_duplicates=int(dropped))


def crease_normals(positions: np.ndarray, faces: np.ndarray, crease_angle_deg: float,
                   pair_budget: int = 1 << 22) -> np.ndarray:
    """Per-corner (T,3,3) shading normals: the area-weighted sum of the normals of the faces
    around the corner's vertex whose normal is within `crease_angle_deg` of the corner's face
    (either orientation; a neighbour facing the other way counts with its sign flipped)."""
    p = positions[faces]
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])  # length = 2 area
    length = np.linalg.norm(cross, axis=1)
    unit = np.where(length[:, None] > 0, cross / np.maximum(length, 1e-300)[:, None], 0.0)
    t = len(faces)
    corner_vertex = faces.reshape(-1)
    corner_face = np.repeat(np.arange(t), 3)
    order = np.argsort(corner_vertex, kind="stable")
    sv, sf = corner_vertex[order], corner_face[order]
    c = len(sv)
    starts = np.flatnonzero(np.r_[True, sv[1:] != sv[:-1]])
    counts = np.diff(np.r_[starts, c])
    degree = np.repeat(counts, counts)
    group_start = np.repeat(starts, counts)
    # Two-sided: the angle between two faces is at most 90 degrees once orientation is ignored.
    cos_limit = math.cos(math.radians(min(max(float(crease_angle_deg), 0.0), 90.0)))
    cos_limit = min(cos_limit, 1.0 - 1e-9) - 1e-12  # 0 degrees still merges coplanar faces
    acc = np.zeros((c, 3))
    pairs_before = np.r_[0, np.cumsum(degree)]
    a = 0
    while a < c:
        b = int(np.searchsorted(pairs_before, pairs_before[a] + pair_budget, side="right")) - 1
        b = max(b, a + 1)
        b = min(b, c)
        rows = np.repeat(np.arange(a, b), degree[a:b])
        within = np.arange(len(rows)) - np.repeat(pairs_before[a:b] - pairs_before[a], degree[a:b])
        cols = group_start[rows] + within
        fi, fj = sf[rows], sf[cols]
        dot = np.einsum("ij,ij->i", unit[fi], unit[fj])
        m = (np.abs(dot) >= cos_limit) & (length[fj] > 0)
        w = np.sign(dot[m])[:, None] * cross[fj[m]]
        r = rows[m] - a
        for k in range(3):
            acc[a:b, k] += np.bincount(r, weights=w[:, k], minlength=b - a)
        a = b
    out = np.empty_like(acc)
    out[order] = acc
    out = out.reshape(t, 3, 3)
    n = np.linalg.norm(out, axis=2)
    fallback = np.where(length[:, None] > 0, unit, np.array([0.0, 1.0, 0.0]))
    return np.where((n > 1e-300)[..., None], out / np.maximum(n, 1e-300)[..., None], fallback[:, None, :])


# ---------------------------------------------------------------------------- .npz archives
def write_mesh_npz(path, mesh: MeshData, meta: dict, albedo: np.ndarray, nondegenerate: np.ndarray) -> None:
    """Write a gibench mesh archive (see `read_mesh_npz` for the fields)."""
    counts = np.bincount(mesh.material_index[nondegenerate], minlength=len(mesh.material_names))
    info = dict(meta, format=NPZ_FORMAT, version=NPZ_VERSION, dropped_duplicates=mesh.dropped_duplicates)
    arrays = dict(
        vertices=mesh.vertices.astype(np.float32),
        faces=mesh.faces.astype(np.uint32),
        normals=mesh.normals.astype(np.float32),
        albedo=np.round(np.clip(albedo, 0, 1) * _ALBEDO_SCALE).astype(np.uint16),
        material_index=mesh.material_index.astype(np.uint16),
        material_names=np.array(mesh.material_names, dtype=str),
        material_kd=np.asarray(mesh.material_kd, dtype=np.float32),
        material_triangles=counts.astype(np.int64),
        meta=np.array(json.dumps(info, sort_keys=True)))
    # Like np.savez_compressed, with a fixed member date so that re-importing gives the same bytes.
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for key, arr in arrays.items():
            member = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            member.compress_type = zipfile.ZIP_DEFLATED
            with zf.open(member, "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.require(arr, requirements='C'), allow_pickle=False)


def read_npz_meta(path) -> tuple[dict, np.ndarray, list]:
    """(meta, material_triangles, material_names) of a gibench archive: small members only."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"].reshape(-1)[0]))
            return meta, np.array(z["material_triangles"]), [str(s) for s in z["material_names"]]
    except FileNotFoundError:
        raise SceneError(f"mesh archive '{path}' not found (run scripts/import_real_scenes.py)") from None
    except Exception as exc:
        raise SceneError(f"mesh archive '{path}' is unreadable ({type(exc).__name__}: {exc})") from None


def read_mesh_npz(path) -> MeshData:
    """Read a gibench mesh archive written by `write_mesh_npz`.

    Members: vertices float32 (V,3) in file units; faces uint32 (T,3); normals float32 (V,3);
    albedo uint16 (T,3) = round(Kd * 65535); material_index uint16 (T,); material_names str (M,);
    material_kd float32 (M,3) (NaN: none); material_triangles int64 (M,) (non-degenerate
    triangles per material, for cheap counts); meta (JSON string).
    """
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"mesh archive '{path}' not found (run scripts/import_real_scenes.py)")
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"].reshape(-1)[0]))
            if meta.get("format") != NPZ_FORMAT:
                raise ValueError(f"format {meta.get('format')!r} is not {NPZ_FORMAT!r}")
            mesh = MeshData(
                vertices=z["vertices"].astype(np.float64), faces=z["faces"].astype(np.int64),
                normals=z["normals"].astype(np.float64), material_index=z["material_index"].astype(np.int64),
                material_names=[str(s) for s in z["material_names"]],
                material_kd=z["material_kd"].astype(np.float64),
                albedo=z["albedo"].astype(np.float64) / _ALBEDO_SCALE,
                dropped_duplicates=int(meta.get("dropped_duplicates", 0)), meta=meta)
    except SceneError:
        raise
    except Exception as exc:
        msg = " ".join(str(exc).split())
        raise SceneError(f"mesh archive '{path}' is unreadable ({type(exc).__name__}: {msg})") from None
    bad = ~np.all(np.isfinite(mesh.vertices), axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise SceneError(f"mesh archive '{path}': non-finite vertex {i} {mesh.vertices[i].tolist()}")
    return mesh


# ---------------------------------------------------------------------------- transforms
def transform_matrix(translate=(0, 0, 0), rotate_deg=(0, 0, 0), scale=1.0) -> np.ndarray:
    """4x4 matrix of p' = R S p + t, R rotating about the fixed X, then Y, then Z axis."""
    from scipy.spatial.transform import Rotation
    s = np.broadcast_to(np.asarray(scale, dtype=np.float64), (3,))
    m = np.eye(4)
    m[:3, :3] = Rotation.from_euler("xyz", np.asarray(rotate_deg, dtype=np.float64), degrees=True).as_matrix() @ np.diag(s)
    m[:3, 3] = np.asarray(translate, dtype=np.float64)
    return m


def transformed(mesh: MeshData, matrix: np.ndarray) -> MeshData:
    """The mesh with positions and normals moved by a 4x4 affine `matrix`."""
    linear = matrix[:3, :3]
    vertices = mesh.vertices @ linear.T + matrix[:3, 3]
    normals = mesh.normals @ np.linalg.inv(linear)  # inverse transpose, row vectors
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    # slogdet: the sign of the determinant without overflow (scale 1e30) or underflow (1e-300)
    faces = mesh.faces[:, ::-1].copy() if np.linalg.slogdet(linear)[0] < 0 else mesh.faces
    return MeshData(vertices, faces, normals, mesh.material_index, mesh.material_names, mesh.material_kd,
                    mesh.albedo, mesh.dropped_duplicates, dict(mesh.meta))


# ---------------------------------------------------------------------------- TOML schema
_TOP_KEYS = ("name", "purpose", "default_albedo", "allow_meshes_outside", "mesh", "light", "camera")
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
    """Read a TOML scene file (format in the module docstring) and return a validated Scene."""
    path = Path(path)
    ctx = _Ctx(path)
    try:
        with open(path, "rb") as fh:
            doc = tomllib.load(fh)
    except FileNotFoundError:
        raise SceneError(f"scene file '{path}' not found") from None
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

    parsed_lights = [_parse_light(ctx, i, t) for i, t in enumerate(lights)]
    parsed_cameras = {cam: _parse_camera(ctx, cam, t) for cam, t in cameras.items()}
    base = path.parent
    verts, norms, faces, albedo = [], [], [], []
    offset = dropped_duplicates = 0
    for i, table in enumerate(meshes):
        mesh, tri_albedo = _parse_mesh(ctx, base, i, table, default_albedo, allow_outside)
        verts.append(mesh.vertices)
        norms.append(mesh.normals)
        faces.append(mesh.faces + offset)
        albedo.append(tri_albedo)
        offset += len(mesh.vertices)
        dropped_duplicates += mesh.dropped_duplicates
    source = f"scene file {path}"
    if dropped_duplicates:
        source += f" ({dropped_duplicates} duplicate triangles dropped)"
    try:
        return Scene.build(name, np.concatenate(verts), np.concatenate(faces), np.concatenate(albedo),
                           parsed_lights, parsed_cameras, normals=np.concatenate(norms),
                           purpose=purpose, source=source)
    except SceneError as exc:
        raise SceneError(f"scene file '{path}': {exc}") from None
