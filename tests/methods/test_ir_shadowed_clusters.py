"""ir_shadowed's triangle clusters: the hemicube pass draws each cluster only into the faces whose
frustum it may reach (methods/ir_shadowed/clusters.py), and the atlas must be the one drawing
every triangle into every face gives."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from bench.gl import Frame, GpuScene, SharedPasses, StageProfiler
from bench.protocol.method import resolve_params
from methods.ir_shadowed.clusters import CLUSTER_TRIANGLES, build_clusters
from methods.ir_shadowed.method import HEMICUBE_FACES, HemicubeAtlas, InstantRadiosityShadowed
from tests.methods.test_ir import make_occluder_scene

W = H = 64


@settings(max_examples=40, deadline=None)
@given(arrays(np.float32, st.tuples(st.integers(3, 200), st.just(3)),
              elements=st.floats(-10, 10, width=32)),
       st.integers(1, 70), st.data())
def test_clusters_hold_every_triangle_once_inside_their_spheres(positions, cluster_triangles, data):
    n_tri = data.draw(st.integers(1, 300))
    faces = data.draw(arrays(np.int64, (n_tri, 3), elements=st.integers(0, len(positions) - 1)))
    ordered, records = build_clusters(positions, faces, cluster_triangles, radius=10.0)
    # a permutation of the triangles, each keeping its corners in order (winding)
    assert sorted(map(tuple, ordered.tolist())) == sorted(map(tuple, faces.tolist()))
    info = records.view(np.uint32)
    counts, firsts = info[:, 4], info[:, 5]
    assert counts.sum() == n_tri and (firsts == np.arange(len(records)) * cluster_triangles).all()
    assert (counts[:-1] == cluster_triangles).all() and 1 <= counts[-1] <= cluster_triangles
    for c, (first, count) in enumerate(zip(firsts, counts)):
        corners = positions[ordered[first:first + count]].reshape(-1, 3).astype(np.float64)
        reach = np.linalg.norm(corners - records[c, :3].astype(np.float64), axis=1)
        assert (reach <= records[c, 3]).all()


def render_atlases(ctx, scene, params, cluster_triangles):
    """One frame's VPLs, then the hemicube atlas drawn with each clustering: (atlas bytes, pairs
    drawn, clusters) for each."""
    gpu = GpuScene(ctx, scene, seed=0)
    view = gpu.view("main", W, H)
    passes = SharedPasses(gpu, view, InstantRadiosityShadowed.needs)
    method = InstantRadiosityShadowed()
    out = []
    try:
        params = resolve_params(InstantRadiosityShadowed, params)
        method.prepare(gpu, scene, gpu.facts, params, view)
        prof = StageProfiler(ctx)
        frame = Frame(ctx=ctx, gpu=gpu, view=view, passes=passes, index=0, seed=0)
        passes.render(prof)
        method.sampler.sample(passes.rsm, frame.random_u32(0))
        for size in cluster_triangles:
            atlas = HemicubeAtlas(gpu, params["vpl_count"], params["shadow_resolution"], plane=True,
                                  cluster_triangles=size)
            try:
                atlas.render(method.sampler)
                out.append((atlas.atlas.read(), atlas.scene.kept_pairs(), atlas.scene.cluster_count))
            finally:
                atlas.release()
    finally:
        method.release()
        passes.release()
        gpu.release()
    return out


def test_culled_atlas_equals_the_whole_scene_in_every_face(gl_ctx):
    """A floor and wall of 16 x 16 quads and a panel (1026 triangles, 17 clusters of 64): the
    culled draw gives the same atlas, byte for byte, as one cluster holding the whole scene (its
    sphere holds every VPL: never culled, every triangle drawn into every face), and draws 0.59 of the
    (cluster, face) pairs (large planar clusters facing most VPLs)."""
    scene = make_occluder_scene(n=16)
    params = {"vpl_count": 64, "shadow_resolution": 32}
    (culled, pairs, n_clusters), (whole, whole_pairs, one) = render_atlases(
        gl_ctx, scene, params, (CLUSTER_TRIANGLES, 10 ** 9))
    instances = params["vpl_count"] * HEMICUBE_FACES
    assert one == 1 and whole_pairs == instances
    assert n_clusters == 17
    assert pairs < 0.75 * n_clusters * instances, pairs / (n_clusters * instances)
    assert culled == whole


def test_many_vpls_keep_the_same_atlas(gl_ctx):
    """1024 VPLs (5120 faces) over the 17 clusters: each cluster's run of face ids is written by
    thousands of invocations at once (an atomic slot each), and the atlas is still the same."""
    scene = make_occluder_scene(n=16)
    params = {"vpl_count": 1024, "shadow_resolution": 8}
    (culled, pairs, n_clusters), (whole, _, _) = render_atlases(gl_ctx, scene, params, (CLUSTER_TRIANGLES, 10 ** 9))
    assert 0 < pairs < n_clusters * 1024 * HEMICUBE_FACES
    assert culled == whole
