#!/usr/bin/env python3
"""Convert the staged real scenes to gibench's compact mesh archives under `scenes/<name>/`.

Reads each scene's mesh from the staged copies (default `/work/shared/data/scenes`, see its
README for provenance and the trimesh 5.2.0 caveats) with `bench.model.meshfile.read_mesh`
(trimesh, `force='scene'`, geometries concatenated, float MTL Kd, textures skipped, duplicate
triangles dropped, shading normals from the file or with a 45 degree crease angle) and writes:

  scenes/<name>/mesh.npz        vertices, faces, normals, per-triangle albedo, materials (file units)
  scenes/<name>/CONVERSION.md   what was converted and how, with counts and the material table
  scenes/<name>/SOURCE.txt ...  the provenance and licence files, copied unchanged

Usage: .venv/bin/python scripts/import_real_scenes.py [--source DIR] [--out DIR] [NAME ...]
The corpus (`bench.model.corpus`) reads only the archives: the staged files are not needed at run time.
"""
from __future__ import annotations

import argparse
import hashlib
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.model.scene import triangle_areas  # noqa: E402
from bench.model.meshfile import DEFAULT_ALBEDO, DEFAULT_CREASE_ANGLE_DEG, read_mesh, write_mesh_npz  # noqa: E402


@dataclass(frozen=True)
class RealScene:
    name: str
    folder: str                 # staged folder
    mesh: str                   # mesh file in it
    copy: tuple                 # provenance / licence files copied unchanged
    licence: str
    units: str
    notes: str = ""


SCENES = (
    RealScene("cornell_box", "cornell_mcguire", "CornellBox-Original.obj", ("SOURCE.txt", "copyright.txt"),
              "CC BY 3.0, (c) 2009 Morgan McGuire", "about metres (box 2 units)",
              "Only CornellBox-Original.obj is converted (the other variants in SOURCE.txt are not). "
              "The upstream 'Bottom Face' of each block repeats a side face: those 4 duplicated triangles "
              "are dropped. The `light` quad (emitter, Ke 17 12 4) is kept in the archive as a "
              "diffuse material; the corpus drops it and uses a spot light instead."),
    RealScene("sponza", "sponza_dabrovic", "sponza.obj", ("SOURCE.txt", "copyright.txt"),
              "CC BY-NC 3.0, (c) 2002 Marko Dabrovic -- NON-COMMERCIAL USE ONLY", "about metres",
              "Textured materials keep their MTL Kd (a sensible average colour, per the staged README)."),
    RealScene("sibenik", "sibenik", "sibenik.obj", ("SOURCE.txt", "copyright.txt"),
              "CC BY-NC, (c) 2002 Marko Dabrovic -- NON-COMMERCIAL USE ONLY", "about metres",
              "The glass materials `staklo*` have Kd 0 0 0: the windows are opaque and black."),
    RealScene("conference", "conference", "conference.obj", ("SOURCE.txt", "copyright.txt"),
              "Public Domain, (c) Anat Grynberg and Greg Ward", "about 4 mm per unit (the corpus scales by 0.004)",
              "`mesh29_SG` (the table top) has two Kd lines upstream (0.286 0.149 0.129, then 1 1 1); "
              "trimesh keeps the last, the importer uses the first (a wood colour). 62% of the triangles "
              "belong to one tiny object on the floor (mesh33_SG + mesh34_SG); they are kept."),
    RealScene("holodeck", "holodeck", "holodeck.obj", ("SOURCE.txt", "license.txt"),
              "CC BY 3.0, (c) 2016 John William Telford", "centimetres (the corpus scales by 0.01)",
              "The emitters `light` (Ke 1 1 1) and `screens` (Ke 1 1 1, Kd 0) are kept as diffuse "
              "materials with their Kd; the corpus adds point lights."),
    RealScene("lost_empire", "lost_empire", "lost_empire.obj", ("SOURCE.txt", "copyright.txt"),
              "CC BY 3.0, (c) 2011 Morgan McGuire", "1 unit = 1 Minecraft block (= 1 m)",
              "All 45 materials share one texture atlas; their Kd is kept. Alpha cut-outs (map_d: leaves, "
              "torches, rails, flowers) are ignored: those quads are opaque."),
    RealScene("bunny", "bunny", "bunny.ply", ("SOURCE.txt",),
              "Stanford 3D Scanning Repository terms: research use, credit the Stanford Computer "
              "Graphics Laboratory, NO COMMERCIAL USE (quoted in SOURCE.txt)", "metres (15.6 cm bunny)",
              "The PLY has no colour: albedo is the default 0.8 (the corpus overrides it)."),
    RealScene("teapot", "teapot_mcguire", "teapot.obj", ("SOURCE.txt",),
              "CC0, (c) 1975 Martin Newell (licence stated in SOURCE.txt)", "arbitrary (the corpus scales by 0.002)",
              "Its one material has Kd 1 1 1 (and a 113-byte texture); the corpus overrides the albedo."),
)


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def nondegenerate(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The triangles `Scene.build` keeps (same criterion, on the stored float32 vertices)."""
    v = vertices.astype(np.float32).astype(np.float64)
    extent = float(np.linalg.norm(v.max(0) - v.min(0)))
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    return ~(repeated | (triangle_areas(v, faces) <= 1e-14 * extent * extent))


def count_file_triangles(path: Path) -> int:
    """Fan-triangulated faces in file order (the staged README's count), for the record."""
    if path.suffix.lower() != ".obj":
        return -1
    total = 0
    with open(path, "rb") as fh:
        for line in fh:
            if line.startswith(b"f ") or line.startswith(b"f\t"):
                total += len(line.split()) - 3
    return total


def convert(scene: RealScene, source_root: Path, out_root: Path) -> dict:
    src_dir = source_root / scene.folder
    src = src_dir / scene.mesh
    out_dir = out_root / scene.name
    out_dir.mkdir(parents=True, exist_ok=True)
    mesh = read_mesh(src, crease_angle_deg=DEFAULT_CREASE_ANGLE_DEG)
    albedo = mesh.triangle_albedo(DEFAULT_ALBEDO, where=f"{src}: ")
    keep = nondegenerate(mesh.vertices, mesh.faces)
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    file_triangles = count_file_triangles(src)
    meta = dict(name=scene.name, source=f"{scene.folder}/{scene.mesh}", source_sha256=sha256(src),
                licence=scene.licence, units=scene.units, loader=mesh.meta.get("loader", ""),
                crease_angle_deg=DEFAULT_CREASE_ANGLE_DEG, file_triangles=file_triangles,
                degenerate=int((~keep).sum()), bbox_min=lo.round(4).tolist(), bbox_max=hi.round(4).tolist())
    write_mesh_npz(out_dir / "mesh.npz", mesh, meta, albedo, keep)
    for name in scene.copy:
        shutil.copyfile(src_dir / name, out_dir / name)
    counts = np.bincount(mesh.material_index, minlength=len(mesh.material_names))
    kept = np.bincount(mesh.material_index[keep], minlength=len(mesh.material_names))
    rows = []
    for i, name in enumerate(mesh.material_names):
        kd = mesh.material_kd[i]
        kd_text = "none (default {:g})".format(DEFAULT_ALBEDO) if np.isnan(kd).any() else " ".join(f"{x:g}" for x in kd)
        rows.append(f"| `{name or '(none)'}` | {kd_text} | {counts[i]:,} | {kept[i]:,} |")
    size = (out_dir / "mesh.npz").stat().st_size
    text = f"""# {scene.name}: conversion record

Written by `scripts/import_real_scenes.py` (do not edit by hand; re-run the script).

* Source: `{scene.folder}/{scene.mesh}` of the staged scenes (provenance in `SOURCE.txt`),
  sha256 `{meta['source_sha256']}`.
* Licence: {scene.licence}.
* Units: {scene.units}. Bounding box (file units): {meta['bbox_min']} -> {meta['bbox_max']}.
* Loaded with {meta['loader']} (`force='scene'`, `process=False`, geometries concatenated,
  materials per geometry) by `bench.model.meshfile.read_mesh`.
* Triangles: {file_triangles if file_triangles >= 0 else len(mesh.faces) + mesh.dropped_duplicates:,} in the file;
  {mesh.dropped_duplicates:,} duplicated triangles dropped (same three positions, either winding);
  {len(mesh.faces):,} stored, of which {meta['degenerate']:,} have zero area (kept here, dropped by `Scene.build`).
* Vertices: {len(mesh.vertices):,} (coincident positions welded, then split where shading normals differ).
* Shading normals: the file's vertex normals where it has them, otherwise area-weighted face
  normals within a {DEFAULT_CREASE_ANGLE_DEG:g} degree crease angle (two-sided).
* Albedo: the float MTL `Kd` of each material (not trimesh's uint8 `diffuse`), stored per triangle
  as uint16 fixed point (Kd x 65535). **Textures are skipped: albedo is Kd only** (no texture,
  bump, alpha or emission maps; `Ke` emitters become ordinary diffuse surfaces).
* Notes: {scene.notes}
* Archive: `mesh.npz`, {size / 1e6:.2f} MB (fields documented in `bench.model.meshfile.read_mesh_npz`).

| material | Kd | triangles | non-degenerate |
|---|---|---:|---:|
""" + "\n".join(rows) + "\n"
    (out_dir / "CONVERSION.md").write_text(text)
    return dict(name=scene.name, triangles=len(mesh.faces), nondegenerate=int(keep.sum()),
                duplicates=mesh.dropped_duplicates, vertices=len(mesh.vertices), size=size)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--source", default="/work/shared/data/scenes", help="staged scenes folder")
    parser.add_argument("--out", default=str(ROOT / "scenes"), help="output folder (default: scenes/)")
    parser.add_argument("names", nargs="*", help=f"scenes to convert (default all: {', '.join(s.name for s in SCENES)})")
    args = parser.parse_args(argv)
    known = {s.name: s for s in SCENES}
    unknown = [n for n in args.names if n not in known]
    if unknown:
        parser.error(f"unknown scene(s) {', '.join(unknown)}; known: {', '.join(known)}")
    for name in args.names or list(known):
        r = convert(known[name], Path(args.source), Path(args.out))
        print(f"{r['name']:12s} {r['triangles']:>8,d} tris ({r['nondegenerate']:,} non-degenerate, "
              f"{r['duplicates']} duplicates dropped), {r['vertices']:>8,d} verts, {r['size'] / 1e6:6.2f} MB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
