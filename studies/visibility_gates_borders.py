"""visibility_gates (issue #23): the border between every two clusters of a scene's topology (the voxel faces
between their empty voxels, a gate's own voxels resolved by the side of its plane) against the area of the
gates that join them, at the defaults and with `border_gates`. Usage: python -m studies.visibility_gates_borders sponza"""
import sys
import time

import numpy as np

from bench.model.corpus import load_scene
from bench.protocol.method import resolve_params
from methods.visibility_gates.method import VisibilityGates, scene_topology, topology_seeds
from methods.visibility_gates.voxels import voxelize


def borders(topo, empty) -> dict:
    """(cluster a, cluster b) -> m^2 of voxel faces between their empty voxels."""
    idx = np.argwhere(empty)
    grid = -np.ones(empty.shape, np.int64)
    grid[tuple(idx.T)] = topo.cluster_of(topo.origin + (idx + 0.5) * topo.pitch)
    area: dict = {}
    for axis in range(3):
        n = empty.shape[axis] - 1
        a, b = np.take(grid, np.arange(n), axis=axis), np.take(grid, np.arange(1, n + 1), axis=axis)
        m = (a >= 0) & (b >= 0) & (a != b)
        for x, y in zip(a[m], b[m]):
            key = (min(x, y), max(x, y))
            area[key] = area.get(key, 0.0) + topo.pitch ** 2
    return area


for name in sys.argv[1].split(","):
    scene = load_scene(name)
    p = resolve_params(VisibilityGates, {})
    _, empty, *_ = voxelize(np.asarray(scene.vertices, float), np.asarray(scene.faces), p["voxel_resolution"],
                            topology_seeds(scene))
    for border_gates in (False, True):
        t = time.time()
        topo, _ = scene_topology(scene, p["voxel_resolution"], p["alpha_percent"], p["merge_gate_fraction"],
                                 p["merge_visible_fraction"], border_gates)
        area = borders(topo, empty)
        gate_area: dict = {}
        for g, (a, b) in enumerate(topo.gates.pairs):
            key = (min(a, b), max(a, b))
            gate_area[key] = gate_area.get(key, 0.0) + topo.gates.area[g]
        print(f"== {name} border_gates={border_gates}: {topo.cluster_count} clusters, {len(topo.gates.radius)} gates, "
              f"pitch {topo.pitch:.3f} m, {time.time() - t:.1f} s; border {sum(area.values()):.1f} m^2, "
              f"gates {sum(gate_area.values()):.1f} m^2")
        for (a, b), m2 in sorted(area.items(), key=lambda kv: -kv[1])[:12]:
            print(f"  clusters {a:3d}-{b:3d}: border {m2:6.1f} m^2, gates {gate_area.get((a, b), 0.0):6.1f} m^2")
