"""Real scenes, read from the compact archives in `scenes/<name>/mesh.npz`.

The archives are written by `scripts/import_real_scenes.py` from the staged originals (see each
folder's SOURCE.txt, CONVERSION.md and `scenes/README.md` for provenance and licences). Albedo
is the MTL Kd only (no textures). Lights and cameras follow the staged README's suggestions;
where it gives a horizontal field of view (75 degrees unless stated), the vertical one below is
for a 16:9 image: fov_y = 2 atan(tan(fov_x / 2) * 9 / 16).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.model.corpus.geometry import quad
from bench.model.corpus.procedural import Plan
from bench.model.scene import Camera, DirectionalLight, PointLight, SceneError, SpotLight
from bench.model.meshfile import read_mesh_npz, read_npz_meta, transform_matrix, transformed


def scenes_dir() -> Path:
    """The `scenes/` folder of the checkout, or $GIBENCH_SCENES_DIR."""
    env = os.environ.get("GIBENCH_SCENES_DIR")
    return Path(env) if env else Path(__file__).resolve().parents[3] / "scenes"


def vertical_fov(horizontal_deg: float, aspect: float = 16 / 9) -> float:
    """Vertical field of view (degrees) of an image `aspect` = width / height wide."""
    return math.degrees(2 * math.atan(math.tan(math.radians(horizontal_deg) / 2) / aspect))


FOV_75_16_9 = vertical_fov(75.0)  # 46.8 degrees


@dataclass(frozen=True)
class ArchivePart:
    """The triangles of one `scenes/<folder>/mesh.npz`, scaled, minus some materials."""
    folder: str
    scale: float = 1.0
    exclude: tuple = ()
    albedo: tuple | None = None               # one RGB for every triangle
    materials: dict = field(default_factory=dict)  # material name -> RGB

    @property
    def path(self) -> Path:
        return scenes_dir() / self.folder / "mesh.npz"

    @property
    def triangle_count(self) -> int:
        _, counts, names = read_npz_meta(self.path)
        return int(sum(c for c, n in zip(counts, names) if n not in self.exclude))

    def build(self):
        mesh = read_mesh_npz(self.path)
        for name in list(self.exclude) + list(self.materials):
            if name not in mesh.material_names:
                raise SceneError(f"mesh archive '{self.path}': no material '{name}'")
        if self.exclude:
            mesh = mesh.without_materials(self.exclude)
        albedo = mesh.triangle_albedo(overrides=self.materials, mesh_albedo=self.albedo, where=f"{self.path}: ")
        mesh = transformed(mesh, transform_matrix(scale=self.scale))
        return mesh.vertices, mesh.faces, mesh.normals, albedo

    def dropped_duplicates(self) -> int:
        meta, _, _ = read_npz_meta(self.path)
        return int(meta.get("dropped_duplicates", 0))


def plan_cornell_box() -> Plan:
    # McGuire's ceiling light is an emitter quad (material `light`, y = 1.98, 0.47 x 0.38 m,
    # Ke 17 12 4). It is dropped; a downward spot just under it carries the same on-axis
    # intensity Ke * area (W/sr), its falloff roughly the luminaire's cosine.
    area = 0.47 * 0.38
    spot = SpotLight([-0.005, 1.95, -0.03], [-0.005, 0.0, -0.03], [17 * area, 12 * area, 4 * area],
                     cutoff_angle_deg=85.0, beam_width_deg=20.0)
    camera = Camera([0.0, 1.0, 3.9], [0.0, 1.0, 0.0], fov_y_deg=39.3)  # framed for a square image
    return Plan([ArchivePart("cornell_box", exclude=("light",))], [spot], {"main": camera},
                notes="CornellBox-Original without its emitter quad; 4 duplicated triangles dropped at import")


def plan_sponza() -> Plan:
    sun = DirectionalLight([0.2, -1.0, 0.35], [8.0, 7.6, 7.0])
    lamp = PointLight([9.0, 2.2, 4.0], [6.0, 5.0, 3.5])  # ground floor, 1.7 m from the nearest surface
    camera = Camera([-14.0, 2.5, 0.0], [0.0, 4.0, 0.0], fov_y_deg=FOV_75_16_9)
    return Plan([ArchivePart("sponza")], [sun, lamp], {"main": camera})


def plan_sibenik() -> Plan:
    # The staged README suggests (0, 5, 0), but that is above the nave's vault (most upward rays
    # escape the model there); (0, 0, 0) is inside, 3.3 m from the nearest surface.
    lights = [PointLight([0.0, 0.0, 0.0], [120.0] * 3), PointLight([-12.0, -10.0, 0.0], [40.0, 36.0, 30.0])]
    camera = Camera([-15.0, -12.5, 0.0], [10.0, -8.0, 0.0], fov_y_deg=FOV_75_16_9)
    return Plan([ArchivePart("sibenik")], lights, {"main": camera})


CONFERENCE_SCALE = 0.004  # metres per file unit (copyright.txt says 0.003; 0.004 gives a 2.1 m door)


def plan_conference() -> Plan:
    s = CONFERENCE_SCALE
    lights = [PointLight(np.array([500.0, 600.0, -200.0]) * s, [5.0] * 3),
              PointLight(np.array([1300.0, 600.0, 200.0]) * s, [3.0] * 3)]
    camera = Camera(np.array([1500.0, 400.0, 450.0]) * s, np.array([300.0, 150.0, -400.0]) * s,
                    fov_y_deg=FOV_75_16_9)
    return Plan([ArchivePart("conference", scale=s)], lights, {"main": camera})


def plan_holodeck() -> Plan:
    s = 0.01  # centimetres
    lights = [PointLight([3.5, 2.8, 0.0], [8.0] * 3),
              PointLight([0.12, 1.55, 0.0], [1.5, 1.5, 1.2])]  # 10 cm under the arch's built-in light quad
    camera = Camera([7.0, 1.7, 0.0], [0.0, 1.2, 0.0], fov_y_deg=FOV_75_16_9)
    return Plan([ArchivePart("holodeck", scale=s)], lights, {"main": camera})


def plan_lost_empire() -> Plan:
    lights = [PointLight([0.5, 16.0, 0.5], [30.0, 24.0, 16.0]),
              PointLight([-8.5, 15.5, -40.5], [20.0, 16.0, 11.0])]
    camera = Camera([-10.5, 16.0, -55.0], [-6.0, 13.0, 0.0], fov_y_deg=FOV_75_16_9)
    return Plan([ArchivePart("lost_empire")], lights, {"main": camera})


BUNNY_FLOOR_Y = -0.0546  # the lowest point of the bunny


def plan_bunny() -> Plan:
    floor = quad((-0.5, BUNNY_FLOOR_Y, -0.5), (0.0, 0.0, 1.0), (1.0, 0.0, 0.0), 1.0 / 16, (0.6, 0.6, 0.6))
    spot = SpotLight([0.2, 0.35, 0.3], [0.0, 0.0, 0.0], [0.6] * 3, cutoff_angle_deg=30.0)
    camera = Camera([0.0, 0.05, 0.35], [0.006, 0.022, -0.0135], fov_y_deg=30.0)
    return Plan([ArchivePart("bunny", albedo=(0.75, 0.75, 0.75)), floor], [spot], {"main": camera},
                notes="bunny albedo 0.75 (the PLY has none) on an added 1 x 1 m floor of 512 triangles")


TEAPOT_SCALE = 0.002  # file units -> metres: a 31 cm wide teapot


def plan_teapot() -> Plan:
    s = TEAPOT_SCALE
    floor = quad((-0.5, 0.0, -0.5), (0.0, 0.0, 1.0), (1.0, 0.0, 0.0), 1.0 / 16, (0.6, 0.6, 0.6))
    spot = SpotLight([0.3, 0.6, 0.4], [0.0, 0.05, 0.0], [1.5] * 3, cutoff_angle_deg=30.0)
    camera = Camera(np.array([0.0, 90.0, 250.0]) * s, np.array([5.0, 35.0, 0.0]) * s, fov_y_deg=vertical_fov(45.0))
    return Plan([ArchivePart("teapot", scale=s, albedo=(0.8, 0.8, 0.8)), floor], [spot], {"main": camera},
                notes="teapot albedo 0.8 (its Kd is 1 1 1) on an added 1 x 1 m floor of 512 triangles")
