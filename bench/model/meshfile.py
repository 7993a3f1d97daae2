"""Mesh files: reading them into a cleaned `MeshData`, the gibench `.npz` mesh archive, transforms.

`read_mesh(path)` loads a mesh with trimesh (OBJ/MTL, PLY, glTF/GLB, STL, OFF) or a gibench
mesh archive (`.npz`, written by `write_mesh_npz` for `scripts/import_real_scenes.py`; fields in
`read_mesh_npz`). Scene files (`bench.model.scenefile`) and the real-scene corpus
(`bench.model.corpus.real`) place meshes with `transform_matrix` / `transformed`.

The albedo a file gives a material: the *float* MTL `Kd` (trimesh's `material.kwargs['kd']`,
not the uint8 `material.diffuse`), a glTF `baseColorFactor` (stored as uint8 by trimesh), or
the per-triangle albedo of an `.npz` (`MeshData.triangle_albedo` applies a scene file's
overrides and default). A material that repeats `Kd` uses its first `Kd` line (trimesh keeps
the last).

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

Every bad input raises `SceneError` with a one-line message naming the file: missing or
unreadable mesh or archive, an OBJ's missing material library (`material_library`: why an
error, not a warning), unsupported format, non-finite vertex, no triangles.
"""
from __future__ import annotations

import json
import math
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.model.scene import SceneError

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


def material_library(obj_path: Path, text: str) -> tuple[str, bytes] | None:
    """(name, bytes) of the material library an OBJ names, found as trimesh finds it (the text
    after the file's first `mtllib`, looked up by trimesh's own resolver in the OBJ's folder);
    None when the OBJ names none.

    A library that is named but missing (or outside the OBJ's folder) is an error naming it, not
    a warning: it holds the albedo, which every GI figure scales with, and trimesh silently falls
    back to no materials, so the scene would render with the default albedo, under the content
    hash of the same OBJ without `mtllib`, and a run's figures would not be of the scene its author
    described. Bad input is refused before any work; remove the `mtllib` line to use
    `default_albedo` on purpose."""
    import trimesh
    start = text.find("mtllib")   # as trimesh.exchange.obj.load_obj: the first occurrence, to the line's end
    if start < 0:
        return None
    end = text.find("\n", start)
    name = text[start + 6:end if end >= 0 else len(text)].strip()
    try:
        if not name:
            raise FileNotFoundError(name)
        return name, trimesh.resolvers.FilePathResolver(str(obj_path)).get(name)
    except (OSError, ValueError):   # ValueError: the name leaves the OBJ's folder
        raise SceneError(f"mesh file '{obj_path}': its material library (mtllib '{name}') is not in the OBJ's "
                         f"folder '{obj_path.parent.resolve()}'; add it there, or remove the mtllib line to use the "
                         f"default albedo") from None


def _first_kd_overrides(mtl_text: str) -> dict:
    """Materials whose MTL block has several `Kd` lines -> the first one (trimesh keeps the last)."""
    kd_lines: dict[str, list] = {}
    current = None
    for line in mtl_text.splitlines():
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
    text = None
    if suffix in _TEXT_SUFFIXES:
        try:
            text = path.read_bytes().decode("utf-8")
        except UnicodeDecodeError as exc:
            raise SceneError(f"mesh file '{path}' is not a {suffix} file: byte {exc.start} is not UTF-8 text") from None
        except OSError as exc:
            raise SceneError(f"mesh file '{path}' is unreadable ({exc.strerror})") from None
    library = material_library(path, text) if suffix == ".obj" else None
    import trimesh
    try:
        loaded = trimesh.load(str(path), force="scene", process=False)
    except ImportError:  # trimesh's fallbacks for undecodable text import optional modules
        raise SceneError(f"mesh file '{path}' is not a valid {suffix} file (trimesh cannot parse it)") from None
    except Exception as exc:  # trimesh raises many types for a bad file
        msg = " ".join(str(exc).split()) or type(exc).__name__
        raise SceneError(f"mesh file '{path}' is unreadable ({type(exc).__name__}: {msg})") from None
    kd_first = _first_kd_overrides(library[1].decode("utf-8", "replace")) if library else {}

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
    with np.errstate(over="ignore", invalid="ignore"):
        normals = mesh.normals @ np.linalg.inv(linear)  # inverse transpose, row vectors
        length = np.linalg.norm(normals, axis=1, keepdims=True)
    if not np.all(np.isfinite(length)):
        # a scale of 1e-291 gives normals whose squares overflow; a normal's direction does not depend
        # on a uniform scale: the inverse of the matrix scaled to its largest entry, each row to its own
        normals = mesh.normals @ np.linalg.inv(linear / np.abs(linear).max())
        normals /= np.maximum(np.abs(normals).max(axis=1, keepdims=True), 1e-300)
        length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals /= np.maximum(length, 1e-300)
    # slogdet: the sign of the determinant without overflow (scale 1e30) or underflow (1e-300)
    faces = mesh.faces[:, ::-1].copy() if np.linalg.slogdet(linear)[0] < 0 else mesh.faces
    return MeshData(vertices, faces, normals, mesh.material_index, mesh.material_names, mesh.material_kd,
                    mesh.albedo, mesh.dropped_duplicates, dict(mesh.meta))
