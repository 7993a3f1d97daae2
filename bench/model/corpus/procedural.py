"""Procedural corpus scenes (metres, deterministic). Each `plan_*` returns a `Plan`: the parts
(counted without building), lights and cameras; `bench.model.corpus` turns a plan into a Scene."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from bench.model.corpus.geometry import GREEN, RED, WHITE, Heightfield, Icosphere, box, quad, wavy_height
from bench.model.scene import Camera, DirectionalLight, PointLight, SceneError, SpotLight


@dataclass
class Plan:
    parts: list
    lights: list
    cameras: dict
    notes: str = ""
    extra: dict = field(default_factory=dict)

    @property
    def triangle_count(self) -> int:
        return int(sum(p.triangle_count for p in self.parts))


def _require(cond: bool, scene: str, message: str) -> None:
    if not cond:
        raise SceneError(f"scene '{scene}': {message}")


# ---------------------------------------------------------------------------- Cornell box
# The two blocks of the classic box (McGuire's CornellBox-Original coordinates, squared up):
# centre (x, z), size, yaw about +Y in degrees.
_SHORT_BLOCK = ((0.3275, 0.375), (0.6, 0.6, 0.6), -16.6)
_TALL_BLOCK = ((-0.335, -0.29), (0.6, 1.2, 0.6), 17.5)


def cornell_parts(offset=(0.0, 0.0, 0.0), grid: int = 8) -> list:
    """A closed 2 x 2 x 2 m Cornell box (floor y=0, x and z in [-1, 1]) with its two blocks."""
    ox, oy, oz = offset
    cell = 2.0 / grid
    walls = {"-x": RED, "+x": GREEN, "+y": WHITE, "-y": WHITE, "+z": WHITE, "-z": WHITE}
    parts = box((ox, oy + 1.0, oz), (2.0, 2.0, 2.0), cell, walls, inward=True)
    for (cx, cz), size, yaw in (_SHORT_BLOCK, _TALL_BLOCK):
        parts += box((ox + cx, oy + 0.5 * size[1], oz + cz), size, cell, WHITE, yaw_deg=yaw, skip=("-y",))
    return parts


def _cornell_light_and_camera(offset=(0.0, 0.0, 0.0), intensity: float = 20.0):
    o = np.asarray(offset, dtype=np.float64)
    # Low in the front-left corner, aimed up at the ceiling above the camera: only the far edge
    # of the lit patch is in view, so most light on screen (about 80%) has bounced once.
    spot = SpotLight(o + [-0.6, 0.2, 0.8], o + [0.0, 2.0, 0.4], [intensity] * 3, cutoff_angle_deg=30.0)
    camera = Camera(o + [0.0, 1.0, 0.95], o + [0.0, 0.9, -1.0], fov_y_deg=60.0)
    return spot, camera


def plan_cornell_spot(grid: int = 8) -> Plan:
    _require(int(grid) == grid and 1 <= grid <= 256, "cornell_spot", f"option grid must be an integer in [1, 256], got {grid}")
    spot, camera = _cornell_light_and_camera()
    return Plan(cornell_parts(grid=int(grid)), [spot], {"main": camera})


def plan_cornell_tiled(n: int = 4, grid: int = 8) -> Plan:
    _require(int(n) == n and 1 <= n <= 64, "cornell_tiled", f"option n must be an integer in [1, 64], got {n}")
    _require(int(grid) == grid and 1 <= grid <= 256, "cornell_tiled", f"option grid must be an integer in [1, 256], got {grid}")
    n, grid = int(n), int(grid)
    spacing = 2.5  # 0.5 m gaps: no coincident walls between neighbours
    parts = []
    for i in range(n):
        for k in range(n):
            parts += cornell_parts((i * spacing, 0.0, -k * spacing), grid)
    spot, camera = _cornell_light_and_camera()
    return Plan(parts, [spot], {"main": camera},
                notes="only box (0, 0) is lit and seen; the others are closed, dark and add triangles")


# ---------------------------------------------------------------------------- rooms
def _wall_with_door(x: float, z0: float, z1: float, height: float, door: tuple, cell: float, albedo) -> list:
    """A wall in the plane x = const from z0 to z1 with a door opening door=(dz0, dz1, door_height)."""
    dz0, dz1, dh = door
    return [quad((x, 0, z0), (0, 0, dz0 - z0), (0, height, 0), cell, albedo),
            quad((x, 0, dz1), (0, 0, z1 - dz1), (0, height, 0), cell, albedo),
            quad((x, dh, dz0), (0, 0, dz1 - dz0), (0, height - dh, 0), cell, albedo)]


def plan_rooms(cell: float = 0.4, intensity: float = 20.0) -> Plan:
    _require(0.05 <= cell <= 4.0, "rooms", f"option cell must be in [0.05, 4] m, got {cell}")
    width, depth, height = 4.0, 4.0, 2.7   # per room (x, z, y); three rooms along +x
    z0, z1 = -0.5 * depth, 0.5 * depth
    colours = [(0.75, 0.72, 0.65), (0.7, 0.75, 0.8), (0.8, 0.72, 0.6)]
    floor = (0.55, 0.5, 0.45)
    parts = []
    for r in range(3):
        x0 = r * width
        parts.append(quad((x0, 0, z0), (0, 0, depth), (width, 0, 0), cell, floor))           # floor, +y
        parts.append(quad((x0, height, z0), (width, 0, 0), (0, 0, depth), cell, WHITE))      # ceiling, -y
        parts.append(quad((x0, 0, z0), (width, 0, 0), (0, height, 0), cell, colours[r]))     # back wall z0, +z
        parts.append(quad((x0, 0, z1), (0, height, 0), (width, 0, 0), cell, colours[r]))     # front wall z1, -z
    parts.append(quad((0, 0, z0), (0, height, 0), (0, 0, depth), cell, RED))                   # end wall x=0
    parts.append(quad((3 * width, 0, z0), (0, 0, depth), (0, height, 0), cell, GREEN))         # end wall x=12
    # Doors on opposite sides: no straight line from the light through both doors.
    parts += _wall_with_door(width, z0, z1, height, (0.6, 1.5, 2.1), cell, WHITE)
    parts += _wall_with_door(2 * width, z0, z1, height, (-1.5, -0.6, 2.1), cell, WHITE)
    light = PointLight([1.0, 2.2, -1.2], [intensity] * 3)
    cameras = {"main": Camera([7.2, 1.5, -1.4], [4.0, 1.1, 1.05], fov_y_deg=55.0),     # room 2 -> lit room 1
               "far": Camera([11.5, 1.5, 1.5], [8.0, 1.0, -1.05], fov_y_deg=55.0)}     # room 3 -> room 2
    return Plan(parts, [light], cameras,
                notes="light in room 1 (x 0-4); 'main' in room 2 looks through door 1, 'far' in room 3 through door 2")


# ---------------------------------------------------------------------------- hidden bounce
def plan_hidden_bounce(cell: float = 0.25, intensity: float = 120.0) -> Plan:
    _require(0.05 <= cell <= 4.0, "hidden_bounce", f"option cell must be in [0.05, 4] m, got {cell}")
    size = (5.0, 3.0, 6.0)
    walls = {"-x": (0.7, 0.7, 0.7), "+x": (0.7, 0.7, 0.7), "-y": (0.6, 0.6, 0.6), "+y": (0.8, 0.8, 0.8),
             "-z": (0.7, 0.7, 0.7), "+z": (0.9, 0.55, 0.25)}  # +z: the warm wall behind the camera
    parts = box((0.0, 1.5, 0.0), size, cell, walls, inward=True)
    parts += box((-1.0, 0.4, -1.2), (0.8, 0.8, 0.8), cell, (0.3, 0.5, 0.8), yaw_deg=25.0, skip=("-y",))
    parts += box((1.1, 0.7, -1.8), (0.6, 1.4, 0.6), cell, (0.8, 0.8, 0.8), yaw_deg=-20.0, skip=("-y",))
    parts.append(Icosphere((0.2, 0.45, -0.2), 0.45, 3, (0.8, 0.3, 0.3)))
    # Behind the camera, aimed at the wall behind it and the ceiling above: nothing it lights
    # directly is in view, everything on screen is lit by that hidden surface.
    spot = SpotLight([0.8, 0.4, 1.9], [0.2, 2.4, 3.0], [intensity] * 3, cutoff_angle_deg=35.0)
    camera = Camera([0.0, 1.4, 1.0], [0.0, 1.0, -3.0], fov_y_deg=55.0)
    return Plan(parts, [spot], {"main": camera})


# ---------------------------------------------------------------------------- big floor
def plan_big_floor(intensity: float = 120.0) -> Plan:
    half = 20.0
    parts = [quad((-half, 0, -half), (0, 0, 2 * half), (2 * half, 0, 0), 1e9, (0.7, 0.7, 0.7)),   # 2 triangles
             quad((-half, 0, -6.0), (2 * half, 0, 0), (0, 10.0, 0), 1e9, (0.6, 0.65, 0.7))]     # 2 triangles
    radius = 0.8
    parts.append(Icosphere((0.0, radius * 1.06, 0.0), radius, 4, (0.75, 0.75, 0.75), bumps=12, bump_height=0.05, seed=7))
    for i in range(6):          # a field of small cubes to the right of the blob
        for k in range(6):
            parts += box((1.3 + 0.3 * i, 0.075, -0.8 + 0.3 * k), (0.15, 0.15, 0.15), 0.05,
                         (0.8, 0.55, 0.3), yaw_deg=15.0 * ((i + k) % 3), skip=("-y",))
    # Straight down onto the floor in front of the blob: the blob's front and the cubes are lit
    # (almost) only by the floor's bounce.
    spot = SpotLight([0.3, 5.0, 2.0], [0.3, 0.0, 2.0], [intensity] * 3, cutoff_angle_deg=12.0)
    camera = Camera([1.0, 1.0, 3.8], [0.5, 0.5, 0.0], fov_y_deg=45.0)
    return Plan(parts, [spot], {"main": camera}, notes="floor and back wall are 2 triangles each")


# ---------------------------------------------------------------------------- lit wall corner
def plan_lit_wall_corner(cell: float = 0.25, irradiance: float = 3.0) -> Plan:
    """A lit wall meeting an unlit floor, the corner in view: screen-space GI's own regime.

    Floor y = 0 (x in [-1.5, 1.5], z in [-1, 1], light grey) and a terracotta wall z = -1
    (x in [-1.5, 1.5], y in [0, 1.5]) under a directional light travelling along -z: the wall
    faces it (irradiance `irradiance`), the floor is parallel to it and gets exactly none, so
    every bit of light on the floor is the wall's bounce (and the wall gets none). The camera
    looks down at the corner with the lit wall on screen: 99.5% of the unshadowed one-bounce
    light in view comes from on-screen senders (128x96, `studies/ssdo_screen_bound.py`).
    """
    _require(0.05 <= cell <= 4.0, "lit_wall_corner", f"option cell must be in [0.05, 4] m, got {cell}")
    _require(irradiance >= 0, "lit_wall_corner", f"option irradiance must be >= 0, got {irradiance}")
    parts = [quad((-1.5, 0, -1.0), (0, 0, 2.0), (3.0, 0, 0), cell, (0.7, 0.7, 0.7)),      # floor, +y
             quad((-1.5, 0, -1.0), (3.0, 0, 0), (0, 1.5, 0), cell, (0.8, 0.45, 0.25))]    # wall, +z
    sun = DirectionalLight([0.0, 0.0, -1.0], [irradiance] * 3)
    camera = Camera([0.5, 1.3, 1.7], [0.0, 0.3, -0.8], fov_y_deg=55.0)
    return Plan(parts, [sun], {"main": camera}, notes="light parallel to the floor: the floor is lit only by the wall")


# ---------------------------------------------------------------------------- sphere inside
def plan_sphere_inside(radius: float = 1.0, albedo: float = 0.5, light_offset: float = 0.3,
                       intensity: float = 1.0, subdivisions: int = 4) -> Plan:
    """A closed diffuse sphere seen from inside, lit by a point light off its centre.

    Analytic one-bounce radiance: for any two points x, y on a sphere of radius R,
    cos(theta_x) cos(theta_y) / |x - y|^2 = 1 / (4 R^2), so the radiance leaving x after one
    bounce is rho/pi * (rho/pi) * (1 / (4 R^2)) * (total flux on the sphere = 4 pi I), i.e.

        L_indirect = rho^2 I / (pi R^2)     everywhere, whatever the light position,

    (0.0796 W/(m^2 sr) for the defaults rho = 0.5, I = 1 W/sr, R = 1 m). The tessellated sphere
    (icosphere, 20 * 4^subdivisions triangles, vertices on the sphere, radial shading
    normals) differs from the ideal one by O(edge^2 / R^2) (about 0.3% at the default 5,120
    triangles).
    """
    name = "sphere_inside"
    _require(radius > 0, name, f"option radius must be > 0, got {radius}")
    _require(0 <= albedo <= 1, name, f"option albedo must be in [0, 1], got {albedo}")
    _require(0 <= light_offset <= 0.9, name, f"option light_offset must be in [0, 0.9] (fraction of R), got {light_offset}")
    _require(intensity >= 0, name, f"option intensity must be >= 0, got {intensity}")
    _require(int(subdivisions) == subdivisions and 2 <= subdivisions <= 7, name,
             f"option subdivisions must be an integer in [2, 7], got {subdivisions}")
    r = float(radius)
    sphere = Icosphere((0.0, 0.0, 0.0), r, int(subdivisions), (albedo,) * 3)
    light = PointLight([light_offset * r, 0.0, 0.0], [intensity] * 3)
    camera = Camera([-0.2 * r, -0.15 * r, 0.55 * r], [0.1 * r, 0.05 * r, -r], fov_y_deg=70.0)
    expected = albedo * albedo * intensity / (math.pi * r * r)
    return Plan([sphere], [light], {"main": camera},
                notes=f"analytic one-bounce radiance rho^2 I / (pi R^2) = {expected:.6g}",
                extra={"analytic_indirect_radiance": expected})


def sphere_inside_indirect(radius: float = 1.0, albedo: float = 0.5, intensity: float = 1.0) -> float:
    """rho^2 I / (pi R^2): the exact one-bounce radiance inside a diffuse sphere."""
    return albedo * albedo * intensity / (math.pi * radius * radius)


# ---------------------------------------------------------------------------- high-poly series
_ROOM = 6.0          # room: x and z in [-3, 3], y in [0, 3]
_ROOM_HEIGHT = 3.0
_ROOM_CELL = 0.75


def _highpoly_room() -> list:
    h, s, cell = _ROOM_HEIGHT, _ROOM, _ROOM_CELL
    walls = {"-x": (0.75, 0.7, 0.65), "+x": (0.65, 0.7, 0.75), "+y": WHITE, "-z": (0.7, 0.7, 0.7), "+z": (0.7, 0.7, 0.7)}
    return box((0.0, 0.5 * h, 0.0), (s, h, s), cell, walls, inward=True, skip=("-y",))


def highpoly_grid(triangles: int) -> tuple[int, int]:
    """Terrain cells (nu, nv), nearly square, with 2 nu nv + room triangles closest to `triangles`."""
    room = sum(p.triangle_count for p in _highpoly_room())
    cells = max(1, (int(triangles) - room) // 2)
    n = max(1, int(round(math.sqrt(cells))))
    best = None
    for nu in range(max(1, int(n * 0.9)), int(n * 1.1) + 2):
        nv = max(1, int(round(cells / nu)))
        err = abs(nu * nv - cells)
        if best is None or err < best[0]:
            best = (err, nu, nv)
    return best[1], best[2]


def plan_highpoly(triangles: int = 10_000, amplitude: float = 0.6) -> Plan:
    name = "highpoly"
    _require(int(triangles) == triangles and 1_000 <= triangles <= 50_000_000, name,
             f"option triangles must be an integer in [1000, 5e7], got {triangles}")
    _require(0 <= amplitude <= 2.5, name, f"option amplitude must be in [0, 2.5] m, got {amplitude}")
    nu, nv = highpoly_grid(int(triangles))
    half = 0.5 * _ROOM
    terrain = Heightfield(-half, half, -half, half, nu, nv, 0.0,
                          wavy_height(amplitude, -half, half, -half, half, waves=32, seed=3, min_wavelength=0.05),
                          albedo=(0.65, 0.62, 0.55))
    parts = _highpoly_room() + [terrain]
    lights = [PointLight([1.2, 2.6, -0.9], [12.0] * 3),
              SpotLight([-2.6, 2.8, 2.6], [0.5, 0.3, -0.5], [25.0] * 3, cutoff_angle_deg=25.0)]
    camera = Camera([-2.6, 1.4, 2.7], [0.4, 0.2, -0.4], fov_y_deg=55.0)
    return Plan(parts, lights, {"main": camera}, notes=f"terrain {nu} x {nv} quads in a 6 x 3 x 6 m room")
