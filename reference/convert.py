"""`Scene` + camera -> Mitsuba 3 scene (`mi.load_dict`), matching the rasteriser exactly.

* Geometry: one `mi.Mesh` built from the scene's arrays (no re-export): the same triangles,
  the same per-vertex shading normals, re-centred on the bounding-box centre of the used
  vertices (like `GpuScene.origin`) and scaled to unit radius: Mitsuba works in the frame
  (world - origin) / R, R the bounding-sphere radius. Radiance is scale-free: point and spot
  intensities become I / R^2 (the same irradiance at the same relative distance), directional
  irradiance is unchanged. Mitsuba's ray offsets have an absolute floor ((1 + |p|) eps): in
  world units a millimetre-sized scene lost or gained tens of percent of its light (the stress
  suite's scale=1e-4 row); in the unit frame every scale gives the same image.
* Material: two-sided diffuse (`twosided` around `diffuse`) like the GBuffer, albedo per
  triangle through the mesh attribute `face_albedo` (`mesh_attribute` texture).
* Emitters: Mitsuba's `point` (intensity, W/sr), `spot` (intensity, cutoff_angle, beam_width)
  and `directional` (irradiance): the conventions of `bench.model.scene`, one to one.
* Sensor: `perspective` with the camera's *vertical* fov (`fov_axis = "y"`; Mitsuba's default
  is x), the image aspect, `look_at(eye, target, up)`; `hdrfilm` with a `box` filter so one
  film pixel is one rasteriser pixel (pixel centres at (i + 0.5, j + 0.5), row 0 at the top).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.model.scene import DirectionalLight, PointLight, Scene, SceneError, SpotLight


def scene_origin(scene: Scene) -> np.ndarray:
    lo, hi = scene.bounds()
    return 0.5 * (lo + hi)


def scene_scale(scene: Scene) -> float:
    """1 / R: Mitsuba's frame is (world - scene_origin) * scene_scale (unit bounding-sphere radius)."""
    lo, hi = scene.bounds()
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    return 1.0 / radius if radius > 0 else 1.0


def to_frame(scene: Scene, points) -> np.ndarray:
    """World points (..., 3) in Mitsuba's frame."""
    return (np.asarray(points, dtype=np.float64) - scene_origin(scene)) * scene_scale(scene)


def clip_range(scene: Scene, camera_name: str) -> tuple[float, float]:
    """Near/far clip distances that contain the whole scene (as the GL view does)."""
    lo, hi = scene.bounds()
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    dist = float(np.linalg.norm(scene.cameras[camera_name].eye - 0.5 * (lo + hi)))
    far = (dist + radius) * 1.05 + 1e-6
    near = max(far * 1e-5, 1e-4 * radius)
    return near, far * 2.0


def build_mesh(mi, scene: Scene, origin: np.ndarray, scale: float = 1.0):
    bsdf = mi.load_dict({"type": "twosided", "material": {
        "type": "diffuse", "reflectance": {"type": "mesh_attribute", "name": "face_albedo"}}})
    props = mi.Properties()
    props["bsdf"] = bsdf
    mesh = mi.Mesh(scene.name or "scene", len(scene.vertices), len(scene.faces), props=props,
                   has_vertex_normals=True, has_vertex_texcoords=False)
    params = mi.traverse(mesh)
    # buffer types differ by variant (mi.Float in llvm_*, dr.scalar.ArrayXf in scalar_*)
    float_buffer, index_buffer = type(params["vertex_positions"]), type(params["faces"])
    params["vertex_positions"] = float_buffer(np.ascontiguousarray(((scene.vertices - origin) * scale).astype(np.float32).ravel()))
    params["vertex_normals"] = float_buffer(np.ascontiguousarray(scene.normals.astype(np.float32).ravel()))
    params["faces"] = index_buffer(np.ascontiguousarray(scene.faces.astype(np.uint32).ravel()))
    params.update()
    mesh.add_attribute("face_albedo", 3, float_buffer(np.ascontiguousarray(scene.albedo.astype(np.float32).ravel())))
    return mesh


def _rgb(values) -> dict:
    return {"type": "rgb", "value": [float(v) for v in values]}


def emitter_dict(mi, light, origin: np.ndarray, scale: float = 1.0) -> dict:
    if isinstance(light, PointLight):
        return {"type": "point", "position": ((light.position - origin) * scale).tolist(),
                "intensity": _rgb(np.asarray(light.intensity) * scale * scale)}
    if isinstance(light, SpotLight):
        pos, target = (light.position - origin) * scale, (light.target - origin) * scale
        axis = light.direction
        up = np.array([0.0, 1.0, 0.0]) if abs(axis[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
        return {"type": "spot", "to_world": mi.ScalarTransform4f().look_at(origin=pos.tolist(), target=target.tolist(),
                                                                            up=up.tolist()),
                "intensity": _rgb(np.asarray(light.intensity) * scale * scale),
                "cutoff_angle": float(light.cutoff_angle_deg),
                "beam_width": float(light.beam_width_deg)}
    if isinstance(light, DirectionalLight):
        return {"type": "directional", "direction": light.direction.tolist(), "irradiance": _rgb(light.irradiance)}
    raise SceneError(f"reference: unsupported light {light!r}")


def sensor_dict(mi, scene: Scene, camera_name: str, width: int, height: int, origin: np.ndarray,
                spp: int = 1, sampler: dict | None = None, scale: float = 1.0) -> dict:
    if camera_name not in scene.cameras:
        raise SceneError(f"scene '{scene.name}' has no camera '{camera_name}'; cameras: {sorted(scene.cameras)}")
    if int(width) < 1 or int(height) < 1:
        raise ValueError(f"reference: image size {width}x{height} must be positive")
    cam = scene.cameras[camera_name]
    near, far = clip_range(scene, camera_name)
    return {
        "type": "perspective", "fov": float(cam.fov_y_deg), "fov_axis": "y",
        "near_clip": near * scale, "far_clip": far * scale,
        "to_world": mi.ScalarTransform4f().look_at(origin=((cam.eye - origin) * scale).tolist(),
                                                   target=((cam.target - origin) * scale).tolist(), up=cam.up.tolist()),
        "film": {"type": "hdrfilm", "width": int(width), "height": int(height), "pixel_format": "rgb",
                 "rfilter": {"type": "box"}, "sample_border": False},
        "sampler": sampler or {"type": "independent", "sample_count": int(spp)},
    }


def scene_dict(mi, scene: Scene, camera_name: str, width: int, height: int, integrator: dict | None = None,
               sampler: dict | None = None, emitters: list | None = None) -> dict:
    """The Mitsuba scene dict (mesh object included) of one view, in the unit frame: positions
    Mitsuba reports are (world - scene_origin) * scene_scale (see `to_frame`).
    `emitters`: already-loaded emitter objects, one per scene light (else dicts are used)."""
    origin, scale = scene_origin(scene), scene_scale(scene)
    d = {"type": "scene",
         "geometry": build_mesh(mi, scene, origin, scale),
         "sensor": sensor_dict(mi, scene, camera_name, width, height, origin, sampler=sampler, scale=scale)}
    for i, light in enumerate(scene.lights):
        d[f"light_{i:04d}"] = emitters[i] if emitters is not None else emitter_dict(mi, light, origin, scale)
    if integrator is not None:
        d["integrator"] = integrator
    return d


def load_view(mi, scene: Scene, camera_name: str, width: int, height: int, integrator: dict | None = None,
              sampler: dict | None = None):
    return mi.load_dict(scene_dict(mi, scene, camera_name, width, height, integrator, sampler))


@dataclass
class MitsubaView:
    """A loaded Mitsuba scene of one view and the light samplers of its emitters."""
    scene: object
    lights: list


def light_samplers(mi, scene: Scene, emitters: list, origin: np.ndarray, scale: float = 1.0) -> list:
    from reference.integrators import LightSampler
    lo, hi = scene.bounds()
    center = tuple(((0.5 * (lo + hi) - origin) * scale).tolist())
    radius = (0.5 * float(np.linalg.norm(hi - lo)) * 1.01 + 1e-6) * scale
    out = []
    for light, emitter in zip(scene.lights, emitters):
        if isinstance(light, PointLight):
            out.append(LightSampler(emitter, "point", position=tuple(((light.position - origin) * scale).tolist())))
        elif isinstance(light, SpotLight):
            out.append(LightSampler(emitter, "spot", position=tuple(((light.position - origin) * scale).tolist()),
                                    axis=tuple(light.direction.tolist()),
                                    cos_cutoff=float(np.cos(np.radians(light.cutoff_angle_deg)))))
        else:
            out.append(LightSampler(emitter, "directional", axis=tuple(light.direction.tolist()), center=center,
                                    radius=radius))
    return out


def build_view(mi, scene: Scene, camera_name: str, width: int, height: int) -> MitsubaView:
    """The Mitsuba scene of one view plus light samplers sharing its emitter objects (used by
    the reference integrators' light-sampled MIS)."""
    origin, scale = scene_origin(scene), scene_scale(scene)
    emitters = [mi.load_dict(emitter_dict(mi, light, origin, scale)) for light in scene.lights]
    mscene = mi.load_dict(scene_dict(mi, scene, camera_name, width, height, emitters=emitters))
    return MitsubaView(mscene, light_samplers(mi, scene, emitters, origin, scale))
