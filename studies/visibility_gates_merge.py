"""visibility_gates (issue #23): greedy clusters per scene, every gate's width ratio and the visible fraction of the union of its two clusters, and the cluster counts by (merge_gate_fraction, merge_visible_fraction). Usage: python -m studies.visibility_gates_merge rooms,sibenik"""
import sys, time
import numpy as np
from bench.model.corpus import load_scene
from methods.visibility_gates.method import topology_seeds
from methods.visibility_gates.voxels import voxelize
from methods.visibility_gates.skeleton import KIND_UNCLASSIFIED, cluster, prune_spurs, segment, skeleton_graph
from methods.visibility_gates.gates import paper_gate_radii, merge_wide_gates, visible_fraction, _sample_nodes

for name in sys.argv[1].split(","):
    t = time.time()
    scene = load_scene(name)
    _, empty, origin, pitch, closed, surface = voxelize(np.asarray(scene.vertices, float), np.asarray(scene.faces), 64, topology_seeds(scene))
    coords, graph = skeleton_graph(empty)
    coords, graph = prune_spurs(coords, graph, empty)
    pos = origin + (coords + 0.5) * pitch
    radius = surface.distance(pos)
    if closed:
        lo, hi = origin + pitch, origin + (np.asarray(empty.shape) - 1) * pitch
        radius = np.minimum(radius, np.minimum(pos - lo, hi - pos).min(axis=1))
    radius = np.maximum(radius, 1e-3 * pitch)
    kind, assoc, seg_edges, lines = segment(graph, pos, radius)
    seg_nodes = np.flatnonzero(kind != KIND_UNCLASSIFIED)
    label, count = cluster(seg_nodes, seg_edges, pos, radius, kind, 20.0)
    crad = np.zeros(count)
    for n, c in label.items():
        crad[c] = max(crad[c], radius[n])
    gr, gp = paper_gate_radii(seg_edges, label, radius)
    of_node = np.array([label[int(assoc[i])] for i in range(len(coords))])
    sizes = np.bincount(of_node, minlength=count)
    print(f"== {name}: {count} greedy clusters, {len(gr)} gates, nodes {len(coords)}, pitch {pitch:.3f}, {time.time()-t:.1f}s")
    for g in np.argsort(-(gr / np.minimum(crad[gp[:, 0]], crad[gp[:, 1]]))):
        a, b = gp[g]
        ratio = gr[g] / min(crad[a], crad[b])
        vf = visible_fraction(empty, coords[_sample_nodes(np.flatnonzero(of_node == a))], coords[_sample_nodes(np.flatnonzero(of_node == b))])
        print(f"  gate {g:3d} {a:3d}-{b:3d} ratio {ratio:5.2f} r {gr[g]:.2f} rmax {crad[a]:.2f}/{crad[b]:.2f} nodes {sizes[a]}/{sizes[b]} visible {vf:.2f}")
    for frac in (0.75, 0.5, 0.25, 0.0):
        row = []
        for mv in (0.0, 0.3, 0.5, 0.7, 0.8, 0.9, 1.0):
            _, n = merge_wide_gates(count, crad, gr, gp, frac, empty, coords, of_node, mv)
            row.append(f"{mv}:{n}")
        print(f"  fraction {frac}: clusters by min_visible " + " ".join(row))
    sys.stdout.flush()
