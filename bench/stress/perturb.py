"""Scene perturbations of the stress suite (`bench.stress.suite`): each returns a new, validated Scene.

Invariances (the answer must not change, up to noise):
  scale(scene, s)           every position times s; point and spot intensities times s^2 (the
                            irradiance I cos / r^2 keeps its value), directional irradiance kept.
  translate(scene, k)       every position moved by k scene radii along a generic direction.
  zero_area / sliver / duplicate / flipped / t_junction / coplanar
                            degenerate geometry injected on (or into) `count` host triangles
                            chosen by area with a fixed seed; new triangles lie in their host's
                            plane, carry its albedo and its interpolated shading normals, so the
                            surface (and every radiometric quantity) is the same.
Robustness (the answer changes; it must stay finite and non-negative):
  grazing_camera(scene)     a camera 1e-3 scene radii above the largest plane, looking along it.
  grazing_light(scene)      point and spot lights moved onto the nearest surface (1e-5 radii
                            above it), directional lights 1 degree above the largest plane.

A perturbed scene is named `<scene>+<tag>` (SCENE_NAME_PATTERN characters), so its references
and images never mix with the unperturbed scene's.
"""
from __future__ import annotations

import numpy as np

from bench.model.scene import Camera, DirectionalLight, PointLight, Scene, SpotLight

# A fixed, generic direction (no axis, no diagonal): translations along it move every coordinate.
TRANSLATION_DIRECTION = np.array([0.8017837, 0.5345225, 0.2672612])
GRAZING_CAMERA_HEIGHT_RADII = 1e-3
GRAZING_LIGHT_HEIGHT_RADII = 1e-5
GRAZING_DIRECTIONAL_DEG = 1.0
SLIVER_ASPECT = 1e-6


def _radius(scene: Scene) -> float:
    lo, hi = scene.bounds()
    return max(0.5 * float(np.linalg.norm(hi - lo)), 1e-300)


def _center(scene: Scene) -> np.ndarray:
    lo, hi = scene.bounds()
    return 0.5 * (lo + hi)


def _rebuild(scene: Scene, tag: str, vertices=None, faces=None, albedo=None, normals=None, lights=None,
             cameras=None) -> Scene:
    return Scene.build(f"{scene.name}+{tag}",
                       scene.vertices if vertices is None else vertices,
                       scene.faces if faces is None else faces,
                       scene.albedo if albedo is None else albedo,
                       scene.lights if lights is None else lights,
                       scene.cameras if cameras is None else cameras,
                       normals=scene.normals if normals is None else normals,
                       purpose=scene.purpose, source=f"{scene.source}; stress perturbation {tag}")


def _map_points(light, fn, intensity_factor: float):
    """A copy of `light` with its positions mapped by `fn` and its intensity scaled."""
    if isinstance(light, PointLight):
        return PointLight(fn(light.position), light.intensity * intensity_factor)
    if isinstance(light, SpotLight):
        return SpotLight(fn(light.position), fn(light.target), light.intensity * intensity_factor,
                         cutoff_angle_deg=light.cutoff_angle_deg, beam_width_deg=light.beam_width_deg)
    return DirectionalLight(light.direction, light.irradiance)


def _map_cameras(cameras: dict, fn) -> dict:
    return {k: Camera(fn(c.eye), fn(c.target), c.up, c.fov_y_deg) for k, c in cameras.items()}


def scale(scene: Scene, s: float, tag: str | None = None) -> Scene:
    """Uniform scale about the origin by `s`, radiance unchanged (I -> s^2 I for point and spot)."""
    s = float(s)
    if not (np.isfinite(s) and s > 0):
        raise ValueError(f"scale factor must be a finite number > 0, got {s}")
    fn = lambda p: np.asarray(p, dtype=np.float64) * s
    return _rebuild(scene, tag or f"scale={s:.0e}", vertices=scene.vertices * s,
                    lights=[_map_points(l, fn, s * s) for l in scene.lights],
                    cameras=_map_cameras(scene.cameras, fn))


def translate(scene: Scene, radii: float, tag: str | None = None) -> Scene:
    """Translation by `radii` scene radii along TRANSLATION_DIRECTION (lights and cameras follow)."""
    offset = TRANSLATION_DIRECTION / np.linalg.norm(TRANSLATION_DIRECTION) * float(radii) * _radius(scene)
    fn = lambda p: np.asarray(p, dtype=np.float64) + offset
    return _rebuild(scene, tag or f"translate={radii:.0e}R", vertices=scene.vertices + offset,
                    lights=[_map_points(l, fn, 1.0) for l in scene.lights],
                    cameras=_map_cameras(scene.cameras, fn))


# ---------------------------------------------------------------------------- degenerate geometry
def host_triangles(scene: Scene, count: int, seed: int = 0) -> np.ndarray:
    """`count` distinct triangle indices drawn with probability proportional to area (fixed seed)."""
    areas = scene.areas()
    count = int(min(count, len(areas)))
    rng = np.random.default_rng(seed)
    return np.sort(rng.choice(len(areas), size=count, replace=False, p=areas / areas.sum()))


def _bary_points(scene: Scene, hosts: np.ndarray, bary: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions and interpolated unit shading normals at barycentric `bary` (3,) in each host."""
    f = scene.faces[hosts]
    p = sum(bary[i] * scene.vertices[f[:, i]] for i in range(3))
    n = sum(bary[i] * scene.normals[f[:, i]] for i in range(3))
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return p, n


def _append(scene: Scene, tag: str, points: list, normals: list, tris: np.ndarray, albedo: np.ndarray,
            faces=None) -> Scene:
    """Append new vertices (lists of (K,3) arrays, one per corner) and triangles over them."""
    base_v = len(scene.vertices)
    new_v = np.concatenate(points)
    new_n = np.concatenate(normals)
    return _rebuild(scene, tag, vertices=np.concatenate([scene.vertices, new_v]),
                    normals=np.concatenate([scene.normals, new_n]),
                    faces=np.concatenate([scene.faces if faces is None else faces, tris + base_v]),
                    albedo=np.concatenate([scene.albedo, albedo]))


def zero_area(scene: Scene, count: int = 32, seed: int = 0) -> Scene:
    """Collinear triangles (three points on a host's edge) and repeated-index triangles: both carry
    no area and must be dropped (`Scene.dropped_degenerate`)."""
    hosts = host_triangles(scene, count, seed)
    k = len(hosts)
    pa, na = _bary_points(scene, hosts, np.array([1.0, 0.0, 0.0]))
    pm, nm = _bary_points(scene, hosts, np.array([0.5, 0.5, 0.0]))
    pb, nb = _bary_points(scene, hosts, np.array([0.0, 1.0, 0.0]))
    idx = np.arange(k)
    collinear = np.stack([idx, idx + k, idx + 2 * k], axis=1)
    repeated = scene.faces[hosts][:, [0, 0, 1]] - len(scene.vertices)  # indices into existing vertices
    tris = np.concatenate([collinear, repeated])
    return _append(scene, "zero_area", [pa, pm, pb], [na, nm, nb], tris,
                   np.concatenate([scene.albedo[hosts], scene.albedo[hosts]]))


def sliver(scene: Scene, count: int = 32, seed: int = 0, aspect: float = SLIVER_ASPECT) -> Scene:
    """Triangles of height `aspect` x base inside each host, in its plane."""
    hosts = host_triangles(scene, count, seed)
    k = len(hosts)
    px, nx = _bary_points(scene, hosts, np.array([0.6, 0.2, 0.2]))
    py, ny = _bary_points(scene, hosts, np.array([0.2, 0.6, 0.2]))
    base = py - px
    fn = scene.face_normals()[hosts]
    perp = np.cross(fn, base)
    perp /= np.maximum(np.linalg.norm(perp, axis=1, keepdims=True), 1e-300)
    pz = 0.5 * (px + py) + perp * (aspect * np.linalg.norm(base, axis=1, keepdims=True))
    nz = nx + ny
    nz /= np.maximum(np.linalg.norm(nz, axis=1, keepdims=True), 1e-300)
    idx = np.arange(k)
    return _append(scene, "sliver", [px, py, pz], [nx, ny, nz], np.stack([idx, idx + k, idx + 2 * k], 1),
                   scene.albedo[hosts])


def duplicate(scene: Scene, count: int = 32, seed: int = 0) -> Scene:
    """Each host triangle repeated, half with the same winding, half reversed (same vertex indices):
    `Scene.build` drops the repeats (`dropped_duplicates`)."""
    hosts = host_triangles(scene, count, seed)
    repeats = scene.faces[hosts].copy()
    repeats[1::2] = repeats[1::2, ::-1]
    return _rebuild(scene, "duplicate", faces=np.concatenate([scene.faces, repeats]),
                    albedo=np.concatenate([scene.albedo, scene.albedo[hosts]]))


def flipped(scene: Scene, count: int = 32, seed: int = 0) -> Scene:
    """Each host triangle's winding reversed in place (surfaces are two-sided: nothing may change)."""
    hosts = host_triangles(scene, count, seed)
    faces = scene.faces.copy()
    faces[hosts] = faces[hosts][:, ::-1]
    return _rebuild(scene, "flipped", faces=faces)


def t_junction(scene: Scene, count: int = 32, seed: int = 0) -> Scene:
    """Each host split in two at the midpoint of its first edge, its neighbour across that edge left
    whole: a T-junction (a vertex in the middle of another triangle's edge)."""
    hosts = host_triangles(scene, count, seed)
    k = len(hosts)
    pm, nm = _bary_points(scene, hosts, np.array([0.5, 0.5, 0.0]))
    f = scene.faces[hosts]
    m = len(scene.vertices) + np.arange(k)
    keep = np.ones(len(scene.faces), dtype=bool)
    keep[hosts] = False
    first = np.stack([f[:, 0], m, f[:, 2]], axis=1)
    second = np.stack([m, f[:, 1], f[:, 2]], axis=1)
    vertices = np.concatenate([scene.vertices, pm])
    normals = np.concatenate([scene.normals, nm])
    faces = np.concatenate([scene.faces[keep], first, second])
    albedo = np.concatenate([scene.albedo[keep], scene.albedo[hosts], scene.albedo[hosts]])
    return _rebuild(scene, "t_junction", vertices=vertices, normals=normals, faces=faces, albedo=albedo)


def coplanar(scene: Scene, count: int = 32, seed: int = 0) -> Scene:
    """A second triangle (own vertices) over part of each host: corner, edge midpoint and centroid,
    coincident and coplanar with it, same albedo."""
    hosts = host_triangles(scene, count, seed)
    k = len(hosts)
    pa, na = _bary_points(scene, hosts, np.array([1.0, 0.0, 0.0]))
    pm, nm = _bary_points(scene, hosts, np.array([0.5, 0.5, 0.0]))
    pc, nc = _bary_points(scene, hosts, np.array([1 / 3, 1 / 3, 1 / 3]))
    idx = np.arange(k)
    return _append(scene, "coplanar", [pa, pm, pc], [na, nm, nc], np.stack([idx, idx + k, idx + 2 * k], 1),
                   scene.albedo[hosts])


DEGENERATE = {"zero_area": zero_area, "sliver": sliver, "duplicate": duplicate, "flipped": flipped,
              "t_junction": t_junction, "coplanar": coplanar}


# ---------------------------------------------------------------------------- grazing views and lights
def dominant_plane(scene: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(centroid, unit normal towards the scene centre, in-plane unit axis of largest extent,
    vertices) of the plane with the largest total triangle area (faces grouped by rounded plane)."""
    n = scene.face_normals()
    areas = scene.areas()
    centroids = scene.vertices[scene.faces].mean(axis=1)
    r = _radius(scene)
    # canonical sign: the largest-magnitude component of each normal positive
    sign = np.sign(n[np.arange(len(n)), np.argmax(np.abs(n), axis=1)])
    cn = n * sign[:, None]
    d = (cn * centroids).sum(axis=1) / r
    keys = np.round(np.c_[cn * 1e3, d * 1e3]).astype(np.int64)
    uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    total = np.bincount(inverse, weights=areas)
    best = int(np.argmax(total))
    members = inverse == best
    verts = scene.vertices[np.unique(scene.faces[members])]
    centroid = (centroids[members] * areas[members, None]).sum(0) / areas[members].sum()
    normal = (cn[members] * areas[members, None]).sum(0)
    normal /= np.linalg.norm(normal)
    if np.dot(_center(scene) - centroid, normal) < 0:
        normal = -normal
    rel = verts - centroid
    rel -= np.outer(rel @ normal, normal)
    _, _, vt = np.linalg.svd(rel, full_matrices=False)
    axis = vt[0] - np.dot(vt[0], normal) * normal
    axis /= np.linalg.norm(axis)
    return centroid, normal, axis, verts


def grazing_camera(scene: Scene, view: str) -> Scene:
    """Camera `view` replaced by one 1e-3 radii above the largest plane, looking along it across 90%
    of its extent (a view along a wall)."""
    centroid, normal, axis, verts = dominant_plane(scene)
    extent = float(np.ptp((verts - centroid) @ axis))
    h = GRAZING_CAMERA_HEIGHT_RADII * _radius(scene)
    eye = centroid - 0.45 * extent * axis + h * normal
    target = centroid + 0.45 * extent * axis + h * normal
    cam = scene.cameras[view]
    cameras = dict(scene.cameras)
    cameras[view] = Camera(eye, target, normal, cam.fov_y_deg)
    return _rebuild(scene, "grazing_camera", cameras=cameras)


def grazing_light(scene: Scene) -> Scene:
    """Point and spot lights moved onto their nearest surface (1e-5 radii above it, on their side);
    directional lights turned to 1 degree above the largest plane."""
    from trimesh.triangles import closest_point  # vectorised over triangles: no spatial index needed
    triangles = scene.vertices[scene.faces]
    r = _radius(scene)
    _, normal, axis, _ = dominant_plane(scene)
    face_n = scene.face_normals()
    lights = []
    for light in scene.lights:
        if isinstance(light, DirectionalLight):
            along = light.direction - np.dot(light.direction, normal) * normal
            along = along / np.linalg.norm(along) if np.linalg.norm(along) > 1e-9 else axis
            t = np.radians(GRAZING_DIRECTIONAL_DEG)
            lights.append(DirectionalLight(np.cos(t) * along - np.sin(t) * normal, light.irradiance))
            continue
        points = closest_point(triangles, np.broadcast_to(light.position, (len(triangles), 3)))
        tri = int(np.argmin(np.linalg.norm(points - light.position, axis=1)))
        n = face_n[tri]
        if np.dot(light.position - points[tri], n) < 0:
            n = -n
        pos = points[tri] + GRAZING_LIGHT_HEIGHT_RADII * r * n
        if isinstance(light, PointLight):
            lights.append(PointLight(pos, light.intensity))
        else:
            target = light.target if np.linalg.norm(light.target - pos) > 1e-9 * r else pos + n
            lights.append(SpotLight(pos, target, light.intensity, cutoff_angle_deg=light.cutoff_angle_deg,
                                    beam_width_deg=light.beam_width_deg))
    return _rebuild(scene, "grazing_light", lights=lights)
