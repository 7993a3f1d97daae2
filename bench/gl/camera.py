"""View and projection matrices (numpy, float64, row-major; transposed when sent to GLSL).

Coordinates on the GPU are re-centred on the scene's bounding-box centre (`origin`) so float32
keeps its precision on scenes far from the world origin.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.model.scene import Camera


def look_at(eye, target, up) -> np.ndarray:
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    f = target - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = r, u, -f
    m[:3, 3] = -m[:3, :3] @ eye
    return m


def perspective(fov_y_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    t = 1.0 / np.tan(np.radians(fov_y_deg) / 2.0)
    m = np.zeros((4, 4))
    m[0, 0] = t / aspect
    m[1, 1] = t
    m[2, 2] = (far + near) / (near - far)
    m[2, 3] = 2.0 * far * near / (near - far)
    m[3, 2] = -1.0
    return m


def orthographic(half_w: float, half_h: float, near: float, far: float) -> np.ndarray:
    m = np.eye(4)
    m[0, 0] = 1.0 / half_w
    m[1, 1] = 1.0 / half_h
    m[2, 2] = -2.0 / (far - near)
    m[2, 3] = -(far + near) / (far - near)
    return m


@dataclass(frozen=True)
class View:
    """One camera at one resolution, in the GPU's re-centred coordinates."""
    name: str
    camera: Camera
    width: int
    height: int
    origin: np.ndarray
    view: np.ndarray
    proj: np.ndarray
    near: float
    far: float

    @property
    def view_proj(self) -> np.ndarray:
        return self.proj @ self.view

    @property
    def eye_local(self) -> np.ndarray:
        return self.camera.eye - self.origin

    @classmethod
    def create(cls, name: str, camera: Camera, width: int, height: int, origin, scene_radius: float,
               scene_center) -> "View":
        origin = np.asarray(origin, dtype=np.float64)
        eye = camera.eye - origin
        target = camera.target - origin
        dist = float(np.linalg.norm(camera.eye - np.asarray(scene_center)))
        far = (dist + scene_radius) * 1.05 + 1e-6
        near = max(far * 1e-5, 1e-4 * scene_radius)
        return cls(name=name, camera=camera, width=int(width), height=int(height), origin=origin,
                   view=look_at(eye, target, camera.up),
                   proj=perspective(camera.fov_y_deg, width / height, near, far), near=near, far=far)

    def primary_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """World-space ray origin and unit directions through pixel centres (i+0.5, j+0.5),
        HxWx3, row 0 at the top (the reference test's ground truth)."""
        right, up, fwd = self.camera.basis()
        t = np.tan(np.radians(self.camera.fov_y_deg) / 2.0)
        aspect = self.width / self.height
        xs = ((np.arange(self.width) + 0.5) / self.width * 2.0 - 1.0) * t * aspect
        ys = (1.0 - (np.arange(self.height) + 0.5) / self.height * 2.0) * t
        d = fwd[None, None, :] + xs[None, :, None] * right[None, None, :] + ys[:, None, None] * up[None, None, :]
        d /= np.linalg.norm(d, axis=2, keepdims=True)
        return self.camera.eye, d
