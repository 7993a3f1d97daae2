"""Geometry parts the corpus generators assemble (metres, numpy, deterministic).

Each part knows its triangle count without building anything (`triangle_count`), so that
`list_scenes()` stays cheap for multi-million-triangle scenes, and builds its arrays on demand
(`build() -> (vertices, faces, normals, albedo)`, albedo per triangle).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from bench.model.scene import vertex_normals

WHITE = (0.725, 0.71, 0.68)  # Cornell box white, red and green (McGuire's MTL)
RED = (0.63, 0.065, 0.05)
GREEN = (0.14, 0.45, 0.091)


def segments(length: float, cell: float) -> int:
    """Number of grid cells of at most `cell` metres along `length`."""
    return max(1, int(math.ceil(length / cell - 1e-9)))


def _albedo(albedo, count: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(albedo, dtype=np.float64), (count, 3)).copy()


def rotation_y(yaw_deg: float) -> np.ndarray:
    a = math.radians(yaw_deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


@dataclass(frozen=True)
class Grid:
    """A parallelogram origin + [0,1]u + [0,1]v cut into nu x nv quads; faces along u x v."""
    origin: tuple
    u: tuple
    v: tuple
    nu: int
    nv: int
    albedo: tuple

    @property
    def triangle_count(self) -> int:
        return 2 * self.nu * self.nv

    def build(self):
        o, u, v = (np.asarray(a, dtype=np.float64) for a in (self.origin, self.u, self.v))
        s = np.linspace(0.0, 1.0, self.nu + 1)
        t = np.linspace(0.0, 1.0, self.nv + 1)
        verts = (o + s[:, None, None] * u + t[None, :, None] * v).reshape(-1, 3)
        idx = np.arange((self.nu + 1) * (self.nv + 1)).reshape(self.nu + 1, self.nv + 1)
        a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
        c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
        faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
        n = np.cross(u, v)
        normals = np.tile(n / np.linalg.norm(n), (len(verts), 1))
        return verts, faces, normals, _albedo(self.albedo, len(faces))


def quad(origin, u, v, cell: float, albedo) -> Grid:
    """A Grid whose cells are at most `cell` metres on a side."""
    return Grid(tuple(origin), tuple(u), tuple(v), segments(float(np.linalg.norm(u)), cell),
                segments(float(np.linalg.norm(v)), cell), tuple(albedo))


def box(center, size, cell: float, albedo, yaw_deg: float = 0.0, inward: bool = False,
        skip: tuple = ()) -> list:
    """The faces of an axis-aligned box rotated by `yaw_deg` about +Y, as Grids.

    `center` is the centre of the box, `size` its (x, y, z) extent. Faces point outward
    (inward for a room seen from inside). `skip` names faces to leave out: '+x', '-x', '+y',
    '-y', '+z', '-z' (e.g. '-y' for a block standing on a floor). `albedo` is one RGB or a dict
    face name -> RGB.
    """
    hx, hy, hz = (0.5 * float(s) for s in size)
    sx, sy, sz = (float(s) for s in size)
    local = {  # origin, u, v with u x v outward
        "+x": ((hx, -hy, -hz), (0, sy, 0), (0, 0, sz)),
        "-x": ((-hx, -hy, -hz), (0, 0, sz), (0, sy, 0)),
        "+y": ((-hx, hy, -hz), (0, 0, sz), (sx, 0, 0)),
        "-y": ((-hx, -hy, -hz), (sx, 0, 0), (0, 0, sz)),
        "+z": ((-hx, -hy, hz), (sx, 0, 0), (0, sy, 0)),
        "-z": ((-hx, -hy, -hz), (0, sy, 0), (sx, 0, 0)),
    }
    rot = rotation_y(yaw_deg)
    c = np.asarray(center, dtype=np.float64)
    parts = []
    for face, (o, u, v) in local.items():
        if face in skip:
            continue
        if inward:
            u, v = v, u
        colour = albedo[face] if isinstance(albedo, dict) else albedo
        parts.append(quad(rot @ np.asarray(o, float) + c, rot @ np.asarray(u, float),
                          rot @ np.asarray(v, float), cell, colour))
    return parts


@dataclass(frozen=True)
class Icosphere:
    """trimesh's icosphere (20 * 4^subdivisions triangles), radial normals, optional displacement.

    `bumps` > 0 displaces radially by `bump_height * radius` times a deterministic sum of
    `bumps` sines of random directions (seed `seed`); the normals are then area-weighted.
    """
    center: tuple
    radius: float
    subdivisions: int
    albedo: tuple
    bumps: int = 0
    bump_height: float = 0.0
    seed: int = 0

    @property
    def triangle_count(self) -> int:
        return 20 * 4 ** self.subdivisions

    def build(self):
        import trimesh
        sphere = trimesh.creation.icosphere(subdivisions=self.subdivisions, radius=1.0)
        unit = np.asarray(sphere.vertices, dtype=np.float64)
        unit /= np.linalg.norm(unit, axis=1, keepdims=True)
        faces = np.asarray(sphere.faces, dtype=np.int64)
        radius = np.full(len(unit), float(self.radius))
        if self.bumps:
            rng = np.random.default_rng(self.seed)
            dirs = rng.normal(size=(self.bumps, 3))
            freq = rng.uniform(2.0, 7.0, size=self.bumps)
            phase = rng.uniform(0.0, 2 * np.pi, size=self.bumps)
            wave = np.sin((unit @ dirs.T) * freq + phase).sum(axis=1) / math.sqrt(self.bumps)
            radius = radius * (1.0 + self.bump_height * wave)
        verts = unit * radius[:, None] + np.asarray(self.center, dtype=np.float64)
        normals = unit if not self.bumps else vertex_normals(verts, faces)
        return verts, faces, normals, _albedo(self.albedo, len(faces))


@dataclass(frozen=True)
class Heightfield:
    """y = y0 + height(x, z) over [x0,x1] x [z0,z1], nu x nv quads, normals from the height grid."""
    x0: float
    x1: float
    z0: float
    z1: float
    nu: int
    nv: int
    y0: float
    height: Callable = field(compare=False)
    albedo: tuple = (0.6, 0.6, 0.6)

    @property
    def triangle_count(self) -> int:
        return 2 * self.nu * self.nv

    def build(self):
        xs = np.linspace(self.x0, self.x1, self.nu + 1)
        zs = np.linspace(self.z0, self.z1, self.nv + 1)
        x, z = np.meshgrid(xs, zs, indexing="ij")
        h = self.height(x, z)
        dhdx, dhdz = np.gradient(h, xs, zs)
        verts = np.stack([x, self.y0 + h, z], axis=-1).reshape(-1, 3)
        normals = np.stack([-dhdx, np.ones_like(h), -dhdz], axis=-1).reshape(-1, 3)
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        idx = np.arange((self.nu + 1) * (self.nv + 1), dtype=np.int64).reshape(self.nu + 1, self.nv + 1)
        a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
        c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
        # x-axis then z-axis winding: (x, z) grid -> normal -y; reverse for +y (upward) faces.
        faces = np.concatenate([np.stack([a, c, b], 1), np.stack([a, d, c], 1)])
        return verts, faces, normals, _albedo(self.albedo, len(faces))


def wavy_height(amplitude: float, x0: float, x1: float, z0: float, z1: float, waves: int = 16,
                seed: int = 0, min_wavelength: float = 0.25, max_wavelength: float = 2.5) -> Callable:
    """A deterministic rolling-hills height function, zero (with zero slope) on the border."""
    rng = np.random.default_rng(seed)
    angle = rng.uniform(0.0, 2 * np.pi, waves)
    wavelength = np.exp(rng.uniform(math.log(min_wavelength), math.log(max_wavelength), waves))
    k = 2 * np.pi / wavelength
    kx, kz = k * np.cos(angle), k * np.sin(angle)
    weight = wavelength / np.sqrt(0.5 * np.sum(wavelength ** 2))  # longer waves are higher; sum std ~ 1
    phase = rng.uniform(0.0, 2 * np.pi, waves)

    def height(x, z):
        acc = np.zeros(np.broadcast(x, z).shape)
        for i in range(waves):
            acc += weight[i] * np.sin(kx[i] * x + kz[i] * z + phase[i])
        window = np.sin(np.pi * (x - x0) / (x1 - x0)) ** 2 * np.sin(np.pi * (z - z0) / (z1 - z0)) ** 2
        return amplitude * 0.5 * (1.0 + np.tanh(acc)) * window

    return height


def assemble(parts) -> tuple:
    """Concatenate built parts -> vertices, faces, normals, albedo."""
    verts, faces, normals, albedo = [], [], [], []
    offset = 0
    for part in parts:
        v, f, n, a = part.build()
        verts.append(v)
        faces.append(np.asarray(f, dtype=np.int64) + offset)
        normals.append(n)
        albedo.append(a)
        offset += len(v)
    return np.concatenate(verts), np.concatenate(faces), np.concatenate(normals), np.concatenate(albedo)
