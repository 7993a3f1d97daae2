"""Ray-cast truth for the studies: is the segment between a receiver and an emitter free of the
scene's triangles (Mitsuba 3, the scene's triangles as one mesh)? Shared by studies.ir_shadowed_leaks and
studies.visibility_gates_pairs, which score a method's visibility per (pixel, VPL) pair against it."""
from __future__ import annotations

import numpy as np

from reference.env import load_mitsuba


def mitsuba_scene(scene):
    """(mitsuba module, a Mitsuba scene of the scene's triangles as one mesh) for ray tests."""
    mi = load_mitsuba()
    mesh = mi.Mesh("scene", len(scene.vertices), len(scene.faces))
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(scene.vertices.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(scene.faces.astype(np.uint32).ravel())
    params.update()
    return mi, mi.load_dict({"type": "scene", "mesh": mesh})


def ray_truth(mi, msc, xs, ys):
    """(P, K) open segment free of triangles, and the first triangle it hits (-1 none) (world coords)."""
    free = np.zeros((len(xs), len(ys)), bool)
    prim = -np.ones((len(xs), len(ys)), np.int64)
    for first in range(0, len(xs), 256):
        o = np.repeat(xs[first:first + 256], len(ys), 0)
        d = np.tile(ys, (len(o) // len(ys), 1)) - o
        length = np.linalg.norm(d, axis=1)
        d /= length[:, None]
        ray = mi.Ray3f(mi.Point3f(*(mi.Float(o[:, i].astype(np.float32)) for i in range(3))),
                       mi.Vector3f(*(mi.Float(d[:, i].astype(np.float32)) for i in range(3))))
        ray.maxt = mi.Float((length * (1 - 1e-4)).astype(np.float32))
        si = msc.ray_intersect_preliminary(ray)
        hit = np.array(si.is_valid(), bool)
        free[first:first + 256] = ~hit.reshape(-1, len(ys))
        prim[first:first + 256] = np.where(hit, np.array(si.prim_index, np.int64), -1).reshape(-1, len(ys))
    return free, prim
